"""Reproducible fit of the calibrated profile to Table I and to the paper's text claims.

How this works: the objective is computed from ``expected_cells`` (the exact expectation
of every cell, no sampling), so it is smooth and the same on every run. It sums, over
the 13 two-sided Table I rows on ``PAPER_GRID``,

    (relative mean-error deviation / 0.25)^6 + (failure deviation in points / 5)^6

(a soft maximum: the sixth power makes the worst row dominate, aiming at every row
within 25 % and 5 points) plus squared hinge penalties for the claims in ``CLAIMS``.
All parameters are positive and searched in log space with a Nelder-Mead written
here (no scipy), restarted from the previous optimum until it stops improving, from a
fixed start and a few starts drawn from a seeded Generator; the best optimum wins.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from lunad.sim.paper_model import CalibratedProfile, CellStats, FloatArray, expected_cells
from lunad.sim.sweep import PAPER_GRID, RowResult, SweepGrid, expected_sweep, row_mask
from lunad.sim.table1 import FIT_ROWS, WORST_CASE_ROW, Interval, Table1Row

ERROR_TOLERANCE_REL = 0.25  # the aim: every row's mean error within 25 % (docs/paper-model.md)
FAILURE_TOLERANCE_PTS = 5.0  # ... and its failure rate within 5 points
SOFTMAX_POWER = 6
CLAIM_WEIGHT = 50.0
FIT_SEED = 3
RANDOM_STARTS = 2
EXPONENT_BOUNDS = (0.05, 10.0)  # keeps the alpha*p and m*p trade-offs from running away
S0_MIN = 1e-6
_EXPONENTS = frozenset({"alpha_r", "m_r", "p", "alpha_d", "m_d", "q"})

PARAM_NAMES: tuple[str, ...] = tuple(f.name for f in fields(CalibratedProfile) if f.name != "name")

START = CalibratedProfile(
    sigma0_cm=0.1,
    k_cm_per_klux=0.006,
    alpha_r=9.0,
    m_r=9.0,
    s0=1e-4,
    p=0.25,
    alpha_d=0.4,
    m_d=0.62,
    threshold_10klux=0.136,
    q=0.3,
    tau=0.8,
)
"""Deterministic first start (found by an earlier exploratory run of this same fit)."""


@dataclass(frozen=True, slots=True)
class Claim:
    """A claim of the paper's text, as a bound on a pooled slice of the sweep.

    Attributes:
        name: what the paper says and where.
        row: the slice (intervals of lux, R, theta), pooled like a Table I row.
        max_error_cm / min_error_cm: bounds on its mean error, cm (None: no bound).
        max_failure_pct / min_failure_pct: bounds on its failure rate, percent.
    """

    name: str
    row: Table1Row
    max_error_cm: float | None = None
    min_error_cm: float | None = None
    max_failure_pct: float | None = None
    min_failure_pct: float | None = None


def _slice(label: str, lux: Interval, r: Interval, theta: Interval) -> Table1Row:
    return Table1Row("claim", label, lux, r, theta, math.nan, math.nan)


CLAIMS: tuple[Claim, ...] = (
    Claim(
        "stable region (abstract, V): lux < 10 klux, R > 0.5, angle < 45 deg: sub-cm",
        _slice(
            "stable",
            Interval(0, 10000, hi_open=True),
            Interval(0.5, 0.9, lo_open=True),
            Interval(0, 45, hi_open=True),
        ),
        max_error_cm=1.0,
        min_error_cm=0.5,
        max_failure_pct=1.0,
    ),
    Claim(
        "R = 0.9 stays accurate up to 70 klux (IV.A): R 0.9, 70 klux, angle < 45 deg",
        _slice(
            "white at 70 klux",
            Interval(70000, 70000),
            Interval(0.9, 0.9),
            Interval(0, 45, hi_open=True),
        ),
        max_error_cm=2.0,
        max_failure_pct=2.0,
    ),
    Claim(
        "below 5000 lux: about 1.5 cm and no dropouts (V)",
        _slice("low light", Interval(0, 5000, hi_open=True), Interval(0.1, 0.9), Interval(0, 85)),
        max_error_cm=1.5 * (1 + ERROR_TOLERANCE_REL),
        max_failure_pct=0.5,
    ),
    Claim(
        "worst case (Table I): L > 50 klux, R 0.1, angle > 75 deg: > 9 cm, > 35 %",
        WORST_CASE_ROW,
        min_error_cm=9.0,
        min_failure_pct=35.0,
        max_failure_pct=95.0,
    ),
)
"""The text's claims the fit must respect (the sensor's 1 cm resolution sets the 0.5 cm floor)."""


@dataclass(frozen=True, slots=True)
class BoundCheck:
    """One criterion of a claim: a measured value against its bounds.

    Attributes:
        quantity: "mean error" (cm) or "failure rate" (percent).
        unit: "cm" or "%".
        value: the profile's pooled value (NaN: no valid reading, so no mean error).
        lo: lower bound, inclusive (None: none).
        hi: upper bound, inclusive (None: none).
    """

    quantity: str
    unit: str
    value: float
    lo: float | None
    hi: float | None

    @property
    def holds(self) -> bool:
        """The value is defined and within its bounds."""
        if math.isnan(self.value):
            return False
        return (self.lo is None or self.value >= self.lo) and (
            self.hi is None or self.value <= self.hi
        )

    def criterion(self) -> str:
        """The bounds in words, e.g. ``0.5 cm <= mean error <= 1 cm``."""
        q, u = self.quantity, self.unit
        if self.lo is not None and self.hi is not None:
            return f"{self.lo:g} {u} <= {q} <= {self.hi:g} {u}"
        if self.lo is not None:
            return f"{q} >= {self.lo:g} {u}"
        if self.hi is not None:
            return f"{q} <= {self.hi:g} {u}"
        return f"{q} defined (at least one valid reading)"

    def line(self) -> str:
        """``PASS``/``FAIL``, the measured value and the criterion it was judged by."""
        got = "none valid" if math.isnan(self.value) else f"{self.value:.2f} {self.unit}"
        mark = "PASS" if self.holds else "FAIL"
        return f"{mark} {self.quantity} {got}; criterion: {self.criterion()}"


@dataclass(frozen=True, slots=True)
class ClaimCheck:
    """A claim's value under a profile, each bound checked, and whether all hold."""

    name: str
    mean_error_cm: float
    failure_rate_pct: float
    bounds: tuple[BoundCheck, ...]

    @property
    def holds(self) -> bool:
        """Every bound holds (and the mean error is defined)."""
        return all(b.holds for b in self.bounds)


@dataclass(frozen=True, slots=True)
class FitResult:
    """Outcome of ``fit``: the profile, its objective, rows, claims and cost."""

    profile: CalibratedProfile
    objective: float
    rows: list[RowResult]
    claims: list[ClaimCheck]
    evaluations: int
    seconds: float


class _Objective:
    """The fit's objective on a grid, with the row masks computed once."""

    def __init__(self, grid: SweepGrid) -> None:
        self.lux, self.r, self.theta = grid.mesh()
        self.rows = np.array(
            [row_mask(r, self.lux, self.r, self.theta) for r in FIT_ROWS], dtype=float
        )
        self.claims = np.array(
            [row_mask(c.row, self.lux, self.r, self.theta) for c in CLAIMS], dtype=float
        )
        self.paper_err = np.array([r.mean_error_cm for r in FIT_ROWS])
        self.paper_fail = np.array([r.failure_rate_pct for r in FIT_ROWS])
        self.evaluations = 0

    def pooled(self, stats: CellStats, masks: FloatArray) -> tuple[FloatArray, FloatArray]:
        valid = masks @ stats.valid
        with np.errstate(invalid="ignore", divide="ignore"):
            err = (masks @ stats.abs_error_sum_cm) / valid
        return err, 100.0 * (1.0 - valid / masks.sum(axis=1))

    def __call__(self, x: FloatArray) -> float:
        self.evaluations += 1
        profile = to_profile(x)
        with np.errstate(all="ignore"):
            stats = expected_cells(profile, self.lux, self.r, self.theta)
            err, fail = self.pooled(stats, self.rows)
            c_err, c_fail = self.pooled(stats, self.claims)
        if not (np.all(np.isfinite(err)) and np.all(np.isfinite(c_err))):
            return 1e12
        rel = (err - self.paper_err) / self.paper_err / ERROR_TOLERANCE_REL
        pts = (fail - self.paper_fail) / FAILURE_TOLERANCE_PTS
        j = float(np.sum(rel**SOFTMAX_POWER) + np.sum(pts**SOFTMAX_POWER))
        return j + CLAIM_WEIGHT * _claim_penalty(c_err, c_fail)


def _hinge(value: float, lo: float | None, hi: float | None, scale: float) -> float:
    short = (lo - value) if lo is not None and value < lo else 0.0
    over = (value - hi) if hi is not None and value > hi else 0.0
    return ((short + over) / scale) ** 2


def _claim_penalty(err: FloatArray, fail: FloatArray) -> float:
    total = 0.0
    for claim, e, f in zip(CLAIMS, err, fail, strict=True):
        total += _hinge(float(e), claim.min_error_cm, claim.max_error_cm, 1.0)
        total += _hinge(
            float(f), claim.min_failure_pct, claim.max_failure_pct, FAILURE_TOLERANCE_PTS
        )
    return total


def to_vector(profile: CalibratedProfile) -> FloatArray:
    """Log of the parameters, the space the search runs in (all parameters are > 0)."""
    return np.log(np.array([max(getattr(profile, n), 1e-12) for n in PARAM_NAMES]))


def to_profile(x: FloatArray) -> CalibratedProfile:
    """Inverse of ``to_vector``, clipping exponents to ``EXPONENT_BOUNDS`` and s0 to S0_MIN."""
    values = {n: float(v) for n, v in zip(PARAM_NAMES, np.exp(x), strict=True)}
    for n in _EXPONENTS:
        values[n] = min(max(values[n], EXPONENT_BOUNDS[0]), EXPONENT_BOUNDS[1])
    values["s0"] = max(values["s0"], S0_MIN)
    return CalibratedProfile(**values)  # type: ignore[arg-type]  # keys: PARAM_NAMES, all floats


def nelder_mead(
    f: Callable[[FloatArray], float],
    x0: FloatArray,
    step: float = 0.3,
    max_evals: int = 2500,
    f_tol: float = 1e-9,
) -> tuple[FloatArray, float]:
    """Minimise ``f`` from ``x0`` (standard reflection/expansion/contraction/shrink)."""
    n = x0.size
    simplex = [x0.copy()] + [x0 + step * np.eye(n)[i] for i in range(n)]
    values = [f(x) for x in simplex]
    evals = n + 1
    while evals < max_evals:
        order = np.argsort(values)
        simplex = [simplex[i] for i in order]
        values = [values[i] for i in order]
        if abs(values[-1] - values[0]) <= f_tol * (abs(values[0]) + 1e-12):
            break
        centroid = np.mean(simplex[:-1], axis=0)
        xr = centroid + (centroid - simplex[-1])
        fr = f(xr)
        evals += 1
        if fr < values[0]:
            xe = centroid + 2.0 * (centroid - simplex[-1])
            fe = f(xe)
            evals += 1
            simplex[-1], values[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < values[-2]:
            simplex[-1], values[-1] = xr, fr
        else:
            xc = centroid + 0.5 * (simplex[-1] - centroid)
            fc = f(xc)
            evals += 1
            if fc < values[-1]:
                simplex[-1], values[-1] = xc, fc
            else:
                simplex = [simplex[0] + 0.5 * (x - simplex[0]) for x in simplex]
                values = [values[0]] + [f(x) for x in simplex[1:]]
                evals += n
    best = int(np.argmin(values))
    return simplex[best], values[best]


def _restarted(f: Callable[[FloatArray], float], x0: FloatArray) -> tuple[FloatArray, float]:
    x, fx = nelder_mead(f, x0)
    for _ in range(3):
        x_new, f_new = nelder_mead(f, x, step=0.1)
        if f_new >= fx * (1 - 1e-6):
            break
        x, fx = x_new, f_new
    return x, fx


def check_claims(profile: CalibratedProfile, grid: SweepGrid = PAPER_GRID) -> list[ClaimCheck]:
    """Evaluate ``CLAIMS`` for a profile from the exact expectation."""
    lux, r, t = grid.mesh()
    stats = expected_cells(profile, lux, r, t)
    out = []
    for claim in CLAIMS:
        mask = row_mask(claim.row, lux, r, t)
        valid = float(stats.valid[mask].sum())
        err = float(stats.abs_error_sum_cm[mask].sum()) / valid if valid > 0 else math.nan
        fail = float(100.0 * (1.0 - valid / mask.sum()))
        bounds = (
            BoundCheck("mean error", "cm", err, claim.min_error_cm, claim.max_error_cm),
            BoundCheck("failure rate", "%", fail, claim.min_failure_pct, claim.max_failure_pct),
        )
        out.append(ClaimCheck(claim.name, err, fail, bounds))
    return out


def format_claims(claims: Sequence[ClaimCheck]) -> str:
    """``--fit``'s claims: per claim its name, then one PASS/FAIL line per criterion.

    Each line carries the measured value and the bound it was judged by, so a FAIL
    says by how much without a look at the code.
    """
    lines = ["text claims (exact expectation on the sweep grid):"]
    for c in claims:
        lines.append(f"  {c.name}")
        lines += [f"    {b.line()}" for b in c.bounds]
    return "\n".join(lines) + "\n"


def fit(
    grid: SweepGrid = PAPER_GRID,
    seed: int = FIT_SEED,
    random_starts: int = RANDOM_STARTS,
    starts: Sequence[CalibratedProfile] = (START,),
) -> FitResult:
    """Fit the calibrated profile; same arguments, same result."""
    t0 = time.perf_counter()
    objective = _Objective(grid)
    rng = np.random.default_rng(seed)
    x_starts = [to_vector(s) for s in starts]
    x_starts += [x_starts[0] + rng.normal(0.0, 0.5, x_starts[0].size) for _ in range(random_starts)]
    best_x, best_f = x_starts[0], math.inf
    for x0 in x_starts:
        x, fx = _restarted(objective, x0)
        if fx < best_f:
            best_x, best_f = x, fx
    profile = replace(to_profile(best_x))
    rows = expected_sweep(profile, grid)
    return FitResult(
        profile,
        best_f,
        rows,
        check_claims(profile, grid),
        objective.evaluations,
        time.perf_counter() - t0,
    )


def format_profile(profile: CalibratedProfile) -> str:
    """The profile as Python source, ready to paste as ``CALIBRATED_DEFAULT``."""
    body = "".join(f"    {n}={getattr(profile, n):.6g},\n" for n in PARAM_NAMES)
    return f"CALIBRATED_DEFAULT = CalibratedProfile(\n{body})\n"
