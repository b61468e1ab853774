"""Scenarios: time-varying truth (distance, reflectivity, angle, lux) at a frame rate.

A scenario is a TOML file. Every truth field has its own timeline; a table names
the fields it sets and leaves the others on their course:

```toml
description = "Obstacle steps in front of a wall"   # optional
rate_hz = 250          # frame rate, Hz (TF-Luna allows 500/n, M05 p.15); default 250
duration_s = 12.0      # optional; default: the last time named below

[initial]              # values at t = 0; unnamed fields take Truth's defaults
distance_m = 4.13      # metres
reflectivity = 0.8     # 0..1 (up to 10 for retroreflectors)
angle_deg = 0.0        # incidence, degrees, 0..90
lux = 300.0            # ambient light, lux

[[keyframe]]           # reached at t_s by a straight line from the field's last point
t_s = 8.0
distance_m = 0.5

[[keyframe]]
t_s = 9.0
lux = 2000.0
interp = "hold"        # "linear" (default) or "hold": keep the old value, jump at t_s

[[step]]               # the same as a keyframe with interp = "hold"
t_s = 2.0
distance_m = 1.21
reflectivity = 0.5
```

Between points a field ramps (``linear``) or holds (``hold``/``step``); after its
last point it holds. Tables must be in time order. Every instant where the distance
jumps is a *step* (``Scenario.step_times_s``): ``lunad eval`` measures its lag and
leaves the frames right after it out of the "away from steps" metrics.
"""

from __future__ import annotations

import bisect
import math
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from lunad.protocol.commands import FRAME_RATES_HZ
from lunad.sim.physics import Truth

DEFAULT_RATE_HZ = 250.0  # the TF-Luna's fastest frame rate, M05 p.9
FIELDS = ("distance_m", "reflectivity", "angle_deg", "lux")
FIELD_LIMITS: dict[str, tuple[float, float]] = {
    "distance_m": (0.01, 100.0),
    "reflectivity": (0.0, 10.0),
    "angle_deg": (0.0, 90.0),
    "lux": (0.0, 200_000.0),
}
"""Allowed range of each truth field, inclusive, in its unit (metres, 0..1 and up to
10 for retroreflectors, degrees, lux); ``lunad sim``'s truth flags use the same."""
MAX_DURATION_S = 86_400.0
"""A scenario lasts at most a day, and its tables' times lie within it: a frame index
is seconds times the rate (21.6 M frames at 250 Hz), and ``duration_s = 1e308`` gave
none at all. A longer run plays one again and again (``lunad sim --loop``)."""
_TOP_KEYS = {"name", "description", "rate_hz", "duration_s", "initial", "keyframe", "step"}
_INTERP = ("linear", "hold")

TRUTH_CSV_HEADER = "t_s,distance_m,reflectivity,angle_deg,lux"
"""Header of :func:`truth_csv_row`'s rows: time in seconds, then Truth's fields."""


class ScenarioError(ValueError):
    """A scenario file or name is wrong; the message names the field and what is allowed."""


@dataclass(frozen=True, slots=True)
class Timeline:
    """One field's course: points (t_s, value), each reached linearly or by a jump.

    Attributes:
        times_s: point times, seconds, non-decreasing.
        values: the field's value at each point.
        linear: for each point, whether it is reached by a ramp from the previous one.
    """

    times_s: tuple[float, ...]
    values: tuple[float, ...]
    linear: tuple[bool, ...]

    def at(self, t_s: float) -> float:
        """The field's value at ``t_s`` seconds."""
        i = bisect.bisect_right(self.times_s, t_s) - 1
        if i < 0:
            return self.values[0]
        if i + 1 >= len(self.times_s) or not self.linear[i + 1]:
            return self.values[i]
        t0 = self.times_s[i]
        t1 = self.times_s[i + 1]
        v0 = self.values[i]
        return v0 + (self.values[i + 1] - v0) * (t_s - t0) / (t1 - t0)

    def jumps(self) -> tuple[float, ...]:
        """Times at which the value jumps, seconds."""
        out = []
        for i in range(1, len(self.times_s)):
            prev = self.at(self.times_s[i] - 1e-12) if self.times_s[i] > 0 else self.values[0]
            if not self.linear[i] and self.values[i] != prev:
                out.append(self.times_s[i])
        return tuple(out)


@dataclass(frozen=True, slots=True)
class Scenario:
    """A time-varying truth, sampled at a frame rate.

    Attributes:
        name: short name (the file's stem for files).
        description: one line for listings.
        rate_hz: frame rate, Hz.
        duration_s: length, seconds.
        timelines: one per Truth field, in FIELDS order.
        step_times_s: instants where the distance jumps, seconds.
    """

    name: str
    description: str
    rate_hz: float
    duration_s: float
    timelines: tuple[Timeline, ...] = field(repr=False)
    step_times_s: tuple[float, ...] = ()

    @property
    def n_frames(self) -> int:
        """Number of frames in ``duration_s`` at ``rate_hz``."""
        return max(1, round(self.duration_s * self.rate_hz))

    def truth_at(self, t_s: float) -> Truth:
        """The truth at ``t_s`` seconds from the start (held after the end)."""
        d, r, a, lux = (tl.at(t_s) for tl in self.timelines)
        return Truth(distance_m=d, reflectivity=r, angle_deg=a, lux=lux)

    def frame_times(self) -> Iterator[float]:
        """Frame times, seconds: k / rate_hz for every frame."""
        rate = self.rate_hz
        for k in range(self.n_frames):
            yield k / rate

    def step_frames(self) -> tuple[int, ...]:
        """Index of the first frame at or after each step."""
        return tuple(math.ceil(t * self.rate_hz - 1e-9) for t in self.step_times_s)

    def with_duration(self, duration_s: float) -> Scenario:
        """The same scenario cut (or held) to ``duration_s`` seconds."""
        if not 0 < duration_s <= MAX_DURATION_S:
            raise ScenarioError(
                f"duration_s must be above 0 and at most {MAX_DURATION_S:g} s (a day),"
                f" got {duration_s!r}"
            )
        steps = tuple(t for t in self.step_times_s if t < duration_s)
        return replace(self, duration_s=float(duration_s), step_times_s=steps)


def truth_csv_row(t_s: float, truth: Truth) -> str:
    """One CSV row (no newline) for ``truth`` at ``t_s``; columns as TRUTH_CSV_HEADER."""
    return (
        f"{t_s:.6f},{truth.distance_m:.4f},{truth.reflectivity:.4f},"
        f"{truth.angle_deg:.3f},{truth.lux:.1f}"
    )


def builtin_scenarios() -> tuple[str, ...]:
    """Names of the scenarios shipped in ``lunad.sim/scenarios``, sorted."""
    folder = resources.files("lunad.sim").joinpath("scenarios")
    return tuple(sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml")))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a built-in scenario by name, or a scenario file by path.

    Raises:
        ScenarioError: unknown name, unreadable file, or a bad field (named).
    """
    text_path = str(name_or_path)
    path = Path(text_path)
    if text_path.endswith(".toml") or path.exists():
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ScenarioError(f"cannot read scenario file {text_path}: {exc}") from exc
        except UnicodeDecodeError as exc:
            raise ScenarioError(
                f"cannot read scenario file {text_path}: not UTF-8 text (TOML must be): "
                f"byte 0x{exc.object[exc.start]:02x} at offset {exc.start}"
            ) from exc
        return parse_scenario(text, name=path.stem, source=text_path)
    names = builtin_scenarios()
    if text_path not in names:
        raise ScenarioError(
            f"unknown scenario {text_path!r}: give a .toml path or one of {', '.join(names)}"
        )
    res = resources.files("lunad.sim").joinpath("scenarios", f"{text_path}.toml")
    return parse_scenario(res.read_text(encoding="utf-8"), name=text_path, source=text_path)


def _number(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ScenarioError(f"{where}: {key} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ScenarioError(f"{where}: {key} must be finite, got {value!r}")
    return v


def _field_value(where: str, key: str, value: Any) -> float:
    v = _number(where, key, value)
    lo, hi = FIELD_LIMITS[key]
    if not lo <= v <= hi:
        raise ScenarioError(f"{where}: {key} must be within [{lo}, {hi}], got {v}")
    return v


def parse_scenario(text: str, name: str = "scenario", source: str = "<string>") -> Scenario:
    """Build a Scenario from TOML text (format in this module's docstring).

    Raises:
        ScenarioError: bad TOML or a bad field; the message names ``source`` and the field.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from exc
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise ScenarioError(
            f"{source}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_TOP_KEYS)}"
        )
    rate = _number(source, "rate_hz", doc.get("rate_hz", DEFAULT_RATE_HZ))
    if not (rate.is_integer() and int(rate) in FRAME_RATES_HZ and rate > 0):
        raise ScenarioError(
            f"{source}: rate_hz must be a frame rate the sensor runs at, 500/n Hz "
            f"(250, 166, 125, 100, 83, ..., 2, 1; M05 p.15), got {rate:g}"
        )
    initial = doc.get("initial", {})
    if not isinstance(initial, dict):
        raise ScenarioError(f"{source}: [initial] must be a table")
    base = Truth()
    points: dict[str, list[tuple[float, float, bool]]] = {}
    for key in FIELDS:
        v = initial.get(key, getattr(base, key))
        points[key] = [(0.0, _field_value(f"{source} [initial]", key, v), False)]
    extra = set(initial) - set(FIELDS)
    if extra:
        raise ScenarioError(
            f"{source} [initial]: unknown key(s) {sorted(extra)}; allowed: {FIELDS}"
        )

    tables: list[tuple[float, int, str, dict[str, Any]]] = []
    for kind in ("keyframe", "step"):
        entries = doc.get(kind, [])
        if not isinstance(entries, list):
            raise ScenarioError(f"{source}: use [[{kind}]] (an array of tables)")
        for i, entry in enumerate(entries):
            where = f"{source} [[{kind}]] #{i + 1}"
            if not isinstance(entry, dict):
                raise ScenarioError(
                    f"{where}: must be a table (a [[{kind}]] header and key = value lines), "
                    f"got {entry!r}"
                )
            if "t_s" not in entry:
                raise ScenarioError(f"{where}: t_s (seconds) is required")
            t = _number(where, "t_s", entry["t_s"])
            if not 0 <= t <= MAX_DURATION_S:
                raise ScenarioError(
                    f"{where}: t_s must be 0..{MAX_DURATION_S:g} s (a day), got {t:g}"
                )
            tables.append((t, i, kind, entry))
    for kind in ("keyframe", "step"):
        times = [t for t, _, k, _ in tables if k == kind]
        if times != sorted(times):
            raise ScenarioError(f"{source}: [[{kind}]] tables must be in time order")
    tables.sort(key=lambda x: x[0])
    last_t = 0.0
    for t, i, kind, entry in tables:
        where = f"{source} [[{kind}]] #{i + 1}"
        allowed = {"t_s", *FIELDS} | ({"interp"} if kind == "keyframe" else set())
        bad = set(entry) - allowed
        if bad:
            raise ScenarioError(
                f"{where}: unknown key(s) {sorted(bad)}; allowed: {sorted(allowed)}"
            )
        interp = entry.get("interp", "linear") if kind == "keyframe" else "hold"
        if interp not in _INTERP:
            raise ScenarioError(f"{where}: interp must be one of {_INTERP}, got {interp!r}")
        named = [k for k in FIELDS if k in entry]
        if not named:
            raise ScenarioError(f"{where}: names no field; give one of {FIELDS}")
        for key in named:
            v = _field_value(where, key, entry[key])
            if interp == "linear" and t == points[key][-1][0] and t > 0:
                raise ScenarioError(f'{where}: {key} ramps in zero time; use interp = "hold"')
            points[key].append((t, v, interp == "linear"))
        last_t = max(last_t, t)

    timelines = tuple(
        Timeline(
            tuple(p[0] for p in points[k]),
            tuple(p[1] for p in points[k]),
            tuple(p[2] for p in points[k]),
        )
        for k in FIELDS
    )
    if "duration_s" in doc:
        duration = _number(source, "duration_s", doc["duration_s"])
        if not 0 < duration <= MAX_DURATION_S:
            raise ScenarioError(
                f"{source}: duration_s must be above 0 and at most {MAX_DURATION_S:g} s"
                f" (a day), got {duration:g}"
            )
    else:
        duration = max(last_t, 1.0 / rate)
    steps = tuple(t for t in timelines[0].jumps() if t < duration)
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise ScenarioError(f"{source}: description must be a string")
    scenario_name = doc.get("name", name)
    if not isinstance(scenario_name, str):
        raise ScenarioError(f"{source}: name must be a string")
    return Scenario(scenario_name, description, rate, duration, timelines, steps)
