"""FrameClock: the sensor's frame rate measured from its reads (pure, no I/O).

The reads are made up here the way a serial port gives them: the sensor sends a frame
every period on its own clock, and a read brings every frame whose last byte arrived
before it, stamped a little after that (scheduling latency)."""

from __future__ import annotations

import itertools
import random
import tracemalloc
from collections.abc import Iterator

import pytest

from lunad.daemon.frame_clock import (
    KEEP_WINDOWS,
    NS,
    TOLERANCE,
    FrameClock,
    sensor_rate_near,
)

MS = 1_000_000


def sensor_frames(t0_ns: int, segments: list[tuple[float, float]]) -> Iterator[int]:
    """Send times of the frames (ns): ``segments`` of (rate Hz, seconds) in turn; a rate
    of 0 is a pause."""
    t = float(t0_ns)
    for rate_hz, seconds in segments:
        end = t + seconds * NS
        if not rate_hz:
            t = end
        while t < end:
            t += NS / rate_hz
            yield round(t)


def reads(
    sent: Iterator[int],
    rng: random.Random,
    most: int = 10,
    stalls_every_s: float | None = None,
    stall_s: float = 0.3,
    stamped_late: bool = False,
) -> Iterator[tuple[int, int]]:
    """(read time ns, frames) of a reader taking 1..``most`` frames a read, stamped
    0.05-2 ms after the last one arrived. Every ``stalls_every_s`` seconds the reader
    stalls for ``stall_s``: the next read brings the backlog, stamped when it ends (or,
    ``stamped_late``, the read happens before the stall and is stamped after it, the
    worst case: a frame count from one time with the time of another)."""
    frames = list(sent)
    i = 0
    last = 0
    next_stall = frames[0] + stalls_every_s * NS if stalls_every_s else None
    while i < len(frames):
        n = min(rng.randint(1, most), len(frames) - i)
        t = frames[i + n - 1] + rng.randint(50_000, 2 * MS)
        if next_stall is not None and t >= next_stall:
            assert stalls_every_s  # next_stall is only set with stalls
            end = t + int(stall_s * NS)
            if not stamped_late:  # everything sent by the end of the stall
                while i + n < len(frames) and frames[i + n] <= end:
                    n += 1
            t = end
            next_stall = end + stalls_every_s * NS
        t = max(t, last + 1)
        last = t
        i += n
        yield t, n


def run(clock: FrameClock, it: Iterator[tuple[int, int]]) -> list[tuple[int, float | None, bool]]:
    """Feed every read; (read time, measured_hz, what feed returned) a read."""
    out = []
    for t, n in it:
        changed = clock.feed(t, n)
        out.append((t, clock.measured_hz, changed))
    return out


def measured_after(trace: list[tuple[int, float | None, bool]], t_ns: int) -> list[float]:
    return [m for t, m, _ in trace if t >= t_ns and m is not None]


T0 = 10**12


@pytest.mark.parametrize("seed", range(5))
def test_steady_250_hz_in_reads_of_1_to_10_frames(seed: int) -> None:
    """Configured 100 Hz, the sensor sends 250: the clock starts at 100, switches once
    to 250 within 2 s, and the measurement stays within 2 % of 250 after that."""
    rng = random.Random(seed)
    clock = FrameClock(100)
    assert clock.rate_hz == 100 and clock.period_ns == 10 * MS
    trace = run(clock, reads(sensor_frames(T0, [(250, 20)]), rng))
    switches = [t for t, _, changed in trace if changed]
    assert len(switches) == 1 and switches[0] - T0 < 2 * NS
    assert clock.rate_hz == clock.sensor_hz == 250 and clock.period_ns == 4 * MS
    assert clock.differs
    settled = measured_after(trace, T0 + 2 * NS)
    assert settled and max(abs(m / 250 - 1) for m in settled) < 0.02


def test_a_sensor_at_the_configured_rate_changes_nothing() -> None:
    rng = random.Random(1)
    clock = FrameClock(250)
    trace = run(clock, reads(sensor_frames(T0, [(250, 20)]), rng))
    assert not any(changed for _, _, changed in trace)
    assert clock.rate_hz == 250 and not clock.differs
    assert max(abs(m / 250 - 1) for m in measured_after(trace, T0 + 2 * NS)) < 0.02


@pytest.mark.parametrize("stamped_late", [False, True])
@pytest.mark.parametrize("seed", range(3))
def test_stalls_then_backlog_bursts_do_not_move_it(seed: int, stamped_late: bool) -> None:
    """A reader stalled for 0.3 s every 2 s reads 75 frames at once after each stall.
    The measurement stays within 2 % of 250 (the task allows 5 %), and the timing never
    leaves 250. Stamped late (the count of one time with the time of another), a stall
    spoils the one window it falls in, which the median of five leaves out."""
    rng = random.Random(seed)
    clock = FrameClock(250)
    it = reads(sensor_frames(T0, [(250, 30)]), rng, stalls_every_s=2.0, stamped_late=stamped_late)
    trace = run(clock, it)
    gaps = [b[0] - a[0] for a, b in itertools.pairwise(trace)]
    assert sum(gap >= 0.3 * NS for gap in gaps) >= 10  # the stalls happened
    assert not any(changed for _, _, changed in trace)
    settled = measured_after(trace, T0 + 2 * NS)
    assert max(abs(m / 250 - 1) for m in settled) < 0.02
    assert clock.rate_hz == 250


def test_backlog_bursts_are_whole_frames_of_the_stall() -> None:
    """The stall reads above do bring about 75 frames (0.3 s at 250 Hz)."""
    rng = random.Random(0)
    got = list(reads(sensor_frames(T0, [(250, 10)]), rng, stalls_every_s=2.0))
    gaps = [(b[0] - a[0], b[1]) for a, b in itertools.pairwise(got)]
    burst = [n for gap, n in gaps if gap >= 0.3 * NS]
    assert burst and all(74 <= n <= 86 for n in burst)


def test_sensor_pauses_do_not_move_it() -> None:
    """The sensor itself goes silent for 0.3 s every 2 s (no backlog: fewer frames)."""
    rng = random.Random(4)
    sent = sensor_frames(T0, [(250, 1.7), (0, 0.3)] * 10)
    clock = FrameClock(250)
    trace = run(clock, reads(sent, rng))
    assert not any(changed for _, _, changed in trace)
    settled = measured_after(trace, T0 + 2 * NS)
    assert max(abs(m / 250 - 1) for m in settled) < 0.05
    assert clock.rate_hz == 250


def test_a_sensor_pausing_every_half_second_is_still_measured() -> None:
    """0.3-0.6 s of frames, then 0.3 s of none, over and over (as in the daemon's test of
    batching after a stall): every pause is left out, and nothing changes."""
    rng = random.Random(5)
    segments = [(250.0, 2.0)]
    for _ in range(25):
        segments += [(250.0, 0.3 + 0.3 * rng.random()), (0.0, 0.3)]
    clock = FrameClock(250)
    trace = run(clock, reads(sensor_frames(T0, segments), rng))
    assert not any(changed for *_, changed in trace)
    assert max(abs(m / 250 - 1) for m in measured_after(trace, T0 + 2 * NS)) < 0.02


@pytest.mark.parametrize(("low_hz", "within_s"), [(100, 3.0), (25, 9.0), (10, 15.0)])
def test_a_fall_in_rate_is_not_taken_for_pauses(low_hz: int, within_s: float) -> None:
    """From 250 Hz to a lower rate, read in batches of up to 5 frames: at 25 or 10 Hz every
    read looks like the end of a pause (a long gap, few frames), yet the clock follows."""
    rng = random.Random(6)
    clock = FrameClock(250)
    trace = run(clock, reads(sensor_frames(T0, [(250, 3), (low_hz, 20)]), rng, most=5))
    switches = [t for t, _, changed in trace if changed]
    assert len(switches) == 1 and switches[0] - T0 - 3 * NS < within_s * NS
    assert clock.rate_hz == low_hz


def test_a_rate_change_from_100_to_250_hz_is_followed() -> None:
    """The sensor runs at the configured 100 Hz for 5 s, then at 250 (a power cycle that
    lost the setting, say): the clock stays at 100, then switches to 250 within 2.5 s."""
    rng = random.Random(7)
    clock = FrameClock(100)
    trace = run(clock, reads(sensor_frames(T0, [(100, 5), (250, 10)]), rng))
    change = T0 + 5 * NS
    switches = [t for t, _, changed in trace if changed]
    assert len(switches) == 1 and 0 < switches[0] - change < 2.5 * NS
    before = [m for t, m, _ in trace if T0 + 2 * NS <= t < change and m is not None]
    assert max(abs(m / 100 - 1) for m in before) < 0.02
    after = measured_after(trace, change + 3 * NS)
    assert max(abs(m / 250 - 1) for m in after) < 0.02
    assert clock.rate_hz == 250


def test_back_to_the_configured_rate() -> None:
    rng = random.Random(8)
    clock = FrameClock(100)
    trace = run(clock, reads(sensor_frames(T0, [(250, 5), (100, 6)]), rng))
    assert sum(changed for *_, changed in trace) == 2
    assert clock.rate_hz == 100 and not clock.differs


def test_a_clock_that_does_not_follow_measures_but_keeps_its_rate() -> None:
    """``follow=False`` (an I2C sensor): the configured rate stays the timing; the verdict
    still changes."""
    rng = random.Random(2)
    clock = FrameClock(100, follow=False)
    trace = run(clock, reads(sensor_frames(T0, [(250, 5)]), rng))
    assert sum(changed for *_, changed in trace) == 1
    assert clock.sensor_hz == 250 and clock.differs
    assert clock.rate_hz == 100 and clock.period_ns == 10 * MS


def test_no_verdict_before_enough_windows() -> None:
    """Under 1.5 s of frames (three windows) the clock keeps the configured rate."""
    rng = random.Random(3)
    clock = FrameClock(100)
    trace = run(clock, reads(sensor_frames(T0, [(250, 1.4)]), rng))
    assert clock.measured_hz is None and clock.rate_hz == 100
    assert not any(changed for *_, changed in trace)


def test_the_first_reads_frames_are_not_counted() -> None:
    """A port opened on a streaming sensor may hold a backlog: the first read opens the
    first window, its frames do not count."""
    clock = FrameClock(250)
    clock.feed(T0, 400)  # 1.6 s of frames queued before the port was opened
    t = T0
    for _ in range(2000):
        t += 4 * MS
        clock.feed(t, 1)
    assert clock.measured_hz is not None and abs(clock.measured_hz / 250 - 1) < 0.001


def test_time_going_back_opens_a_new_window() -> None:
    """A recording appended to after a reboot: monotonic time starts again."""
    clock = FrameClock(100)
    t = T0
    for _ in range(300):
        t += 10 * MS
        clock.feed(t, 1)
    t = 5 * NS
    for _ in range(1000):
        t += 4 * MS
        clock.feed(t, 1)
    assert clock.measured_hz is not None and abs(clock.measured_hz / 250 - 1) < 0.01


def test_slow_rates_need_enough_frames_per_window() -> None:
    """At 5 Hz a window holds 25 frames (5 s): no verdict on a handful of frames."""
    clock = FrameClock(5)
    t = T0
    for _ in range(70):
        t += 200 * MS
        clock.feed(t, 1)
    assert clock.measured_hz is None
    for _ in range(100):
        t += 200 * MS
        clock.feed(t, 1)
    assert clock.measured_hz is not None and abs(clock.measured_hz - 5) < 0.01


@pytest.mark.parametrize(
    ("hz", "want"),
    [(249.0, 250.0), (251.9, 250.0), (166.0, 500 / 3), (100.4, 100.0), (200.0, 200.0)],
)
def test_sensor_rate_near(hz: float, want: float) -> None:
    assert sensor_rate_near(hz) == pytest.approx(want)


def test_within_tolerance_of_the_configured_rate_is_the_configured_rate() -> None:
    """The sensor asked for 23 Hz may run at 500/21 = 23.8 Hz: not a new rate."""
    clock = FrameClock(23)
    t = T0
    for _ in range(500):
        t += round(NS * 21 / 500)
        clock.feed(t, 1)
    assert clock.measured_hz is not None and abs(clock.measured_hz / 23 - 1) < TOLERANCE
    assert clock.rate_hz == 23 and not clock.differs


def test_nominal_must_be_positive() -> None:
    with pytest.raises(ValueError):
        FrameClock(0)


def test_a_read_allocates_nothing_that_stays() -> None:
    """O(1) a read: memory does not grow with reads (a ring of five window rates)."""
    clock = FrameClock(250)
    t = T0
    for _ in range(2000):
        t += 4 * MS
        clock.feed(t, 1)
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        for _ in range(100_000):
            t += 4 * MS
            clock.feed(t, 1)
        after, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after - before < 1024
    assert len(clock._rates) == KEEP_WINDOWS
