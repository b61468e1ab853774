"""Bench figure 2: parse + filter + encode of one frame at a time, pure Python, no I/O,
in microseconds per frame (and each stage alone); and ``bench_message``, the same for one
``--publish-hz`` message, with warm caches and after a sleep."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lunad.daemon.tools.bench.measure import median
from lunad.daemon.tools.bench.rounds import SENSOR_HZ

IDENT = b'"sensor":"tfluna","run":"0000000000000000"'
"""``range_ident`` of the messages the pure-work benchmarks encode (a constant: it is
made once per daemon run)."""


@dataclass
class PipelineResult:
    """Per-frame cost of the pure hot path, microseconds."""

    frames: int
    parse_us: float
    filter_us: float
    encode_us: float
    total_us: float
    message_frames: int
    """Frames in one ``--publish-hz`` message (sensor rate / publish rate, rounded up)."""
    message_gap_s: float
    """The time between two such messages (1 / publish rate), seconds."""
    message_warm_us: float
    """One such message (parse and filter its frames, encode the last), run right after
    the one before it: caches warm. Median."""
    message_cold_us: float
    """The same after sleeping ``message_gap_s``, as the low-power loop does between
    messages: what a wake-up costs in cache misses on this machine. Median."""


def _sensor_frames(n: int, seed: int = 1) -> list[bytes]:
    import random

    from lunad.protocol.frame import encode_frame, temp_raw_from_c
    from lunad.sim.physics import PaperSensor, Truth

    rng = random.Random(seed)
    model = PaperSensor()
    temp = temp_raw_from_c(40.0)
    out = []
    for k in range(n):
        truth = Truth(2.0 + 0.5 * ((k // 500) % 3), 0.8, 10.0, 100.0 + 50.0 * (k % 7))
        r = model.sample(truth, rng)
        out.append(encode_frame(r.dist_cm, r.amp, temp))
    return out


def bench_pipeline(
    n_frames: int = 50_000, publish_hz: float = 50.0, messages: int = 200
) -> PipelineResult:
    """Parse, filter and encode ``n_frames`` frames fed one at a time (as at 250 Hz);
    then ``messages`` pairs of ``--publish-hz`` messages (``bench_message``)."""
    import time

    from lunad.filters import RangeFilter
    from lunad.protocol.frame import Frame
    from lunad.protocol.messages import encode_range, reasons_json
    from lunad.protocol.parser import FrameParser

    chunks = _sensor_frames(n_frames)
    period = 4_000_000
    ts = [k * period for k in range(n_frames)]

    parser = FrameParser()
    t0 = time.perf_counter()
    frames: list[Frame] = []
    for chunk, t in zip(chunks, ts, strict=True):
        frames += parser.feed(chunk, t)  # type: ignore[arg-type]
    parse_s = time.perf_counter() - t0

    filt = RangeFilter()
    t0 = time.perf_counter()
    ests = [filt.step(f.distance_m, f.amp, f.t_mono_ns) for f in frames]
    filter_s = time.perf_counter() - t0

    rcache: dict[tuple[str, ...], bytes] = {}
    t0 = time.perf_counter()
    for seq, (f, e) in enumerate(zip(frames, ests, strict=True)):
        reasons = rcache.get(e.reasons)
        if reasons is None:
            reasons = rcache[e.reasons] = reasons_json(e.reasons)
        encode_range(
            IDENT,
            seq,
            1,
            f.t_mono_ns,
            f.t_mono_ns,
            f.distance_m,
            f.amp,
            f.temp_c,
            e.strength,
            e.range_m,
            e.sigma_m,
            e.lux_est,
            e.status,
            reasons,
            e.zone,
        )
    encode_s = time.perf_counter() - t0

    # All three together, as the read loop runs them.
    parser = FrameParser()
    filt = RangeFilter()
    rcache = {}
    seq = 0
    t0 = time.perf_counter()
    for chunk, t in zip(chunks, ts, strict=True):
        for fr in parser.feed(chunk, t):
            e = filt.step(fr.distance_m, fr.amp, fr.t_mono_ns)  # type: ignore[union-attr]
            reasons = rcache.get(e.reasons)
            if reasons is None:
                reasons = rcache[e.reasons] = reasons_json(e.reasons)
            encode_range(
                IDENT,
                seq,
                1,
                t,
                t,
                fr.distance_m,  # type: ignore[union-attr]
                fr.amp,  # type: ignore[union-attr]
                fr.temp_c,  # type: ignore[union-attr]
                e.strength,
                e.range_m,
                e.sigma_m,
                e.lux_est,
                e.status,
                reasons,
                e.zone,
            )
            seq += 1
    total_s = time.perf_counter() - t0
    us = 1e6 / n_frames
    per_message = math.ceil(SENSOR_HZ / publish_hz)
    warm_us, cold_us = bench_message(per_message, 1.0 / publish_hz, messages)
    return PipelineResult(
        n_frames,
        parse_s * us,
        filter_s * us,
        encode_s * us,
        total_s * us,
        per_message,
        1.0 / publish_hz,
        warm_us,
        cold_us,
    )


def bench_message(frames: int = 5, gap_s: float = 0.02, messages: int = 200) -> tuple[float, float]:
    """Median microseconds of one ``--publish-hz`` message's pure work: one read of
    ``frames`` frames parsed, each filtered (spaced a sensor frame apart, as
    ``Daemon._read_folded`` does), the last encoded. Each pair of messages sleeps
    ``gap_s`` first: the first of the pair runs cold, the second right after it, warm.
    The two differ by what caches and branch predictors lost while asleep; on a shared
    VM, several times the work itself (docs/performance.md, "Cold wake-ups").
    Returns (warm, cold)."""
    import time

    from lunad.filters import RangeFilter
    from lunad.protocol.frame import Frame
    from lunad.protocol.messages import encode_range, reasons_json
    from lunad.protocol.parser import FrameParser

    raw = _sensor_frames(2 * messages * frames, seed=2)
    reads = [b"".join(raw[i : i + frames]) for i in range(0, len(raw), frames)]
    parser = FrameParser()
    filt = RangeFilter()
    rcache: dict[tuple[str, ...], bytes] = {}
    spacing = 1_000_000_000 // SENSOR_HZ
    clock = time.perf_counter_ns
    warm: list[float] = []
    cold: list[float] = []
    for i, data in enumerate(reads):
        t = (i + 1) * frames * spacing
        if i % 2 == 0:
            time.sleep(gap_s)
        t0 = clock()
        items = parser.feed(data, t)
        k = len(items)
        for fr in items:
            k -= 1
            e = filt.step(fr.distance_m, fr.amp, t - k * spacing)  # type: ignore[union-attr]
        last: Frame = items[-1]  # type: ignore[assignment]
        reasons = rcache.get(e.reasons)
        if reasons is None:
            reasons = rcache[e.reasons] = reasons_json(e.reasons)
        encode_range(IDENT, i, frames, t, t, last.distance_m, last.amp, last.temp_c, e.strength,
                     e.range_m, e.sigma_m, e.lux_est, e.status, reasons, e.zone)  # fmt: skip
        (cold if i % 2 == 0 else warm).append(clock() - t0)
    return median(warm) / 1e3, median(cold) / 1e3
