"""``lunad soak``: run the daemon for a long time under a seeded schedule of faults.

How this works. The soak process plays the sensor (a ``PtyDevice`` in this process),
runs ``lunad serve --config FILE`` as a real subprocess, as systemd would, and
subscribes to it like robot code. A seeded schedule of faults is built up front,
scaled to the duration (every fault type at least once, then repeated rounds in a
shuffled order) and printed; one executor thread drives it.

Exact accounting. A ``Ledger`` sees every byte the device writes to the pty (through
``PtyDevice``'s ``on_bytes_written`` hook) and runs a reference ``FrameParser`` over
them. The frames the reference finds are exactly what a correct daemon must publish,
numbered from 0 like the daemon's ``seq``. This counts collisions instead of avoiding
them: random garbage (and cut or corrupted frames) can, with probability about 1/256
per header candidate, form a frame with a good checksum, which a correct parser must
publish ("false" frames) and which may swallow the real frame that follows ("eaten").
Both are counted and reported, and the daemon is judged against the reference, so the
faults can use real random bytes, 0x59 and 0x5A included. Every published ``range``
message is matched by ``seq`` against the reference frame (distance and amp); a gap
in ``seq`` at the main subscriber, a mismatch, a frame never published, or a frame
published that the bytes did not contain is a loss. Bytes still in the pty when it is
unplugged die with it, and pyserial flushes the input on open; so before an unplug
(and at the end) the sensor is paused and the ledger drained (published == reference),
and after a replug the sensor stays silent until the daemon has sent its start-up
commands (it has opened the port).

Recovery time of a fault: from its end (for an unplug, the replug) to the first frame
the daemon read after it arriving at the main subscriber. A silent sensor must also
show ``waiting`` on health within 2 s.

Resources: RSS (``VmRSS``), open file descriptors and CPU ticks of the daemon are
sampled every few seconds; RSS growth per hour is a least-squares fit after warm-up.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lunad.daemon.bench import _cpu_ticks
from lunad.daemon.record import Recorder
from lunad.daemon.soak_bytes import DAEMON_INPUT, SENSOR_OUTPUT, compare
from lunad.daemon.source import Chunk
from lunad.protocol.commands import CommandReply
from lunad.protocol.frame import Frame, encode_frame, temp_raw_from_c
from lunad.protocol.messages import topic
from lunad.protocol.parser import FrameParser
from lunad.sim.pty_device import DeviceError, PtyDevice

NS = 1_000_000_000
SENSOR = "soak"
RECOVERY_LIMIT_S = 5.0  # every fault must recover within this (issue 7)
WAITING_LIMIT_S = 2.0  # a silent sensor shows state waiting within this (docs/architecture.md)
RSS_LIMIT_MIB_PER_H = 1.0
RSS_NOISE_FLOOR_KIB = 256.0  # below this, growth in a short window is allocator noise
STALL_LIMIT_S = 1.0  # sensor write -> daemon read, while a subscriber is slow
DRAIN_TIMEOUT_S = 5.0
MIN_DURATION_S = 50.0
SHORT_SOAK_S = 120.0  # up to this, the minimum fault durations, one round

FAULT_KINDS = (
    "slow_subscriber",
    "garbage",
    "corrupt",
    "cut",
    "silence",
    "unplug",
    "rate_burst",
    "baud",
    "churn",
    "sighup",
)
"""Every fault type; a soak exercises each at least once."""

FAULT_HELP = {
    "garbage": "bursts of 1-16 random bytes before a share of the frames",
    "corrupt": "a share of the frames sent with a wrong checksum",
    "cut": "frames cut after 1-8 bytes, then the next whole frame",
    "silence": "the sensor sends nothing (health must say waiting within 2 s)",
    "unplug": "the pty closed and its symlink removed, then a new pty at the same path",
    "rate_burst": "the sensor switches to 250 Hz, then to 1 Hz, then back",
    "baud": "baud-rate mismatch: random bytes at the frame rate, no valid frame",
    "slow_subscriber": "a subscriber with RCVHWM 10 stops reading, later resumes",
    "churn": "a subscriber connects and disconnects every 100 ms",
    "sighup": "the config file is changed (publish.health_interval_s) and reloaded",
}


# -- duration and schedule --------------------------------------------------------------

_DURATION_RE = re.compile(r"(\d+(?:\.\d+)?)([smhd]?)")
_UNIT_S = {"": 1.0, "s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}


def parse_duration(text: str) -> float:
    """Seconds in ``60s``, ``10m``, ``1h``, ``24h``, ``1h30m`` or plain ``90``.

    Raises:
        ValueError: anything else, or zero.
    """
    s = text.strip().lower()
    pos = 0
    total = 0.0
    parts = 0
    unitless = False
    for m in _DURATION_RE.finditer(s):
        if m.start() != pos:
            break
        total += float(m.group(1)) * _UNIT_S[m.group(2)]
        pos = m.end()
        parts += 1
        unitless = unitless or not m.group(2)
    if not s or pos != len(s) or total <= 0 or (unitless and parts > 1):
        raise ValueError(f"not a duration: {text!r} (use e.g. 60s, 10m, 1h, 24h or seconds)")
    return total


@dataclass(frozen=True)
class Fault:
    """One scheduled fault.

    Attributes:
        at_s: planned start, seconds after the stream started.
        kind: one of ``FAULT_KINDS``.
        duration_s: how long the fault itself lasts (for ``unplug``: time unplugged;
            for ``slow_subscriber``: time it does not read).
        params: kind-specific settings, all drawn from the seed.
    """

    at_s: float
    kind: str
    duration_s: float
    params: dict[str, float] = field(default_factory=dict)

    def describe(self) -> str:
        """One human line of what this fault does."""
        p = self.params
        k = self.kind
        if k == "garbage":
            return f"garbage before {p['rate']:.0%} of frames"
        if k == "corrupt":
            return f"wrong checksum on {p['rate']:.0%} of frames"
        if k == "cut":
            return f"{p['per_s']:.0f} cut frames a second"
        if k == "silence":
            return "sensor silent"
        if k == "unplug":
            return "unplugged, then replugged at the same path"
        if k == "rate_burst":
            return f"250 Hz for {p['fast_s']:.1f} s, then 1 Hz for {p['slow_s']:.1f} s"
        if k == "baud":
            return f"sensor at {p['baud']:.0f} Bd read at 115200 Bd: noise, no frames"
        if k == "slow_subscriber":
            return f"stops reading, resumes at {p['resume_at_s']:.1f} s"
        if k == "churn":
            return f"connect/disconnect every {p['interval_s'] * 1000:.0f} ms"
        if k == "sighup":
            return f"{p['reloads']:.0f} reload(s), {p['spacing_s']:.1f} s apart"
        return k


def _draw(kind: str, rng: random.Random, short: bool) -> tuple[float, dict[str, float], float]:
    """(duration, params, time the executor needs beyond the duration) of one fault."""

    def u(lo_short: float, hi_short: float, lo_long: float, hi_long: float) -> float:
        return round(rng.uniform(lo_short, hi_short) if short else rng.uniform(lo_long, hi_long), 1)

    if kind == "garbage":
        return u(2, 2.5, 3, 10), {"rate": round(rng.uniform(0.3, 0.6), 2)}, 0.5
    if kind == "corrupt":
        return u(2, 2.5, 3, 10), {"rate": round(rng.uniform(0.1, 0.3), 2)}, 0.5
    if kind == "cut":
        return u(2, 2.5, 3, 10), {"per_s": round(rng.uniform(5, 15))}, 0.5
    if kind == "silence":
        return u(2.5, 3.0, 2.5, 8), {}, 0.5
    if kind == "unplug":
        return u(0.5, 1.5, 0.5, 10), {}, 3.0  # drain, and the daemon's backoff (<= 2 s)
    if kind == "rate_burst":
        fast, slow = u(2, 2.5, 3, 15), u(3.5, 4.0, 4, 20)
        return round(fast + slow, 1), {"fast_s": fast, "slow_s": slow}, 1.5
    if kind == "baud":
        return u(2, 2.5, 3, 10), {"baud": rng.choice((9600, 57600, 230400))}, 0.5
    if kind == "churn":
        return u(2, 2.5, 2, 6), {"interval_s": 0.1}, 1.0
    if kind == "sighup":
        n = rng.randint(1, 2) if short else rng.randint(1, 3)
        return round(0.5 * n, 1), {"reloads": n, "spacing_s": 0.5}, 0.5
    if kind == "slow_subscriber":
        return u(15, 20, 20, 60), {"rcvhwm": 10}, 1.5
    raise ValueError(kind)


def build_schedule(duration_s: float, seed: int) -> list[Fault]:
    """The seeded fault schedule of a soak of ``duration_s`` seconds.

    Rounds of every fault type in a shuffled order, separated by gaps, until the
    duration is filled. ``slow_subscriber`` opens each round and its resume is placed in
    a gap after its stall, so its stall overlaps the round's sensor faults. Soaks up to
    ``SHORT_SOAK_S`` get one round of the short form (short faults, gaps of 0.5-1 s: 47 s
    at most, so it fits the shortest soak). A longer soak whose first long-form round
    (often 120-160 s) would not end 2 s before its end gets that short round instead, so
    every fault ends within the soak and every type is still exercised once.

    Raises:
        ValueError: the duration is too short for one round.
    """
    if duration_s < MIN_DURATION_S:
        raise ValueError(
            f"a soak needs at least {MIN_DURATION_S:.0f} s to exercise every fault once"
        )
    if duration_s > SHORT_SOAK_S:
        faults = _rounds(duration_s, seed, short=False)
        if faults is not None:
            return faults
    faults = _rounds(duration_s, seed, short=True)
    assert faults is not None  # a short round always fits (46.5 s at most, in 50 s)
    return faults


def _rounds(duration_s: float, seed: int, short: bool) -> list[Fault] | None:
    """``build_schedule``'s rounds in the short or long form; None when even the first
    round does not end 2 s before ``duration_s``."""
    rng = random.Random(seed)
    end = duration_s - 2.0
    faults: list[Fault] = []
    cursor = 2.0
    first = True
    while True:
        kinds = [k for k in FAULT_KINDS if k != "slow_subscriber"]
        rng.shuffle(kinds)
        round_faults: list[Fault] = []
        stall, sparams, _ = _draw("slow_subscriber", rng, short)
        resume_due = cursor + stall
        slow_at = cursor
        resume_at: float | None = None
        cursor += 0.5
        for kind in kinds:
            dur, params, extra = _draw(kind, rng, short)
            round_faults.append(Fault(round(cursor, 1), kind, dur, params))
            cursor += dur + extra + (rng.uniform(0.5, 1.0) if short else rng.uniform(3, 12))
            if resume_at is None and cursor >= resume_due:
                resume_at = cursor
                cursor += 2.0
        if resume_at is None:
            resume_at = max(cursor, resume_due)
            cursor = resume_at + 2.0
        slow = Fault(
            round(slow_at, 1),
            "slow_subscriber",
            round(resume_at - slow_at, 1),
            {**sparams, "resume_at_s": round(resume_at, 1)},
        )
        if cursor > end:
            if first:
                return None
            break
        faults.append(slow)
        faults.extend(round_faults)
        first = False
        if short or cursor > end:
            break
    return sorted(faults, key=lambda f: f.at_s)


def format_schedule(faults: list[Fault], seed: int, duration_s: float, rate_hz: int) -> str:
    """The schedule as printed at the start of a soak."""
    lines = [
        f"soak schedule: seed {seed}, {_hms(duration_s)}, sensor at {rate_hz} Hz, "
        f"{len(faults)} faults",
        f"{'at':>9}  {'fault':<16}{'lasts':>8}  what",
    ]
    for f in faults:
        lines.append(f"{f.at_s:8.1f}s  {f.kind:<16}{f.duration_s:7.1f}s  {f.describe()}")
    return "\n".join(lines)


# -- the device and the ledger --------------------------------------------------------


def _raw_m(dist: int) -> float | None:
    """``raw_m`` as the daemon publishes it for a frame's distance field (cm)."""
    if dist == 0 or dist == 0xFFFF:
        return None
    return round(dist / 100.0, 4)


class Ledger:
    """The reference stream (from the bytes written) against the published stream.

    Thread-safe: the device thread calls ``on_written``, the subscriber ``on_range``.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._parser = FrameParser(follow_format_replies=False)  # as the daemon's
        self._carry = b""
        self._pending: deque[tuple[int, int]] = deque()  # good frames written, not yet found
        self.good_sent = 0  # good frames fully written (equals PtyDevice.frames_sent)
        self.ref_count = 0  # frames a correct parser finds in the bytes written
        self.false_frames = 0  # of those, formed by garbage (not a frame the sensor sent)
        self.eaten = 0  # good frames swallowed by a false frame (a correct parser must)
        self.next_seq = 0  # last published seq + 1
        self.published = 0  # distinct range messages received
        self.gaps = 0  # frames lost as gaps in seq
        self.missing = 0  # reference frames never published (found when draining)
        self.unexpected = 0  # published frames the bytes did not contain
        self.mismatched = 0  # published seq whose distance/amp differ from the reference
        self.backwards = 0  # seq went back: the daemon restarted
        self.duplicates = 0  # last-value-cache repeats (not a loss)
        self._offset = 0  # reference index - seq, after a loss was found
        self._expected: dict[int, tuple[tuple[float | None, int], int]] = {}
        self._early: dict[int, tuple[tuple[float | None, int], int]] = {}
        self.read_lat_max_ns = 0  # bytes written -> daemon read them (its t_mono_ns)
        self.window_read_lat_max_ns = 0  # the same since ``window_start()``

    def window_start(self) -> None:
        """Start a window for ``window_read_lat_max_ns`` (a slow subscriber's stall)."""
        with self._lock:
            self.window_read_lat_max_ns = 0

    def _read_latency(self, t_write: int, t_read: int) -> None:
        if t_write and t_read:
            lat = t_read - t_write
            if lat > self.read_lat_max_ns:
                self.read_lat_max_ns = lat
            if lat > self.window_read_lat_max_ns:
                self.window_read_lat_max_ns = lat

    @property
    def lost(self) -> int:
        """Valid frames that reached the daemon and are missing from the stream."""
        return self.gaps + self.missing + self.mismatched + self.unexpected + self.backwards

    def on_written(self, data: bytes, ends: list[int], t_ns: int = 0) -> None:
        """Bytes the device wrote at ``t_ns``; ``ends``: where good frames end in ``data``.

        The parser is fed each byte once. The last 8 bytes of earlier writes are kept
        apart (``_carry``) only to read a good frame that began in an earlier write.
        A good frame the parser holds until the next bytes decide it (its checksum byte
        could start a header) is matched when it comes out, in a later write.
        """
        with self._lock:
            look = self._carry + data
            off = len(self._carry)
            pos = 0
            feed = self._parser.feed
            for e in ends:
                good = look[off + e - 9 : off + e]
                self._pending.append((good[2] | good[3] << 8, good[4] | good[5] << 8))
                self.good_sent += 1
                self._account(feed(data[pos:e], 0), t_ns)
                pos = e
            self._account(feed(data[pos:], 0), t_ns)
            self._carry = look[-8:]

    def _account(self, items: list[Frame | CommandReply], t_ns: int) -> None:
        """Match the frames the reference parser found against the good frames written:
        one that is none of them is false; good ones passed over were eaten."""
        pending = self._pending
        for f in items:
            if type(f) is not Frame:
                continue
            key = (f.dist, f.amp)
            if key in pending:
                while pending[0] != key:
                    pending.popleft()
                    self.eaten += 1
                pending.popleft()
            else:
                self.false_frames += 1
            self._reference(f, t_ns)

    def _reference(self, f: Frame, t_write: int) -> None:
        key = (_raw_m(f.dist), f.amp)
        seq = self.ref_count - self._offset
        self.ref_count += 1
        early = self._early.pop(seq, None)
        if early is not None:
            self.mismatched += early[0] != key
            self._read_latency(t_write, early[1])
        elif seq >= self.next_seq:
            self._expected[seq] = (key, t_write)

    def on_range(self, seq: int, raw_m: float | None, amp: int, t_read_ns: int = 0) -> bool:
        """A published range message (read by the daemon at ``t_read_ns``); False for a
        repeat (the last-value cache)."""
        with self._lock:
            last = self.next_seq - 1
            if seq == last:
                self.duplicates += 1
                return False
            if seq < last:
                self.backwards += 1
                return False
            if seq > self.next_seq:
                self.gaps += seq - self.next_seq
                for s in range(self.next_seq, seq):
                    self._expected.pop(s, None)
            self.next_seq = seq + 1
            self.published += 1
            key = (raw_m, amp)
            want = self._expected.pop(seq, None)
            if want is not None:
                self.mismatched += want[0] != key
                self._read_latency(want[1], t_read_ns)
            else:
                self._early[seq] = (key, t_read_ns)
            return True

    def settled(self) -> bool:
        """Every reference frame published and matched, nothing extra."""
        with self._lock:
            return self.next_seq == self.ref_count - self._offset and not self._early

    def close_books(self) -> tuple[int, int]:
        """After a drain: count what never came and what should not have; resync.

        Returns (missing, unexpected) found now.
        """
        with self._lock:
            missing = max(0, self.ref_count - self._offset - self.next_seq)
            unexpected = len(self._early)
            self.missing += missing
            self.unexpected += unexpected
            self._offset = self.ref_count - self.next_seq
            self._expected.clear()
            self._early.clear()
            return missing, unexpected

    def reset_parser(self) -> None:
        """The pty is gone (unplug): the daemon drops its partial frame, so do we."""
        with self._lock:
            self._parser.reset()
            self._carry = b""

    def summary(self) -> dict[str, int]:
        """The counters, for the report. ``undecided_frames``: good frames written that
        the reference parser has not found yet: one held until the next bytes decide it
        (its checksum byte is 0x59), or swallowed by a false frame with no good frame
        after it to show it."""
        with self._lock:
            return {
                "frames_sent": self.good_sent,
                "reference_frames": self.ref_count,
                "false_frames": self.false_frames,
                "eaten_frames": self.eaten,
                "undecided_frames": len(self._pending),
                "published": self.published,
                "lost": self.lost,
                "gaps": self.gaps,
                "missing": self.missing,
                "unexpected": self.unexpected,
                "mismatched": self.mismatched,
                "seq_backwards": self.backwards,
                "duplicates": self.duplicates,
            }


# -- subscribers ------------------------------------------------------------------


class _Watch:
    def __init__(self, kind: str, after_ns: int, state: str | None) -> None:
        self.kind, self.after_ns, self.state = kind, after_ns, state
        self.t_ns: int | None = None
        self.event = threading.Event()


class LatencyHistogram:
    """Log-spaced histogram of latencies (4 buckets per octave of microseconds)."""

    def __init__(self) -> None:
        self.counts: dict[int, int] = {}
        self.n = 0
        self.max_us = 0.0

    def add(self, us: float) -> None:
        b = int(4 * math.log2(max(us, 1.0)))
        self.counts[b] = self.counts.get(b, 0) + 1
        self.n += 1
        self.max_us = max(self.max_us, us)

    def quantile(self, q: float) -> float:
        """Upper edge of the bucket holding quantile ``q``, microseconds."""
        if not self.n:
            return float("nan")
        k = q * self.n
        seen = 0
        for b in sorted(self.counts):
            seen += self.counts[b]
            if seen >= k:
                return min(2 ** ((b + 1) / 4), self.max_us)
        return self.max_us


class MainSubscriber(threading.Thread):
    """Reads every message promptly (RCVHWM unlimited), as robot code would, and checks
    it against the ledger and the schema; answers "first frame / health state after t"."""

    def __init__(self, endpoint: str, ledger: Ledger) -> None:
        super().__init__(name="soak-sub", daemon=True)
        import zmq

        self._zmq = zmq
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, 0)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RECONNECT_IVL, 100)
        for kind in ("range", "health"):
            self.sock.setsockopt(zmq.SUBSCRIBE, topic(kind, SENSOR))
        self.sock.connect(endpoint)
        self.ledger = ledger
        self.stop = threading.Event()
        self.bad_messages = 0
        self.health_msgs = 0
        self.last_health: Any = None
        self.states: list[tuple[int, str]] = []
        self.latency = LatencyHistogram()
        self.window_max_lat_us = 0.0
        self.last_range_ns = 0
        self.read_times: deque[int] = deque(maxlen=30_000)  # daemon read time of each frame
        self._watches: list[_Watch] = []
        self._wlock = threading.Lock()

    def watch(self, kind: str, after_ns: int, state: str | None = None) -> _Watch:
        """Register before the event: the first ``kind`` message after ``after_ns``
        (range: read by the daemon at or after it; health: with ``state``)."""
        w = _Watch(kind, after_ns, state)
        with self._wlock:
            self._watches.append(w)
        return w

    def wait(self, w: _Watch, timeout_s: float) -> float | None:
        """Seconds from ``after_ns`` to the watched message's arrival, or None."""
        w.event.wait(timeout_s)
        with self._wlock:
            if w in self._watches:
                self._watches.remove(w)
        return None if w.t_ns is None else (w.t_ns - w.after_ns) / NS

    def _notify(self, kind: str, t_ns: int, t_read: int, state: str | None) -> None:
        with self._wlock:
            for w in self._watches:
                if w.t_ns is not None or w.kind != kind:
                    continue
                if kind == "range" and t_read >= w.after_ns:
                    w.t_ns = t_ns
                    w.event.set()
                elif kind == "health" and t_ns >= w.after_ns and state == w.state:
                    w.t_ns = t_ns
                    w.event.set()

    def run(self) -> None:
        from pydantic import ValidationError

        from lunad.protocol.messages import RangeMessage, decode

        zmq = self._zmq
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        mono = time.monotonic_ns
        while not self.stop.is_set():
            if not poller.poll(100):
                continue
            while True:
                try:
                    parts = self.sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                t = mono()
                try:
                    if len(parts) != 2:
                        raise ValueError("not two frames")
                    msg = decode(parts[0], parts[1])
                except (ValueError, ValidationError):
                    self.bad_messages += 1
                    continue
                if isinstance(msg, RangeMessage):
                    if not self.ledger.on_range(msg.seq, msg.raw_m, msg.amp, msg.t_mono_ns):
                        continue
                    self.read_times.append(msg.t_mono_ns)
                    lat_us = (t - msg.t_mono_ns) / 1000
                    self.latency.add(lat_us)
                    self.window_max_lat_us = max(self.window_max_lat_us, lat_us)
                    self.last_range_ns = t
                    self._notify("range", t, msg.t_mono_ns, None)
                else:
                    self.health_msgs += 1
                    self.last_health = msg
                    if not self.states or self.states[-1][1] != msg.state:
                        self.states.append((t, msg.state))
                    self._notify("health", t, t, msg.state)

    def close(self) -> None:
        self.stop.set()
        self.join(2.0)
        self.sock.close(linger=0)
        self.ctx.term()


class SlowSubscriber(threading.Thread):
    """A subscriber with a small RCVHWM that stops reading while ``reading`` is clear."""

    def __init__(self, endpoint: str, rcvhwm: int) -> None:
        super().__init__(name="soak-slow-sub", daemon=True)
        import zmq

        self._zmq = zmq
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, rcvhwm)
        self.sock.setsockopt(zmq.RCVBUF, 4096)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, topic("range", SENSOR))
        self.sock.connect(endpoint)
        self.reading = threading.Event()
        self.reading.set()
        self.stop = threading.Event()
        self.received = 0
        self.lost = 0
        self.last_seq: int | None = None

    def run(self) -> None:
        from lunad.daemon.bench import _seq_of

        zmq = self._zmq
        while not self.stop.is_set():
            if not self.reading.wait(0.1):
                continue
            if not self.sock.poll(100):
                continue
            while self.reading.is_set():
                try:
                    parts = self.sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                seq = _seq_of(parts[1])
                last = self.last_seq
                if last is not None and seq <= last:
                    continue
                if last is not None and seq > last + 1:
                    self.lost += seq - last - 1
                self.last_seq = seq
                self.received += 1

    def close(self) -> None:
        self.stop.set()
        self.reading.set()
        self.join(2.0)
        self.sock.close(linger=0)
        self.ctx.term()


# -- resources --------------------------------------------------------------------------


def _vm_rss_kib(pid: int) -> float:
    """Resident set size of ``pid`` (VmRSS), KiB."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return float(line.split()[1])
    return float("nan")


def _fd_count(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


@dataclass
class Sample:
    """One resource sample of the daemon."""

    t_s: float
    rss_kib: float
    fds: int
    cpu_ticks: int
    published: int


def fit_slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of ys over xs (0 with fewer than two points)."""
    n = len(xs)
    if n < 2:
        return 0.0
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    if sxx == 0:
        return 0.0
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx


# -- results and verdict ----------------------------------------------------------------


@dataclass
class FaultResult:
    """What happened when one fault ran."""

    kind: str
    at_s: float
    duration_s: float
    recovery_s: float | None
    ok: bool
    note: str = ""
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class SoakReport:
    """Everything a soak measured, and its verdict."""

    seed: int
    duration_s: float
    rate_hz: int
    elapsed_s: float = 0.0
    schedule: list[Fault] = field(default_factory=list)
    faults: list[FaultResult] = field(default_factory=list)
    accounting: dict[str, int] = field(default_factory=dict)
    slow_subscriber_lost: int = 0
    slow_subscriber_received: int = 0
    frames_unread: int = 0
    health: dict[str, Any] = field(default_factory=dict)
    bad_messages: int = 0
    latency_us: dict[str, float] = field(default_factory=dict)
    samples: list[Sample] = field(default_factory=list)
    warmup_s: float = 0.0
    rss: dict[str, float] = field(default_factory=dict)
    fds: dict[str, float] = field(default_factory=dict)
    cpu: dict[str, float] = field(default_factory=dict)
    daemon_pid: int = 0
    daemon_died_at_s: float | None = None
    daemon_exit_code: int | None = None
    daemon_stop_s: float | None = None
    log_tracebacks: int = 0
    byte_check: dict[str, Any] = field(default_factory=dict)
    """With ``--keep-logs``: the two byte recordings compared (``soak_bytes.compare``)."""
    aborted: str = ""
    passed: bool = False
    conditions: dict[str, bool] = field(default_factory=dict)
    reasons: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["samples"] = [[s.t_s, s.rss_kib, s.fds, s.cpu_ticks, s.published] for s in self.samples]
        d["samples_columns"] = ["t_s", "rss_kib", "fds", "cpu_ticks", "published"]
        return d


def judge(report: SoakReport) -> SoakReport:
    """Fill in ``conditions``, ``reasons`` and ``passed`` from the measurements."""
    acc = report.accounting
    reasons: list[str] = []
    lost = acc.get("lost", 0)
    no_loss = lost == 0 and report.bad_messages == 0 and acc.get("published", 0) > 0
    if lost:
        parts = [
            f"{acc[k]} {k.replace('_', ' ')}"
            for k in ("gaps", "missing", "mismatched", "unexpected", "seq_backwards")
            if acc.get(k)
        ]
        reasons.append(f"{lost} valid frame(s) lost or wrong: {', '.join(parts)}")
    if report.bad_messages:
        reasons.append(f"{report.bad_messages} message(s) broke the schema")
    if not acc.get("published"):
        reasons.append("nothing was published")
    kinds_done = {f.kind for f in report.faults}
    missing_kinds = [k for k in FAULT_KINDS if k not in kinds_done]
    failed = [f for f in report.faults if not f.ok]
    recovered = not failed and not missing_kinds
    for f in failed[:5]:
        rec = "never" if f.recovery_s is None else f"{f.recovery_s:.2f} s"
        reasons.append(f"{f.kind} at {f.at_s:.1f} s failed (recovery {rec}): {f.note}")
    if len(failed) > 5:
        reasons.append(f"... and {len(failed) - 5} more faults failed")
    if missing_kinds:
        reasons.append(f"fault types not exercised: {', '.join(missing_kinds)}")
    rss_ok = bool(report.rss.get("ok", False))
    if not rss_ok:
        reasons.append(
            f"RSS grew {report.rss.get('growth_kib', float('nan')):.0f} KiB after warm-up "
            f"({report.rss.get('mib_per_h', float('nan')):.2f} MiB/h), "
            f"allowed {report.rss.get('allowed_kib', float('nan')):.0f} KiB"
        )
    fd_ok = bool(report.fds.get("ok", False))
    if not fd_ok:
        reasons.append(
            f"open files grew from {report.fds.get('baseline')} to {report.fds.get('end')}"
        )
    alive = report.daemon_died_at_s is None and not report.aborted
    if report.daemon_died_at_s is not None:
        reasons.append(f"the daemon exited at {report.daemon_died_at_s:.1f} s")
    if report.aborted:
        reasons.append(f"soak aborted: {report.aborted}")
    clean = report.daemon_exit_code == 0 and report.log_tracebacks == 0
    if report.daemon_exit_code != 0 and report.daemon_died_at_s is None:
        reasons.append(f"the daemon exited with {report.daemon_exit_code} on SIGTERM")
    if report.log_tracebacks:
        reasons.append(f"{report.log_tracebacks} traceback(s) in the daemon's log")
    report.conditions = {
        "no_frame_lost": no_loss,
        "every_fault_recovered_5s": recovered,
        "rss_growth_under_1mib_per_h": rss_ok,
        "no_fd_growth": fd_ok,
        "daemon_never_restarted": alive,
        "clean_exit": clean,
    }
    report.reasons = reasons
    report.passed = all(report.conditions.values())
    return report


def rss_verdict(samples: list[Sample], warmup_s: float) -> dict[str, float]:
    """RSS after warm-up: fitted growth per hour and whether it is within the limit.

    The limit is 1 MiB/h over the window after warm-up; for a short window, where a
    fit extrapolates a page or two of allocator noise to an hour, at least
    ``RSS_NOISE_FLOOR_KIB`` of growth over the window is allowed.
    """
    post = [s for s in samples if s.t_s >= warmup_s]
    if len(post) < 3:
        post = samples[len(samples) // 2 :]
    xs = [s.t_s for s in post]
    ys = [s.rss_kib for s in post]
    slope = fit_slope(xs, ys)  # KiB/s
    window = (xs[-1] - xs[0]) if len(xs) >= 2 else 0.0
    growth = slope * window
    allowed = max(RSS_LIMIT_MIB_PER_H * 1024 * window / 3600, RSS_NOISE_FLOOR_KIB)
    rss = [s.rss_kib for s in samples] or [float("nan")]
    return {
        "start_mib": rss[0] / 1024,
        "end_mib": rss[-1] / 1024,
        "max_mib": max(rss) / 1024,
        "window_s": window,
        "mib_per_h": slope * 3600 / 1024,
        "growth_kib": growth,
        "allowed_kib": allowed,
        "ok": float(growth < allowed),
    }


# -- the soak ---------------------------------------------------------------------------


class DaemonDied(Exception):
    """The soak cannot go on: the daemon process exited, or the virtual sensor stopped."""


class Soak:
    """One soak run. ``run()`` returns the judged ``SoakReport``."""

    def __init__(
        self,
        duration_s: float,
        seed: int = 0,
        rate_hz: int = 100,
        progress: Callable[[str], None] | None = None,
        keep_logs: Path | str | None = None,
        schedule: list[Fault] | None = None,
        sample_s: float | None = None,
    ) -> None:
        self.duration_s = duration_s
        self.seed = seed
        self.rate_hz = rate_hz
        self.progress = progress
        self.keep_logs = Path(keep_logs) if keep_logs else None
        self.schedule = schedule if schedule is not None else build_schedule(duration_s, seed)
        self.sample_s = sample_s or (2.0 if duration_s <= 900 else 10.0)
        self.rng = random.Random(seed ^ 0x50A4)
        self.ledger = Ledger()
        self.report = SoakReport(seed=seed, duration_s=duration_s, rate_hz=rate_hz)
        self.report.schedule = list(self.schedule)
        self._reloads = 0
        self._health_interval = 1.0
        self._t0 = 0.0
        self._stop_sampler = threading.Event()
        self._slow: SlowSubscriber | None = None
        self._slow_fault: Fault | None = None
        self._slow_started = 0.0
        self._slow_unread0 = 0
        self._lag_max = 0.0  # how late the soak's own ticker woke: its scheduling lag
        self._sensor_rec: Recorder | None = None  # with keep_logs: the sensor's bytes
        self._lag_window_max = 0.0

    # -- helpers --

    def _now_s(self) -> float:
        return time.monotonic() - self._t0

    def _config_text(self) -> str:
        record = f'record = "{self.keep_logs / DAEMON_INPUT}"\n' if self.keep_logs else ""
        return (
            'log_level = "info"\n'
            f'[sensor]\nname = "{SENSOR}"\nframe_rate_hz = {self.rate_hz}\n'
            f'[source]\ndevice = "{self.link}"\n{record}'
            f'[publish]\nendpoint = "{self.endpoint}"\n'
            f"health_interval_s = {self._health_interval}\n"
        )

    def _check_alive(self) -> None:
        error = self.dev.error
        if error is not None:  # the soak's own virtual sensor: nothing left to measure
            raise DaemonDied(f"the virtual sensor stopped: {type(error).__name__}: {error}")
        code = self.proc.poll()
        if code is not None:
            if self.report.daemon_died_at_s is None:
                self.report.daemon_died_at_s = self._now_s()
                self.report.daemon_exit_code = code
            raise DaemonDied(f"the daemon exited with code {code}")

    def _sleep(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self._check_alive()
            time.sleep(min(left, 0.1))

    def _recovery(self, t_end_ns: int, w: _Watch | None = None) -> float | None:
        if w is None:
            w = self.sub.watch("range", t_end_ns)
        return self.sub.wait(w, RECOVERY_LIMIT_S + 1.0)

    def _drain(self) -> tuple[bool, int, int, float]:
        """Sensor paused by the caller: wait until every reference frame was published."""
        t = time.monotonic()
        time.sleep(0.05)
        while time.monotonic() - t < DRAIN_TIMEOUT_S:
            if self.ledger.settled():
                break
            self._check_alive()
            time.sleep(0.01)
        took = time.monotonic() - t
        missing, unexpected = self.ledger.close_books()
        return missing == 0 and unexpected == 0, missing, unexpected, took

    # -- faults --

    def _fault(self, f: Fault) -> FaultResult:
        dev = self.dev
        start = self._now_s()
        details: dict[str, Any] = {}
        note = ""
        ok_extra = True
        d = f.duration_s
        if f.kind in ("garbage", "corrupt"):
            before = self._parser_counts()
            setattr(dev, f"{f.kind}_rate", f.params["rate"])
            self._sleep(d)
            setattr(dev, f"{f.kind}_rate", 0.0)
            t_end = time.monotonic_ns()
            rec = self._recovery(t_end)
            details["frames_corrupted" if f.kind == "corrupt" else "garbage_bytes"] = (
                dev.frames_corrupted if f.kind == "corrupt" else dev.garbage_bytes
            )
            details["parser_before"] = before
        elif f.kind == "cut":
            temp = temp_raw_from_c(40.0)
            end = time.monotonic() + d
            cuts = 0
            while time.monotonic() < end:
                frame = encode_frame(self.rng.randint(150, 250), self.rng.randint(500, 9000), temp)
                dev.inject_garbage(frame[: self.rng.randint(1, 8)])
                cuts += 1
                self._sleep(1.0 / f.params["per_s"])
            t_end = time.monotonic_ns()
            rec = self._recovery(t_end)
            details["cuts"] = cuts
        elif f.kind == "silence":
            t_start = time.monotonic_ns()
            waiting = self.sub.watch("health", t_start, "waiting")
            dev.pause(d)
            w_s = self.sub.wait(waiting, d)
            self._sleep(max(0.0, d - (time.monotonic_ns() - t_start) / NS))
            t_end = t_start + int(d * NS)
            rec = self._recovery(t_end)
            details["waiting_after_s"] = w_s
            ok_extra = w_s is not None and w_s <= WAITING_LIMIT_S
            note = f"waiting after {w_s:.2f} s" if w_s is not None else "never reported waiting"
        elif f.kind == "unplug":
            dev.pause(1e9)
            drained, missing, _unexpected, took = self._drain()
            details.update(drained=drained, missing=missing, drain_s=round(took, 3))
            t_unplug = time.monotonic_ns()
            reconnecting = self.sub.watch("health", t_unplug, "reconnecting")
            dev.unplug()
            self.ledger.reset_parser()
            self._sleep(d)
            r_s = self.sub.wait(reconnecting, 0.1)
            cmds = dev.commands_received
            w = self.sub.watch("range", 0)
            dev.replug()
            t_replug = time.monotonic_ns()
            w.after_ns = t_replug
            while dev.commands_received == cmds and time.monotonic_ns() - t_replug < 6 * NS:
                self._check_alive()
                time.sleep(0.005)
            dev.pause(0)
            t_end = t_replug
            rec = self._recovery(t_end, w)
            details["reconnecting_after_s"] = r_s
            ok_extra = drained and r_s is not None
            note = "drained, " if drained else f"{missing} frames missing at drain, "
            note += "reconnecting seen" if r_s is not None else "no reconnecting on health"
        elif f.kind == "rate_burst":
            settings = dev.sensor.settings
            t_fast = time.monotonic_ns()
            sent0 = dev.frames_sent
            dev.sensor.settings = dataclasses.replace(settings, rate_hz=250)
            self._sleep(f.params["fast_s"])
            t_slow = time.monotonic_ns()
            sent_fast = dev.frames_sent - sent0
            dev.sensor.settings = dataclasses.replace(dev.sensor.settings, rate_hz=1)
            self._sleep(f.params["slow_s"])
            t_end = time.monotonic_ns()
            dev.sensor.settings = dataclasses.replace(dev.sensor.settings, rate_hz=self.rate_hz)
            rec = self._recovery(t_end)
            reads = list(self.sub.read_times)  # counted by the daemon's read time
            n_fast = sum(1 for t in reads if t_fast <= t < t_slow)
            n_slow = sum(1 for t in reads if t_slow <= t < t_end)
            flaps = sum(1 for t, s in self.sub.states if t >= t_slow and s == "waiting")
            fast_s = (t_slow - t_fast) / NS
            details.update(
                fps_250=round(n_fast / fast_s, 1),
                sensor_fps_250=round(sent_fast / fast_s, 1),
                fps_1=round(n_slow / ((t_end - t_slow) / NS), 2),
                waiting_at_1hz=flaps,
            )
            # Keeping up: the daemon read, in the fast window, what the sensor wrote in it
            # (a starved soak process writes fewer than 250 a second; a frame written
            # just before the window closes may be read just after it).
            ok_extra = n_fast >= 0.9 * sent_fast - 5
            note = (
                f"{details['fps_250']:.0f} fps read at 250 Hz (the sensor wrote "
                f"{details['sensor_fps_250']:.0f}/s), {details['fps_1']:.2f} fps at 1 Hz, "
                f"{flaps} waiting state(s) at 1 Hz"
            )
        elif f.kind == "baud":
            dev.pause(1e9)
            end = time.monotonic() + d
            t_last = time.monotonic()
            sent = 0
            while time.monotonic() < end:
                self._sleep(0.02)
                now = time.monotonic()
                n = round(9 * self.rate_hz * (now - t_last))
                t_last = now
                dev.inject_garbage(self.rng.randbytes(n))
                sent += n
            states = {s for t, s in self.sub.states if t / NS >= end - d}
            t_end = time.monotonic_ns()
            dev.pause(0)
            rec = self._recovery(t_end)
            details.update(noise_bytes=sent, states=sorted(states))
            note = f"{sent} noise bytes"
        elif f.kind == "churn":
            from lunad.protocol.client import Subscriber

            fd0 = _fd_count(self.proc.pid)
            end = time.monotonic() + d
            n = 0
            while time.monotonic() < end:
                s = Subscriber(self.endpoint, sensor=SENSOR)
                s.recv(timeout_s=0.0)
                self._sleep(f.params["interval_s"] / 2)
                s.close()
                n += 1
                self._sleep(f.params["interval_s"] / 2)
            t_end = time.monotonic_ns()
            fd_peak = _fd_count(self.proc.pid)
            rec = None
            while time.monotonic_ns() - t_end < RECOVERY_LIMIT_S * NS:
                if _fd_count(self.proc.pid) <= fd0:
                    rec = (time.monotonic_ns() - t_end) / NS
                    break
                self._check_alive()
                time.sleep(0.05)
            details.update(connections=n, fds_before=fd0, fds_after=_fd_count(self.proc.pid))
            details["fds_right_after"] = fd_peak
            note = f"{n} connections, fds {fd0} -> {fd_peak} -> {details['fds_after']}"
        elif f.kind == "sighup":
            recs = []
            for _ in range(int(f.params["reloads"])):
                self._health_interval = 0.5 if self._health_interval == 1.0 else 1.0
                self.config.write_text(self._config_text())
                t_sig = time.monotonic_ns()
                self.proc.send_signal(signal.SIGHUP)
                self._reloads += 1
                while self._log_count("configuration reloaded") < self._reloads:
                    self._check_alive()
                    if time.monotonic_ns() - t_sig > RECOVERY_LIMIT_S * NS:
                        break
                    time.sleep(0.01)
                t_done = time.monotonic_ns()
                r = self._recovery(t_done)
                recs.append(None if r is None else r + (t_done - t_sig) / NS)
                self._sleep(f.params["spacing_s"])
            rec = None if any(r is None for r in recs) else max(recs)  # type: ignore[type-var]
            reloaded = self._log_count("configuration reloaded")
            ok_extra = reloaded == self._reloads
            details.update(reloads_logged=reloaded, reloads_sent=self._reloads)
            note = f"{reloaded}/{self._reloads} reloads logged so far"
        elif f.kind == "slow_subscriber":
            self._slow = SlowSubscriber(self.endpoint, int(f.params["rcvhwm"]))
            self._slow.start()
            self._slow_fault = f
            self._sleep(0.5)
            self._slow.reading.clear()
            self._slow_started = self._now_s()
            self._slow_unread0 = dev.frames_unread
            self.sub.window_max_lat_us = 0.0
            self.ledger.window_start()
            self._lag_window_max = 0.0
            return FaultResult(f.kind, round(start, 2), 0.0, None, True, "stopped reading")
        else:
            raise ValueError(f.kind)
        ok = rec is not None and rec <= RECOVERY_LIMIT_S and ok_extra
        return FaultResult(
            f.kind, round(start, 2), round(self._now_s() - start, 2), rec, ok, note, details
        )

    def _resume_slow(self, result: FaultResult) -> None:
        slow = self._slow
        assert slow is not None
        target = self.ledger.next_seq - 1
        t = time.monotonic_ns()
        stall_max_lat = self.sub.window_max_lat_us / 1e6
        read_lat = self.ledger.window_read_lat_max_ns / NS
        soak_lag = self._lag_window_max
        unread = self.dev.frames_unread - self._slow_unread0
        slow.reading.set()
        rec = None
        while time.monotonic_ns() - t < (RECOVERY_LIMIT_S + 1) * NS:
            if slow.last_seq is not None and slow.last_seq >= target:
                rec = (time.monotonic_ns() - t) / NS
                break
            self._check_alive()
            time.sleep(0.01)
        slow.close()
        self._slow = None
        self.report.slow_subscriber_lost += slow.lost
        self.report.slow_subscriber_received += slow.received
        result.duration_s = round(self._now_s() - self._slow_started, 2)
        result.recovery_s = rec
        # A stall of the whole machine (the soak's own ticker oversleeping) is not the
        # daemon's: it is allowed on top of the limit.
        no_stall = read_lat <= STALL_LIMIT_S + soak_lag and unread == 0
        result.ok = rec is not None and rec <= RECOVERY_LIMIT_S and no_stall
        result.details.update(
            hwm_lost=slow.lost,
            received=slow.received,
            main_max_latency_s=round(stall_max_lat, 4),
            daemon_read_max_latency_s=round(read_lat, 4),
            soak_lag_max_s=round(soak_lag, 4),
            sensor_frames_unread=unread,
        )
        result.note = (
            f"it lost {slow.lost} (HWM, expected), caught up; meanwhile sensor->daemon read "
            f"max {read_lat * 1000:.1f} ms, read->main sub max {stall_max_lat * 1000:.0f} ms, "
            f"soak's own lag max {soak_lag * 1000:.0f} ms"
        )

    def _parser_counts(self) -> dict[str, int]:
        h = self.sub.last_health
        if h is None:
            return {}
        return {"checksum_errors": h.checksum_errors, "bytes_discarded": h.bytes_discarded}

    def _log_count(self, text: str) -> int:
        try:
            return self.log_path.read_text(errors="replace").count(text)
        except OSError:
            return 0

    # -- sampling --

    def _sample(self) -> Sample | None:
        pid = self.proc.pid
        try:
            return Sample(
                round(self._now_s(), 2),
                _vm_rss_kib(pid),
                _fd_count(pid),
                _cpu_ticks(pid),
                self.ledger.published,
            )
        except (OSError, ValueError, IndexError):
            return None

    def _ticker(self) -> None:
        """Measures the soak process's own scheduling lag (a 50 ms sleep that overslept):
        latencies at the subscriber above it are the soak's, not the daemon's."""
        while not self._stop_sampler.is_set():
            t = time.monotonic()
            time.sleep(0.05)
            lag = time.monotonic() - t - 0.05
            self._lag_max = max(self._lag_max, lag)
            self._lag_window_max = max(self._lag_window_max, lag)

    def _sampler(self) -> None:
        next_progress = 60.0
        while not self._stop_sampler.wait(self.sample_s):
            s = self._sample()
            if s is not None:
                self.report.samples.append(s)
            if self.progress is not None and self._now_s() >= next_progress:
                next_progress += 60.0
                self.progress(self.progress_line())

    def progress_line(self) -> str:
        """One line of how the soak is going."""
        acc = self.ledger.summary()
        done = len(self.report.faults)
        failed = sum(1 for f in self.report.faults if not f.ok)
        s = self.report.samples[-1] if self.report.samples else None
        first = self.report.samples[0] if self.report.samples else None
        cpu = ""
        if s and first and s.published > first.published:
            hz = os.sysconf("SC_CLK_TCK")
            us = (s.cpu_ticks - first.cpu_ticks) / hz * 1e6 / (s.published - first.published)
            cpu = f", CPU {us:.0f} us/frame"
        res = f" | RSS {s.rss_kib / 1024:.1f} MiB, {s.fds} fds{cpu}" if s else ""
        return (
            f"[soak {_hms(self._now_s())}/{_hms(self.duration_s)}] faults {done}/"
            f"{len(self.schedule)} ({failed} failed), sent {acc['frames_sent']}, "
            f"published {acc['published']}, lost {acc['lost']}{res}"
        )

    # -- the run --

    def run(self) -> SoakReport:
        """Start everything, drive the schedule, stop, judge.

        The temporary folder (pty link, socket, config, log) is removed however this
        ends, a failed start included.
        """
        self.work = Path(tempfile.mkdtemp(prefix="lunad-soak-"))
        try:
            return self._run()
        finally:
            shutil.rmtree(self.work, ignore_errors=True)

    def _run(self) -> SoakReport:
        self.link = self.work / "tfluna"
        self.endpoint = f"ipc://{self.work}/soak.sock"
        self.config = self.work / "soak.toml"
        self.log_path = self.work / "daemon.log"
        on_written = self.ledger.on_written
        rep = self.report
        with contextlib.ExitStack() as started:  # undone only if a later step fails
            if self.keep_logs is not None:
                self.keep_logs.mkdir(parents=True, exist_ok=True)
                for name in (DAEMON_INPUT, SENSOR_OUTPUT):
                    (self.keep_logs / name).unlink(missing_ok=True)
                rec = Recorder(self.keep_logs / SENSOR_OUTPUT, "soak: sensor writes")
                self._sensor_rec = rec
                started.callback(rec.close)
                on_written = self._record_written
            self.config.write_text(self._config_text())
            self.dev = PtyDevice(
                rate_hz=self.rate_hz,
                link=self.link,
                seed=self.seed,
                output_enabled=False,
                on_bytes_written=on_written,
            )
            started.callback(self.dev.close)
            self.dev.pause(1e9)  # until the subscription is live: seq 0 must arrive
            self.dev.start()
            self.sub = MainSubscriber(self.endpoint, self.ledger)
            self.sub.start()
            started.callback(self.sub.close)
            log_file = started.enter_context(open(self.log_path, "wb"))
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "lunad.daemon.cli", "serve", "--config", str(self.config)],
                stdout=log_file,
                stderr=subprocess.STDOUT,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
            started.pop_all()  # from here the finally below closes them
        rep.daemon_pid = self.proc.pid
        sampler = threading.Thread(target=self._sampler, name="soak-sampler", daemon=True)
        ticker = threading.Thread(target=self._ticker, name="soak-ticker", daemon=True)
        try:
            fd_baseline = 0
            rep.warmup_s = max(20.0, 0.1 * self.duration_s)
            try:
                self._start_stream()
                s0 = self._sample()
                if s0 is not None:
                    rep.samples.append(s0)
                    fd_baseline = s0.fds
                sampler.start()
                ticker.start()
                self._execute()
            except DaemonDied as exc:
                rep.aborted = str(exc)
            self._finish(fd_baseline)
        finally:
            self._stop_sampler.set()
            for t in (sampler, ticker):
                if t.is_alive():
                    t.join(5.0)
            if self._slow is not None:
                self._slow.close()
            self._stop_daemon()
            log_file.close()
            self.sub.close()
            try:
                self.dev.close()
            except DeviceError as exc:  # judged as a FAIL below, with the report and logs kept
                rep.aborted = rep.aborted or str(exc)
            if self._sensor_rec is not None:
                self._sensor_rec.close()
                self._check_bytes()
            rep.accounting = self.ledger.summary()
            rep.bad_messages = self.sub.bad_messages
            rep.frames_unread = self.dev.frames_unread
            rep.log_tracebacks = self._log_count("Traceback")
            judge(rep)
            self._keep()
        return rep

    def _record_written(self, data: bytes, ends: list[int], t_ns: int = 0) -> None:
        assert self._sensor_rec is not None
        self._sensor_rec(Chunk(data, t_ns))
        self.ledger.on_written(data, ends, t_ns)

    def _start_stream(self) -> None:
        w = self.sub.watch("health", 0, None)
        deadline = time.monotonic() + 15.0
        while self.sub.health_msgs == 0:  # any health message: our subscription is live
            self._check_alive()
            if time.monotonic() > deadline:
                raise DaemonDied("no health message within 15 s")
            time.sleep(0.02)
        _ = w
        while self.dev.commands_received == 0:  # the daemon opened the port (and flushed it)
            self._check_alive()
            if time.monotonic() > deadline:
                raise DaemonDied("the daemon did not configure the sensor within 15 s")
            time.sleep(0.01)
        first = self.sub.watch("range", 0)
        self.dev.pause(0)
        if self.sub.wait(first, 5.0) is None:
            raise DaemonDied("no reading within 5 s of the sensor starting")
        self._t0 = time.monotonic()

    def _execute(self) -> None:
        events: list[tuple[float, int, Fault]] = []
        for i, f in enumerate(self.schedule):
            events.append((f.at_s, i, f))
            if f.kind == "slow_subscriber":
                events.append((f.params["resume_at_s"], i, f))
        events.sort(key=lambda e: (e[0], e[1]))
        slow_result: FaultResult | None = None
        for at, _i, f in events:
            wait = at - self._now_s()
            if wait > 0:
                self._sleep(wait)
            if self._now_s() > self.duration_s * 1.5 + 30 and f.kind != "slow_subscriber":
                continue  # far behind schedule: skip rather than run forever
            if f.kind == "slow_subscriber" and slow_result is not None and self._slow is not None:
                self._resume_slow(slow_result)
                self.report.faults.append(slow_result)
                slow_result = None
                continue
            result = self._fault(f)
            if f.kind == "slow_subscriber":
                slow_result = result
            else:
                self.report.faults.append(result)
        left = self.duration_s - self._now_s()
        if left > 0:
            self._sleep(left)
        self.report.faults.sort(key=lambda r: r.at_s)

    def _finish(self, fd_baseline: int) -> None:
        rep = self.report
        self.dev.pause(1e9)
        with contextlib.suppress(DaemonDied):
            self._drain()
        rep.elapsed_s = round(self._now_s(), 2)
        time.sleep(1.0)  # let the daemon close what churn and the slow subscriber left
        end = self._sample()
        if end is not None:
            rep.samples.append(end)
        hz = os.sysconf("SC_CLK_TCK")
        samples = rep.samples
        if len(samples) >= 2:
            a, b = samples[0], samples[-1]
            frames = max(1, b.published - a.published)
            cpu_s = (b.cpu_ticks - a.cpu_ticks) / hz
            rep.cpu = {
                "us_per_frame": round(cpu_s * 1e6 / frames, 1),
                "pct": round(100 * cpu_s / max(1e-9, b.t_s - a.t_s), 2),
                "cpu_s": round(cpu_s, 2),
            }
        rep.rss = rss_verdict(samples, rep.warmup_s)
        fds = [s.fds for s in samples] or [0]
        post = [s for s in samples if s.t_s >= rep.warmup_s]
        slope = fit_slope([s.t_s for s in post], [float(s.fds) for s in post]) * 3600
        fd_end = end.fds if end else fds[-1]
        rep.fds = {
            "baseline": fd_baseline,
            "end": fd_end,
            "min": min(fds),
            "max": max(fds),
            "per_h_fit": round(slope, 2),
            "ok": float(fd_end <= fd_baseline),
        }
        h = self.sub.last_health
        if h is not None:
            rep.health = {
                k: getattr(h, k)
                for k in ("state", "frames", "checksum_errors", "bytes_discarded", "dropped_sends")
            }
            rep.health["uptime_s"] = h.uptime_s
        lat = self.sub.latency
        rep.latency_us = {
            "p50": round(lat.quantile(0.5), 1),
            "p99": round(lat.quantile(0.99), 1),
            "max": round(lat.max_us, 1),
            "sensor_to_daemon_read_max": round(self.ledger.read_lat_max_ns / 1000, 1),
            "soak_lag_max": round(self._lag_max * 1e6, 1),
        }

    def _stop_daemon(self) -> None:
        proc = self.proc
        if proc.poll() is None:
            t = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            try:
                self.report.daemon_exit_code = proc.wait(5.0)
                self.report.daemon_stop_s = round(time.monotonic() - t, 3)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                self.report.daemon_exit_code = None
        elif self.report.daemon_exit_code is None:
            self.report.daemon_exit_code = proc.returncode

    def _check_bytes(self) -> None:
        assert self.keep_logs is not None
        try:
            check = compare(self.keep_logs)
        except (OSError, ValueError) as exc:
            self.report.byte_check = {"error": str(exc)}
            return
        self.report.byte_check = {
            "complete": check.complete,
            "sensor_bytes": check.sensor_bytes,
            "daemon_bytes": check.daemon_bytes,
            "skipped_spans": len(check.skipped),
            "max_wait_s": round(check.max_wait_s, 4),
            "p99_wait_s": round(check.p99_wait_s, 4),
            "frames": check.frames,
            "summary": check.summary(),
        }

    def _keep(self) -> None:
        if self.keep_logs is None:
            return
        self.keep_logs.mkdir(parents=True, exist_ok=True)
        for name in ("daemon.log", "soak.toml"):
            with contextlib.suppress(OSError):
                shutil.copy(self.work / name, self.keep_logs / name)
        (self.keep_logs / "report.json").write_text(json.dumps(self.report.to_json(), indent=1))


def run_soak(
    duration_s: float,
    seed: int = 0,
    rate_hz: int = 100,
    progress: Callable[[str], None] | None = None,
    keep_logs: Path | str | None = None,
) -> SoakReport:
    """Run a soak of ``duration_s`` seconds; the judged report."""
    return Soak(duration_s, seed, rate_hz, progress, keep_logs).run()


# -- the report -------------------------------------------------------------------------


def _hms(s: float) -> str:
    n = round(s)
    return f"{n // 3600:02d}:{n % 3600 // 60:02d}:{n % 60:02d}"


def format_report(r: SoakReport) -> str:
    """The human report printed at the end."""
    acc = r.accounting
    out = [
        f"soak: seed {r.seed}, {_hms(r.elapsed_s)} of streaming at {r.rate_hz} Hz, "
        f"daemon pid {r.daemon_pid}",
        "",
        "frames",
        f"  sent by the sensor (good, fully written)   {acc.get('frames_sent', 0)}",
        f"  found in the bytes by a reference parser   {acc.get('reference_frames', 0)}"
        f"  ({acc.get('false_frames', 0)} formed by garbage, "
        f"{acc.get('eaten_frames', 0)} real ones swallowed by them)",
        f"  published (distinct seq at the main sub)    {acc.get('published', 0)}",
        f"  lost                                       {acc.get('lost', 0)}"
        f"  (seq gaps {acc.get('gaps', 0)}, missing {acc.get('missing', 0)}, "
        f"wrong content {acc.get('mismatched', 0)}, unexpected {acc.get('unexpected', 0)})",
        f"  slow subscriber HWM losses (expected)      {r.slow_subscriber_lost}"
        f" of {r.slow_subscriber_lost + r.slow_subscriber_received}",
        f"  frames the sensor could not write           {r.frames_unread}",
    ]
    if r.health:
        h = r.health
        out.append(
            f"  daemon health: {h['frames']} frames, {h['checksum_errors']} checksum errors, "
            f"{h['bytes_discarded']} bytes discarded, {h['dropped_sends']} dropped sends"
        )
    if r.latency_us:
        lat = r.latency_us
        out.append(
            f"  read -> subscriber latency: p50 {lat['p50'] / 1000:.2f} ms, "
            f"p99 {lat['p99'] / 1000:.2f} ms, max {lat['max'] / 1000:.1f} ms; "
            f"sensor write -> daemon read max "
            f"{lat.get('sensor_to_daemon_read_max', float('nan')) / 1000:.1f} ms; "
            f"the soak's own scheduling lag max "
            f"{lat.get('soak_lag_max', float('nan')) / 1000:.0f} ms"
        )
    if r.byte_check:
        b = r.byte_check
        out.append(f"  byte recordings: {b.get('summary', b.get('error'))}")
    out += [
        "",
        f"faults ({len(r.faults)})",
        f"{'at':>9}  {'fault':<16}{'lasts':>7}{'recovery':>10}  ok",
    ]
    for f in r.faults:
        rec = "-" if f.recovery_s is None else f"{f.recovery_s:.3f}s"
        out.append(
            f"{f.at_s:8.1f}s  {f.kind:<16}{f.duration_s:6.1f}s{rec:>10}  "
            f"{'yes' if f.ok else 'NO '}  {f.note}"
        )
    by_kind: dict[str, list[float]] = {}
    for f in r.faults:
        if f.recovery_s is not None:
            by_kind.setdefault(f.kind, []).append(f.recovery_s)
    if by_kind:
        out.append("recovery by type (n, median, max):")
        for k in FAULT_KINDS:
            v = sorted(by_kind.get(k, []))
            if v:
                out.append(f"  {k:<16} {len(v):4d}  {v[len(v) // 2]:.3f} s  {v[-1]:.3f} s")
    rss, fds, cpu = r.rss, r.fds, r.cpu
    out += ["", "resources (daemon)"]
    if rss:
        out.append(
            f"  RSS {rss['start_mib']:.1f} -> {rss['end_mib']:.1f} MiB (max {rss['max_mib']:.1f});"
            f" after {r.warmup_s:.0f} s warm-up: {rss['mib_per_h']:+.2f} MiB/h fitted over "
            f"{rss['window_s']:.0f} s = {rss['growth_kib']:+.0f} KiB, "
            f"allowed {rss['allowed_kib']:.0f} KiB"
        )
    if fds:
        out.append(
            f"  open files: {fds['baseline']} at start, {fds['end']} at end "
            f"(min {fds.get('min')}, max {fds.get('max')}; "
            f"fit {fds.get('per_h_fit', 0.0):+.2f}/h)"
        )
    if cpu:
        out.append(
            f"  CPU {cpu['us_per_frame']:.0f} us per published frame, {cpu['pct']:.1f} % "
            f"on average ({cpu['cpu_s']:.1f} s)"
        )
    if r.samples:
        step = max(1, len(r.samples) // 12)
        pts = r.samples[::step] + ([r.samples[-1]] if (len(r.samples) - 1) % step else [])
        out.append(
            "  over time (s: MiB/fds): "
            + ", ".join(f"{s.t_s:.0f}: {s.rss_kib / 1024:.2f}/{s.fds}" for s in pts)
        )
    stop = "" if r.daemon_stop_s is None else f" {r.daemon_stop_s:.2f} s after SIGTERM"
    out.append(f"  daemon exit code {r.daemon_exit_code}{stop}")
    out += ["", "conditions"]
    for name, ok in r.conditions.items():
        out.append(f"  {'ok  ' if ok else 'FAIL'}  {name.replace('_', ' ')}")
    out.append("")
    if r.passed:
        out.append("PASS: every valid frame published, every fault recovered within 5 s, "
                   "no RSS or fd growth, the daemon never restarted")  # fmt: skip
    else:
        out.append("FAIL: " + "; ".join(r.reasons))
    return "\n".join(out)
