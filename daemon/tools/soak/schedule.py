"""The soak's seeded fault plan: the fault types, their parameters drawn from the seed,
and the schedule that fits them into the duration (``build_schedule``)."""

from __future__ import annotations

import random
import re
from dataclasses import dataclass, field

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


_DURATION_RE = re.compile(r"(\d+(?:\.\d+)?)([smhd]?)")
_UNIT_S = {"": 1.0, "s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}


MAX_DURATION_S = 7 * 86400.0
"""Longest soak, seconds (our bound): its schedule is built up front, 43,000 faults and
50 MB for a week; a longer soak is a series of them, each with its own seed."""


def parse_duration(text: str) -> float:
    """Seconds in ``60s``, ``10m``, ``1h``, ``24h``, ``1h30m`` or plain ``90``.

    Raises:
        ValueError: anything else, zero, or over ``MAX_DURATION_S``.
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
    if total > MAX_DURATION_S:
        raise ValueError(f"{text!r} is over a week (168h), the longest soak; run a series")
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
        f"soak schedule: seed {seed}, {hms(duration_s)}, sensor at {rate_hz} Hz, "
        f"{len(faults)} faults",
        f"{'at':>9}  {'fault':<16}{'lasts':>8}  what",
    ]
    for f in faults:
        lines.append(f"{f.at_s:8.1f}s  {f.kind:<16}{f.duration_s:7.1f}s  {f.describe()}")
    return "\n".join(lines)


def hms(s: float) -> str:
    """``s`` seconds as ``HH:MM:SS``, for the schedule and the reports."""
    n = round(s)
    return f"{n // 3600:02d}:{n % 3600 // 60:02d}:{n % 60:02d}"
