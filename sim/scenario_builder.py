"""Scenario files built from truth functions of time: robot motion, a pan servo in a room, clouds.

How this works. A built scenario is a run of *pieces*: stretches of time over which
the truth (distance, reflectivity, incidence, lux) is a smooth function of time. Each
piece is sampled on candidate times one frame (4 ms) apart; from each keyframe the next
is the farthest candidate such that the straight line between the two stays within
every field's tolerance (TOLERANCES) at check points 1 ms apart and, in a piece with
acceleration, no more than ``max_gap_s`` away. Where two pieces meet, a field that
differs by more than its tolerance jumps: a linear keyframe ends the ramp with the
left-hand value and an ``interp = "hold"`` keyframe at the same time sets the right-hand
one (a *step* of sim/scenario.py when it is the distance). Points that only repeat a
constant value are dropped, and the rest is written as sim/scenario.py's TOML.

    python -m lunad.sim.scenario_builder               regenerate every built scenario
    python -m lunad.sim.scenario_builder room_sweep    one of them
    python -m lunad.sim.scenario_builder --check       exit 1 when a shipped file differs

The room of ``room_sweep`` is a floor plan of flat surfaces (segments, metres) and a
ray from the sensor meets the nearest one. The surface a ray sees can change only when
the ray passes a vertex, so the pieces run from vertex to vertex; within a piece the
distance is the ray's intersection with one surface's line, exact up to the piece's
ends, which gives the values on both sides of an edge.

Nothing here is random at run time: the clouds draw from a seeded generator, so
regenerating gives the shipped files byte for byte (tests/test_scenario_builder.py).
"""

from __future__ import annotations

import argparse
import itertools
import math
import random
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

from lunad.sim.physics import Truth
from lunad.sim.scenario import FIELDS

RATE_HZ = 250  # every built scenario runs at the TF-Luna's fastest frame rate, M05 p.9
GRID_S = 0.004  # keyframe candidates one frame apart at 250 Hz, so no knot falls between frames
CHECKS_PER_GRID = 4  # tolerance checked every 1 ms, finer than the frames that read the truth
MAX_GAP_ACCEL_S = 0.020
"""Longest gap between keyframes where the acceleration is not zero, seconds: a truth
sampled every 20 ms reads the stated acceleration in a 5-frame second difference, and
its linear interpolation is off by at most a h^2 / 8 = 0.5 mm at 10 m/s^2."""

TOLERANCES: Mapping[str, float] = {
    # 2 mm of the true (ray-cast) distance, less 0.2 mm for what lies between check points
    "distance_m": 0.0018,
    # reflectivity only jumps (between surfaces); any real ramp is kept to 1e-3
    "reflectivity": 0.001,
    # cos(theta) and so amp off by under 2 % up to 80 deg, below the 3 % amp jitter
    # of physics.AMP_NOISE_FRACTION
    "angle_deg": 0.2,
    # the realistic noise grows by k x 300 lux = 0.08 mm (physics.REALISTIC_K_M_PER_LUX)
    "lux": 300.0,
}
"""Largest error of the linear interpolation between keyframes, per field, in its unit."""

DECIMALS: Mapping[str, int] = {
    "t_s": 6,  # 1 us: edge times are irrational; 1 us moves an edge by 0.09 mdeg at 90 deg/s
    "distance_m": 6,  # 1 um keeps a 20 ms second difference within 0.01 m/s^2
    "reflectivity": 4,
    "angle_deg": 4,
    "lux": 1,
}
"""Decimal places written for each field: fixed, so the text is the same on every run."""

SCENARIOS_DIR = Path(__file__).resolve().parent / "scenarios"

Point = tuple[float, float, bool]
"""One point of a field's timeline: (t_s, value, hold); hold: jump there, else ramp."""


@dataclass(frozen=True, slots=True)
class Piece:
    """A stretch of time over which the truth is a smooth function of time.

    Attributes:
        t0_s, t1_s: start and end, seconds from the scenario's start.
        truth: the truth at any time in [t0_s, t1_s], ends included (its limits there).
        straight: every field is linear in time over the piece: only its ends are kept.
        max_gap_s: longest time between keyframes, seconds; None: the tolerances decide.
    """

    t0_s: float
    t1_s: float
    truth: Callable[[float], Truth]
    straight: bool = False
    max_gap_s: float | None = None


@dataclass(frozen=True, slots=True)
class Recipe:
    """What one built scenario file holds.

    Attributes:
        name: the file's stem, as ``lunad eval --scenario`` takes it.
        description: one line for listings.
        duration_s: length, seconds.
        pieces: the truth, piece after piece from t = 0 to at least duration_s.
    """

    name: str
    description: str
    duration_s: float
    pieces: tuple[Piece, ...]


def _values(truth: Truth) -> tuple[float, ...]:
    return tuple(getattr(truth, f) for f in FIELDS)


def _knots(piece: Piece, tolerances: Mapping[str, float], grid_s: float) -> list[float]:
    """Keyframe times within ``piece``, its ends included, seconds."""
    t0, t1 = piece.t0_s, piece.t1_s
    if piece.straight:
        return [t0, t1]
    cand = [t0]
    i = 1
    while t0 + i * grid_s < t1 - 0.5 * grid_s:
        cand.append(t0 + i * grid_s)
        i += 1
    cand.append(t1)
    fine_t: list[float] = []
    for a, b in itertools.pairwise(cand):
        fine_t.extend(a + (b - a) * k / CHECKS_PER_GRID for k in range(CHECKS_PER_GRID))
    fine_t.append(t1)
    fine = [_values(piece.truth(t)) for t in fine_t]
    tol = [tolerances[f] for f in FIELDS]

    def fits(a: int, b: int) -> bool:
        ia, ib = a * CHECKS_PER_GRID, b * CHECKS_PER_GRID
        ta, tb = fine_t[ia], fine_t[ib]
        va, vb = fine[ia], fine[ib]
        for k in range(ia + 1, ib):
            w = (fine_t[k] - ta) / (tb - ta)
            for j, v in enumerate(fine[k]):
                if abs(v - (va[j] + (vb[j] - va[j]) * w)) > tol[j]:
                    return False
        return True

    gap = piece.max_gap_s
    last = len(cand) - 1
    knots = [0]
    a = 0
    while a < last:
        b = a + 1
        while b < last and (gap is None or cand[b + 1] - cand[a] <= gap + 1e-9) and fits(a, b + 1):
            b += 1
        knots.append(b)
        a = b
    return [cand[k] for k in knots]


def sample(
    pieces: Sequence[Piece],
    tolerances: Mapping[str, float] = TOLERANCES,
    grid_s: float = GRID_S,
) -> dict[str, list[Point]]:
    """Sample pieces into each field's timeline: linear within tolerance, hold at jumps.

    Args:
        pieces: contiguous pieces, the first starting at t = 0 s.
        tolerances: largest interpolation error per field, in its unit; a field that
            changes by more than this where two pieces meet jumps there.
        grid_s: spacing of candidate keyframe times, seconds.

    Returns:
        For each field of FIELDS, its points (t_s, value, hold), rounded to DECIMALS;
        the first is at t = 0 s.

    Raises:
        ValueError: pieces that do not start at 0, leave gaps, have no length, or
            put two keyframes of a field within the 1 us the times are written to.
    """
    if not pieces or pieces[0].t0_s != 0.0:
        raise ValueError("the first piece must start at t = 0 s")
    points: dict[str, list[Point]] = {f: [] for f in FIELDS}

    def put(f: str, t: float, value: float, hold: bool) -> None:
        t_r = round(t, DECIMALS["t_s"])
        line = points[f]
        if line and (t_r < line[-1][0] or (t_r == line[-1][0] and not hold)):
            raise ValueError(f"{f}: two keyframes within 1 us at t = {t_r} s")
        line.append((t_r, round(value, DECIMALS[f]), hold))

    prev: Piece | None = None
    for piece in pieces:
        if not piece.t1_s > piece.t0_s:
            raise ValueError(f"piece at {piece.t0_s} s has no length")
        knots = _knots(piece, tolerances, grid_s)
        if prev is not None:
            if piece.t0_s != prev.t1_s:
                raise ValueError(f"pieces must meet: {prev.t1_s} s then {piece.t0_s} s")
            left, right = prev.truth(piece.t0_s), piece.truth(piece.t0_s)
            for f in FIELDS:
                if abs(getattr(right, f) - getattr(left, f)) > tolerances[f]:
                    put(f, piece.t0_s, getattr(right, f), True)
            knots = knots[1:]
        for t in knots:
            truth = piece.truth(t)
            for f in FIELDS:
                put(f, t, getattr(truth, f), False)
        prev = piece
    return points


def simplify(points: Sequence[Point]) -> list[Point]:
    """Drop points that only repeat a constant value; the timeline stays the same.

    A point goes when it equals the last point kept and the next point equals it too,
    or jumps (a hold keeps the old value up to its own time anyway), or there is none.
    """
    if not points:
        return []
    out = [points[0]]
    for i in range(1, len(points)):
        _, value, _ = points[i]
        nxt = points[i + 1] if i + 1 < len(points) else None
        if value == out[-1][1] and (nxt is None or nxt[2] or nxt[1] == value):
            continue
        out.append(points[i])
    return out


def _fmt(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def to_toml(recipe: Recipe, points: Mapping[str, Sequence[Point]]) -> str:
    """The scenario file's text: a header comment, [initial], then [[keyframe]] tables.

    Keyframes at one time are written ramps first, then the hold, which is the order
    sim/scenario.py needs to end a ramp and jump at the same instant.
    """
    if '"' in recipe.description or "\\" in recipe.description:
        raise ValueError("description must not hold quotes or backslashes")
    lines = [
        f"# Generated by `python -m lunad.sim.scenario_builder {recipe.name}`:"
        " edit sim/scenario_builder.py, not this file.",
        f'description = "{recipe.description}"',
        f"rate_hz = {RATE_HZ}",
        f"duration_s = {_fmt(recipe.duration_s, DECIMALS['t_s'])}",
        "",
        "[initial]",
    ]
    tables: dict[tuple[float, bool], dict[str, float]] = {}
    for f in FIELDS:
        line = simplify(points[f])
        if not line or line[0][0] != 0.0:
            raise ValueError(f"{f}: the first point must be at t = 0 s")
        lines.append(f"{f} = {_fmt(line[0][1], DECIMALS[f])}")
        for t, value, hold in line[1:]:
            tables.setdefault((t, hold), {})[f] = value
    for (t, hold), fields in sorted(tables.items()):
        lines += ["", "[[keyframe]]", f"t_s = {_fmt(t, DECIMALS['t_s'])}"]
        lines += [f"{f} = {_fmt(v, DECIMALS[f])}" for f, v in fields.items()]
        if hold:
            lines.append('interp = "hold"')
    return "\n".join(lines) + "\n"


# -- motion ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Phase:
    """A stretch of constant acceleration.

    Attributes:
        duration_s: length, seconds.
        accel_m_s2: second derivative of the distance, m/s^2 (negative: closing faster).
    """

    duration_s: float
    accel_m_s2: float


def _moving(base: Truth, t0: float, d0: float, v0: float, a: float, t: float) -> Truth:
    u = t - t0
    return replace(base, distance_m=d0 + v0 * u + 0.5 * a * u * u)


def motion_pieces(start_m: float, phases: Sequence[Phase], base: Truth) -> tuple[Piece, ...]:
    """Pieces for a target that starts still at ``start_m`` metres and runs ``phases``.

    ``base`` gives the fields that do not move (reflectivity, angle, lux). A phase with
    acceleration is sampled at least every MAX_GAP_ACCEL_S; one without is a straight line.
    """
    pieces = []
    t, d, v = 0.0, start_m, 0.0
    for ph in phases:
        a, dt = ph.accel_m_s2, ph.duration_s
        pieces.append(
            Piece(
                t,
                t + dt,
                partial(_moving, base, t, d, v, a),
                straight=a == 0.0,
                max_gap_s=None if a == 0.0 else MAX_GAP_ACCEL_S,
            )
        )
        t, d, v = t + dt, d + v * dt + 0.5 * a * dt * dt, v + a * dt
    return tuple(pieces)


def wall_drive() -> Recipe:
    """A robot drives at a sunlit wall from 6 m and brakes to a stop at 0.3 m."""
    start_m, stop_m = 6.0, 0.3
    speed_m_s = 1.5
    accel_m_s2 = 3.0  # gentle start, 0.5 s to cruising speed
    brake_m_s2 = 8.0  # hard braking, 0.19 s to a stop
    still_s = 0.5  # stands before it starts
    parked_s = 2.0  # and after it stops
    accel_s, brake_s = speed_m_s / accel_m_s2, speed_m_s / brake_m_s2
    ramps_m = 0.5 * speed_m_s * (accel_s + brake_s)
    cruise_s = (start_m - stop_m - ramps_m) / speed_m_s
    phases = [
        Phase(still_s, 0.0),
        Phase(accel_s, -accel_m_s2),
        Phase(cruise_s, 0.0),
        Phase(brake_s, brake_m_s2),
        Phase(parked_s, 0.0),
    ]
    base = Truth(start_m, reflectivity=0.6, angle_deg=10.0, lux=30_000.0)
    return Recipe(
        "wall_drive",
        "Robot drives at a sunlit grey wall (R 0.6, 10 deg, 30 klux) at 1.5 m/s: "
        "6 m to a stop at 0.3 m",
        sum(p.duration_s for p in phases),
        motion_pieces(start_m, phases, base),
    )


def manoeuvres() -> Recipe:
    """A target that darts away, reverses, stops dead near the sensor, then backs off."""
    accel_m_s2 = 10.0  # a nimble robot: every hard manoeuvre at 10 m/s^2 ...
    speed_m_s = 3.0  # ... up to 3 m/s, 0.3 s and 0.45 m to get there
    slow_m_s = 0.3  # backing away slowly
    slow_accel_m_s2 = 1.0  # our choice: a gentle start, 0.3 s to 0.3 m/s
    ramp_s = speed_m_s / accel_m_s2
    # 1.1 m + 0.45 m + 3.6 m cruising out + 0.45 m braking = 5.6 m at the far end; back
    # 0.45 m + 4.2 m cruising + 0.45 m braking: a stop at 0.5 m at t = 4.3 s
    phases = [
        Phase(0.5, 0.0),
        Phase(ramp_s, accel_m_s2),
        Phase(1.2, 0.0),
        Phase(2 * ramp_s, -accel_m_s2),  # brakes and reverses in one go
        Phase(1.4, 0.0),
        Phase(ramp_s, accel_m_s2),  # stops dead at 0.5 m: full braking, no creeping
        Phase(2.0, 0.0),
        Phase(slow_m_s / slow_accel_m_s2, slow_accel_m_s2),
        Phase(5.4, 0.0),
    ]
    base = Truth(1.1, reflectivity=0.6, angle_deg=0.0, lux=300.0)
    return Recipe(
        "manoeuvres",
        "Target (R 0.6) darts to 5.6 m and back at 3 m/s, 10 m/s^2 turns, stops at 0.5 m, "
        "backs off",
        sum(p.duration_s for p in phases),
        motion_pieces(1.1, phases, base),
    )


# -- clouds ------------------------------------------------------------------------

CLOUD_SEED = 7  # picked for a mix: 6 ramps and 3 sudden changes in 10 s
CLOUD_LUX_RANGE = (2_000.0, 60_000.0)  # deep cloud shadow to full sun, below the 70 klux limit


def _lux(base: Truth, t0: float, t1: float, a: float, b: float, t: float) -> Truth:
    # raised cosine: a cloud's shadow edge starts and ends softly
    u = min(1.0, max(0.0, (t - t0) / (t1 - t0)))
    return replace(base, lux=a + (b - a) * 0.5 * (1.0 - math.cos(math.pi * u)))


def cloud_flicker() -> Recipe:
    """Clouds over a grey target: ramps of 0.3-2 s and a few sudden changes, seeded."""
    duration_s = 10.0
    dwell_s = (0.2, 1.2)  # light stays put this long between changes
    ramp_s = (0.3, 2.0)  # a cloud edge crosses the sun in 0.3-2 s
    sudden_share = 0.3  # share of changes that are sudden (a hard-edged cloud)
    rng = random.Random(CLOUD_SEED)
    lo, hi = (math.log(x) for x in CLOUD_LUX_RANGE)
    mid = 0.5 * (lo + hi)
    # (t0, t1, log-lux at t0, log-lux at t1, ramp); levels alternate sun and shade
    spans: list[tuple[float, float, float, float, bool]] = []
    t, level = 0.0, hi
    while t < duration_s:
        t1 = min(duration_s, round(t + rng.uniform(*dwell_s), 2))
        spans.append((t, t1, level, level, False))
        t = t1
        if t >= duration_s:
            break
        # from sun into the darker 40 % of the log range, from shade into the brighter 40 %
        reach = 0.4 * (hi - lo)
        nxt = rng.uniform(lo, lo + reach) if level > mid else rng.uniform(hi - reach, hi)
        if rng.random() >= sudden_share:
            t1 = min(duration_s, round(t + rng.uniform(*ramp_s), 2))
            spans.append((t, t1, level, nxt, True))
            t = t1
        level = nxt
    # stretch the drawn levels so that the darkest is 2 klux and the brightest 60 klux
    drawn = [x for s in spans for x in s[2:4]]
    d_lo, d_hi = min(drawn), max(drawn)

    def lux(x: float) -> float:
        return math.exp(lo + (x - d_lo) * (hi - lo) / (d_hi - d_lo))

    base = Truth(3.0, reflectivity=0.5, angle_deg=40.0)
    pieces = tuple(
        Piece(t0, t1, partial(_lux, base, t0, t1, lux(a), lux(b)), straight=not ramp)
        for t0, t1, a, b, ramp in spans
    )
    return Recipe(
        "cloud_flicker",
        "Grey target (R 0.5) at 3 m, 40 deg, as clouds pass: 2-60 klux, ramps and sudden changes",
        duration_s,
        pieces,
    )


# -- the room ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Surface:
    """A flat vertical surface seen from above: a segment of the floor plan.

    Attributes:
        name: what it is, for messages and tests.
        x0_m, y0_m, x1_m, y1_m: its ends, metres (room coordinates).
        reflectivity: its R, 0..1.
    """

    name: str
    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float
    reflectivity: float


@dataclass(frozen=True, slots=True)
class Hit:
    """Where a ray meets a surface.

    Attributes:
        surface: the surface met.
        distance_m: along the ray, metres.
        angle_deg: incidence, between the ray and the surface normal, capped at
            INCIDENCE_CAP_DEG.
    """

    surface: Surface
    distance_m: float
    angle_deg: float


INCIDENCE_CAP_DEG = 85.0  # a beam about 2 deg wide never meets a surface exactly edge-on

WALL_R = 0.8  # white emulsion paint
CORRIDOR_R = 0.6  # the corridor's wall, in its own (greyer) light
SOFA_R = 0.2  # dark fabric
CABINET_R = 0.45  # oak veneer

SENSOR_XY_M = (1.2, 1.5)
"""The sensor in the 5 x 7 m room, metres. x across the room, y along it; pan 0 looks
along +y, positive pans turn left (counter-clockwise, as ROS REP 103). Walls lie 1.2
(left), 1.5 (behind), 3.8 (right) and 5.5 m (ahead) away; the two corners ahead are in
view, the back-left one is behind the sweep and the cabinet hides the back-right one."""


def box(name: str, x0_m: float, y0_m: float, x1_m: float, y1_m: float, r: float) -> list[Surface]:
    """The four sides of an upright box, corners (x0, y0) and (x1, y1), metres."""
    return [
        Surface(f"{name} south", x0_m, y0_m, x1_m, y0_m, r),
        Surface(f"{name} east", x1_m, y0_m, x1_m, y1_m, r),
        Surface(f"{name} north", x1_m, y1_m, x0_m, y1_m, r),
        Surface(f"{name} west", x0_m, y1_m, x0_m, y0_m, r),
    ]


ROOM: tuple[Surface, ...] = (
    Surface("back wall", 0.0, 0.0, 5.0, 0.0, WALL_R),
    Surface("right wall", 5.0, 0.0, 5.0, 7.0, WALL_R),
    Surface("front wall", 5.0, 7.0, 0.0, 7.0, WALL_R),
    # the left wall has a 0.9 m doorway at y 2.6-3.5 m onto a 1.5 m wide corridor
    Surface("left wall, ahead of the door", 0.0, 7.0, 0.0, 3.5, WALL_R),
    Surface("left wall, behind the door", 0.0, 2.6, 0.0, 0.0, WALL_R),
    Surface("corridor wall", -1.5, -1.0, -1.5, 10.0, CORRIDOR_R),
    # a sofa with its back to the sensor, 1.3-1.9 m away; a sideboard against the back
    # wall, 1.5-2.6 m away
    *box("sofa", 2.5, 1.3, 3.3, 2.9, SOFA_R),
    *box("cabinet", 2.4, 0.0, 3.6, 0.6, CABINET_R),
)
"""The room's floor plan: walls, doorway, corridor, sofa, cabinet."""

SWEEP_HALF_DEG = 135.0  # a 270 deg servo pans over +-135 deg ...
SWEEP_RATE_DEG_S = 90.0  # ... at 90 deg/s, reversing at each end: 3 s a sweep
SWEEP_LEGS = 4  # four sweeps, 12 s
ROOM_LUX = 300.0  # indoor light


def _ray(pan_deg: float) -> tuple[float, float]:
    p = math.radians(pan_deg)
    return -math.sin(p), math.cos(p)


def _cross(ax: float, ay: float, bx: float, by: float) -> float:
    return ax * by - ay * bx


def hit_line(surface: Surface, origin_m: tuple[float, float], pan_deg: float) -> Hit | None:
    """Where the ray at ``pan_deg`` meets ``surface``'s line (extended past its ends).

    Returns None when the ray runs parallel to it or the line lies behind the sensor.
    """
    ux, uy = _ray(pan_deg)
    ex, ey = surface.x1_m - surface.x0_m, surface.y1_m - surface.y0_m
    den = _cross(ux, uy, ex, ey)
    if abs(den) < 1e-12:
        return None
    wx, wy = surface.x0_m - origin_m[0], surface.y0_m - origin_m[1]
    dist = _cross(wx, wy, ex, ey) / den
    if dist <= 0.0:
        return None
    cos_inc = abs(_cross(ux, uy, ex, ey)) / math.hypot(ex, ey)
    angle = math.degrees(math.acos(min(1.0, cos_inc)))
    return Hit(surface, dist, min(angle, INCIDENCE_CAP_DEG))


def cast(surfaces: Sequence[Surface], origin_m: tuple[float, float], pan_deg: float) -> Hit | None:
    """The first surface the ray at ``pan_deg`` meets (ends included), or None."""
    ux, uy = _ray(pan_deg)
    best: Hit | None = None
    for s in surfaces:
        hit = hit_line(s, origin_m, pan_deg)
        if hit is None or (best is not None and hit.distance_m >= best.distance_m):
            continue
        ex, ey = s.x1_m - s.x0_m, s.y1_m - s.y0_m
        wx, wy = s.x0_m - origin_m[0], s.y0_m - origin_m[1]
        along = _cross(wx, wy, ux, uy) / _cross(ux, uy, ex, ey)
        if -1e-12 <= along <= 1.0 + 1e-12:
            best = hit
    return best


def sweep_pan_deg(t_s: float) -> float:
    """The servo's pan at ``t_s`` seconds: -135 to +135 deg and back, 90 deg/s."""
    leg_s = 2.0 * SWEEP_HALF_DEG / SWEEP_RATE_DEG_S
    k = min(int(t_s // leg_s), SWEEP_LEGS - 1)
    u = t_s - k * leg_s
    if k % 2 == 0:
        return -SWEEP_HALF_DEG + SWEEP_RATE_DEG_S * u
    return SWEEP_HALF_DEG - SWEEP_RATE_DEG_S * u


def room_truth(t_s: float) -> Truth:
    """The truth at ``t_s`` seconds by casting the ray afresh: what room_sweep samples."""
    hit = cast(ROOM, SENSOR_XY_M, sweep_pan_deg(t_s))
    if hit is None:
        raise ValueError(f"the ray at {sweep_pan_deg(t_s):.3f} deg leaves the room")
    return Truth(hit.distance_m, hit.surface.reflectivity, hit.angle_deg, ROOM_LUX)


def _on_surface(surface: Surface, t_s: float) -> Truth:
    hit = hit_line(surface, SENSOR_XY_M, sweep_pan_deg(t_s))
    if hit is None:
        raise ValueError(f"{surface.name} is not in front of the ray at t = {t_s} s")
    return Truth(hit.distance_m, surface.reflectivity, hit.angle_deg, ROOM_LUX)


def room_pieces() -> tuple[Piece, ...]:
    """One piece per surface seen in each sweep, split where the ray passes a vertex."""
    ox, oy = SENSOR_XY_M
    vertex_pans = sorted(
        {
            math.degrees(math.atan2(-(x - ox), y - oy))
            for s in ROOM
            for x, y in ((s.x0_m, s.y0_m), (s.x1_m, s.y1_m))
        }
    )
    leg_s = 2.0 * SWEEP_HALF_DEG / SWEEP_RATE_DEG_S
    pieces: list[Piece] = []
    for k in range(SWEEP_LEGS):
        t_leg = k * leg_s
        inside = [p for p in vertex_pans if abs(p) < SWEEP_HALF_DEG - 1e-9]
        offsets = sorted(abs(p - sweep_pan_deg(t_leg)) / SWEEP_RATE_DEG_S for p in inside)
        bounds = [t_leg, *(t_leg + u for u in offsets), t_leg + leg_s]
        seen: list[tuple[float, float, Surface]] = []
        for t0, t1 in itertools.pairwise(bounds):
            hit = cast(ROOM, SENSOR_XY_M, sweep_pan_deg(0.5 * (t0 + t1)))
            if hit is None:
                raise ValueError(f"the ray leaves the room at t = {0.5 * (t0 + t1)} s")
            if seen and seen[-1][2] == hit.surface:  # a vertex of a hidden surface
                seen[-1] = (seen[-1][0], t1, hit.surface)
            else:
                seen.append((t0, t1, hit.surface))
        pieces += [Piece(t0, t1, partial(_on_surface, s)) for t0, t1, s in seen]
    return tuple(pieces)


def room_sweep() -> Recipe:
    """A pan servo sweeps the sensor around a furnished room (see ROOM)."""
    return Recipe(
        "room_sweep",
        "Pan servo sweeps +-135 deg at 90 deg/s round a room: walls, corners, a doorway, "
        "a sofa, a cabinet",
        SWEEP_LEGS * 2.0 * SWEEP_HALF_DEG / SWEEP_RATE_DEG_S,
        room_pieces(),
    )


# -- files -------------------------------------------------------------------------

RECIPES: Mapping[str, Callable[[], Recipe]] = {
    "cloud_flicker": cloud_flicker,
    "manoeuvres": manoeuvres,
    "room_sweep": room_sweep,
    "wall_drive": wall_drive,
}
"""Every built scenario by name (the others in sim/scenarios/ are written by hand)."""


def build_text(name: str) -> str:
    """The text of built scenario ``name``'s file.

    Raises:
        KeyError: ``name`` is not in RECIPES.
    """
    recipe = RECIPES[name]()
    return to_toml(recipe, sample(recipe.pieces))


def main(argv: Sequence[str] | None = None) -> int:
    """Regenerate built scenario files; returns the exit code (1: ``--check`` found a change)."""
    parser = argparse.ArgumentParser(
        prog="python -m lunad.sim.scenario_builder",
        description="Regenerate the scenario files built from truth functions of time.",
    )
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help=f"default: all of {', '.join(RECIPES)}"
    )
    parser.add_argument("--out", type=Path, default=SCENARIOS_DIR, help="folder to write to")
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 when a file would change"
    )
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in RECIPES]
    if unknown:
        parser.error(f"unknown scenario(s) {', '.join(unknown)}; built ones: {', '.join(RECIPES)}")
    changed = []
    for name in args.names or list(RECIPES):
        path = args.out / f"{name}.toml"
        text = build_text(name)
        old = path.read_text(encoding="utf-8") if path.exists() else None
        if args.check:
            if old != text:
                changed.append(name)
                print(f"{path}: differs from what {name} builds")
            continue
        path.write_text(text, encoding="utf-8")
        print(f"{path}: {len(text.encode())} bytes, {text.count('[[keyframe]]')} keyframes")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
