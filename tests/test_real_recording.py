"""Real readings through the whole daemon: a TFmini-S on a bicycle logging the roadside
(tests/data/tfmini_s_roadside/SOURCE.md), turned back into frames, recorded and
replayed through `lunad serve`.

There is no truth in a real log, so the checks are ones the readings themselves can
settle: every frame is published; an estimate never sits further from the reading of
its own frame than its sigma and the reading's noise (as the message states them)
allow; and the light estimate does not read the passing roadside as daylight brighter
than the sun. docs/filter.md gives the figures and what remains wrong here.
"""

from __future__ import annotations

import csv
import math
import statistics
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import zmq

from lunad.daemon.sources.base import Chunk
from lunad.daemon.sources.recording import Recorder
from lunad.filters import FilterConfig
from lunad.protocol.frame import encode_frame
from lunad.protocol.messages import HealthMessage, RangeMessage, decode

DATA = Path(__file__).parent / "data" / "tfmini_s_roadside" / "lidar.csv"
LOGGED_HZ = 33
"""About the rate the logger read frames at (median 29.8 ms apart)."""
REPLAY_SPEED = 50
"""The replay's pace against the log's own (about 1700 messages a second, 1.8 s in all):
a subscriber on a loaded test machine keeps up with it; the filter works on the
recorded frame times, so the pace does not change its estimates."""
MAX_DAYLIGHT_LUX = 100_000.0
"""Direct summer sunlight at noon is about 100 klux; this log was taken under an hour
before sunset in November, at most a few klux."""


def _rows() -> list[tuple[int, int, int, int]]:
    """(t_ns from the first row, distance cm, strength, raw temperature) per row."""
    with DATA.open(newline="") as f:
        reader = csv.reader(f)
        next(reader)
        rows = [(datetime.fromisoformat(t), int(d), int(a), int(c)) for t, d, a, c in reader]
    t0 = rows[0][0]
    return [(round((t - t0).total_seconds() * 1e9), d, a, c) for t, d, a, c in rows]


def _record(path: Path) -> int:
    """Write the log as a recording, one frame a read at its logged time; frames written."""
    rows = _rows()
    with Recorder(path, "tfmini-s roadside log", frame_rate_hz=LOGGED_HZ) as rec:
        for t_ns, dist, amp, temp in rows:
            rec(Chunk(encode_frame(dist, amp, temp), 1_000_000_000 + t_ns))
    return len(rows)


def _ranges_until_stopped(endpoint: str, timeout_s: float) -> list[RangeMessage]:
    """Every range message of a replay, until its last health message (``stopped``).

    A plain SUB with no receive limit, fed at ``REPLAY_SPEED``: the daemon drops what a
    peer leaves behind past its send limit (1000 messages), as for any slow subscriber,
    and a full-speed replay (3000 messages in about a tenth of a second) outran this
    loop on a loaded machine.
    """
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, 0)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(endpoint)
    out: list[RangeMessage] = []
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            if not sock.poll(200):
                continue
            topic, payload = sock.recv_multipart()
            msg = decode(topic, payload)
            if isinstance(msg, RangeMessage):
                out.append(msg)
            elif isinstance(msg, HealthMessage) and msg.state == "stopped":
                return out
    finally:
        sock.close()
    raise AssertionError(f"no 'stopped' health within {timeout_s} s ({len(out)} ranges)")


def _normalised_miss(m: RangeMessage, cfg: FilterConfig) -> float:
    """|reading - estimate| over the spread the message states for their difference: its
    sigma, and the reading's own noise by paper eq. 2 from its lux_est and strength
    (sigma0 + k L) / S, with the 1 cm step's share."""
    assert m.raw_m is not None and m.range_m is not None and m.sigma_m is not None
    lux = m.lux_est or 0.0
    reading = (cfg.sigma0_m + cfg.k_m_per_lux * lux) / m.strength
    spread = math.sqrt(m.sigma_m**2 + reading**2 + cfg.resolution_m**2 / 12.0)
    return abs(m.raw_m - m.range_m) / spread


def test_a_real_roadside_log_replays_whole_and_honestly(start_daemon: Any, tmp_path: Path) -> None:
    rec = tmp_path / "roadside.lunarec"
    n = _record(rec)
    assert n == 3000
    endpoint = f"ipc://{tmp_path}/real.sock"
    daemon = start_daemon("--replay", str(rec), "--speed", str(REPLAY_SPEED), "--publish", endpoint)
    msgs = _ranges_until_stopped(endpoint, timeout_s=30.0)
    assert daemon.proc.wait(timeout=15) == 0
    assert [m.seq for m in msgs] == list(range(n)), "every frame of the log is published"

    cfg = FilterConfig()
    usable = [m for m in msgs if m.range_m is not None and m.raw_m is not None]
    assert len(usable) > 0.5 * n
    misses = [_normalised_miss(m, cfg) for m in usable]
    beyond5 = sum(u > 5.0 for u in misses) / len(misses)
    beyond3 = sum(u > 3.0 for u in misses) / len(misses)
    # measured: 0.16 % beyond 5 and 1.6 % beyond 3 (a Gaussian gives 0.00006 % and
    # 0.27 %: the roadside's clutter has heavier tails than noise); 0.51 % and 3.3 %
    # without the cover for readings the track does not explain (docs/filter.md)
    assert beyond5 < 0.005, f"{beyond5:.2%} of estimates over 5 stated sigmas off their reading"
    assert beyond3 < 0.03, f"{beyond3:.2%} of estimates over 3 stated sigmas off their reading"

    lux = [m.lux_est for m in msgs if m.lux_est is not None]
    assert len(lux) > 0.5 * n
    # measured: median 48 klux here, still about ten times the light there was (the
    # roadside's clutter between 30 ms readings reads as noise; docs/filter.md); an
    # estimate learnt from the tracker's innovations read 0.6-4 million lux on a real
    # log of a sweeping TF-Luna
    assert statistics.median(lux) < MAX_DAYLIGHT_LUX
