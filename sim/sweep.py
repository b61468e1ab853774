"""The paper's full factorial sweep and Table I side by side.

How this works: ``SweepGrid`` is the factorial grid (lux x R x theta, section III.1).
A profile from ``lunad.sim.paper_model`` turns every cell into N readings (or their
exact expectation); ``table1_results`` pools, for each Table I row, every reading of
every cell inside the row's intervals (``lunad.sim.table1``): the row's mean error is
the mean |error| over its valid readings, its failure rate the share of dropped
readings. Every cell counts once (uniform weighting). The worst deviation is taken
over the 13 two-sided rows: relative for the mean error, in percentage points for the
failure rate; the one-sided worst-case row only counts when it falls short.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lunad.sim.paper_model import (
    READINGS_PER_SCENARIO,
    CellStats,
    FloatArray,
    Profile,
    expected_cells,
    simulate_cells,
)
from lunad.sim.table1 import TABLE1_ROWS, Table1Row

DEFAULT_SEED = 2024


@dataclass(frozen=True, slots=True)
class SweepGrid:
    """Factorial grid: the levels of each factor (lux, reflectivity, degrees)."""

    lux: tuple[float, ...]
    reflectivity: tuple[float, ...]
    theta_deg: tuple[float, ...]

    def mesh(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Flattened (lux, R, theta) arrays, one entry per cell, lux varying slowest."""
        lux, r, t = np.meshgrid(
            np.array(self.lux),
            np.array(self.reflectivity),
            np.array(self.theta_deg),
            indexing="ij",
        )
        return lux.ravel(), r.ravel(), t.ravel()

    @property
    def cells(self) -> int:
        """Number of cells."""
        return len(self.lux) * len(self.reflectivity) * len(self.theta_deg)


PAPER_GRID = SweepGrid(
    # Three levels per lux row below 20 klux, 10-klux steps above (docs/paper-model.md
    # explains why a uniform 1-klux grid cannot fit Table I's lux and R rows at once).
    lux=(0, 1000, 2500, 5000, 10000, 15000, 20000, 30000, 40000, 50000, 60000, 70000),
    reflectivity=tuple(round(0.1 * i, 1) for i in range(1, 10)),
    theta_deg=tuple(float(a) for a in range(0, 90, 5)),
)
"""The grid Table I is compared on: 12 lux levels x R 0.1..0.9 step 0.1 x 0..85 deg step 5."""

UNIFORM_GRID = SweepGrid(
    lux=tuple(float(x) for x in range(0, 70_001, 1000)),
    reflectivity=PAPER_GRID.reflectivity,
    theta_deg=PAPER_GRID.theta_deg,
)
"""A uniform 1-klux grid, for comparison in the docs."""


@dataclass(frozen=True, slots=True)
class RowResult:
    """One Table I row: the paper's numbers and a profile's, side by side.

    Attributes:
        profile: profile name.
        condition: Table I label.
        group: Table I block.
        mean_error_cm: the profile's mean absolute error of valid readings, cm (NaN if none).
        failure_rate_pct: the profile's dropout rate, percent.
        paper_mean_error_cm: Table I's mean error, cm.
        paper_failure_rate_pct: Table I's failure rate, percent.
        lower_bound: Table I gives ">" values only.
    """

    profile: str
    condition: str
    group: str
    mean_error_cm: float
    failure_rate_pct: float
    paper_mean_error_cm: float
    paper_failure_rate_pct: float
    lower_bound: bool

    @property
    def error_deviation(self) -> float:
        """Relative deviation of the mean error (0.1 = 10 %); for ">" rows only a shortfall."""
        if math.isnan(self.mean_error_cm):
            return math.inf
        dev = (self.mean_error_cm - self.paper_mean_error_cm) / self.paper_mean_error_cm
        return min(dev, 0.0) if self.lower_bound else dev

    @property
    def failure_deviation_pts(self) -> float:
        """Failure rate minus Table I's, percentage points; for ">" rows only a shortfall."""
        dev = self.failure_rate_pct - self.paper_failure_rate_pct
        return min(dev, 0.0) if self.lower_bound else dev

    def to_json(self) -> dict[str, object]:
        """The ``--format json`` object (NaN becomes null)."""
        return {
            "profile": self.profile,
            "condition": self.condition,
            "mean_error_cm": None if math.isnan(self.mean_error_cm) else self.mean_error_cm,
            "failure_rate_pct": self.failure_rate_pct,
            "paper_mean_error_cm": self.paper_mean_error_cm,
            "paper_failure_rate_pct": self.paper_failure_rate_pct,
        }


@dataclass(frozen=True, slots=True)
class Worst:
    """The largest deviations over the two-sided rows (and the worst-case row's shortfall)."""

    error_rel: float
    error_condition: str
    failure_pts: float
    failure_condition: str


def row_mask(row: Table1Row, lux: FloatArray, r: FloatArray, theta: FloatArray) -> FloatArray:
    """Boolean mask of the cells a Table I row summarises."""
    inside = np.vectorize(lambda x, iv: iv.contains(float(x)), otypes=[bool], excluded={1})
    return inside(lux, row.lux) & inside(r, row.reflectivity) & inside(theta, row.theta_deg)


def pool(stats: CellStats, mask: FloatArray) -> tuple[float, float]:
    """Pooled (mean error cm, failure %) of the cells in ``mask``."""
    valid = float(np.sum(stats.valid[mask]))
    total = float(np.count_nonzero(mask)) * stats.readings
    err = float(np.sum(stats.abs_error_sum_cm[mask])) / valid if valid > 0 else math.nan
    return err, 100.0 * (1.0 - valid / total) if total else math.nan


def table1_results(
    profile_name: str,
    stats: CellStats,
    grid: SweepGrid,
    rows: Sequence[Table1Row] = TABLE1_ROWS,
) -> list[RowResult]:
    """Pool the sweep's cells into Table I's rows."""
    lux, r, t = grid.mesh()
    out = []
    for row in rows:
        err, fail = pool(stats, row_mask(row, lux, r, t))
        out.append(
            RowResult(
                profile_name,
                row.condition,
                row.group,
                err,
                fail,
                row.mean_error_cm,
                row.failure_rate_pct,
                row.lower_bound,
            )
        )
    return out


def run_sweep(
    profile: Profile,
    grid: SweepGrid = PAPER_GRID,
    readings: int = READINGS_PER_SCENARIO,
    seed: int | None = DEFAULT_SEED,
) -> list[RowResult]:
    """Simulate every cell of ``grid`` with ``readings`` readings and pool Table I's rows."""
    lux, r, t = grid.mesh()
    stats = simulate_cells(profile, lux, r, t, readings, np.random.default_rng(seed))
    return table1_results(profile.name, stats, grid)


def expected_sweep(profile: Profile, grid: SweepGrid = PAPER_GRID) -> list[RowResult]:
    """Table I's rows from the exact expectation (no sampling)."""
    lux, r, t = grid.mesh()
    return table1_results(profile.name, expected_cells(profile, lux, r, t), grid)


def worst_deviation(results: Sequence[RowResult]) -> Worst:
    """Largest |relative error deviation| and |failure deviation| over the two-sided rows."""
    two_sided = [r for r in results if not r.lower_bound] or list(results)
    by_err = max(two_sided, key=lambda x: abs(x.error_deviation))
    by_fail = max(two_sided, key=lambda x: abs(x.failure_deviation_pts))
    return Worst(
        by_err.error_deviation, by_err.condition, by_fail.failure_deviation_pts, by_fail.condition
    )


def _num(x: float, fmt: str) -> str:
    return "-" if math.isnan(x) else format(x, fmt)


def format_table(results: Sequence[RowResult]) -> str:
    """Human-readable side-by-side table of one or more profiles, with worst deviations."""
    lines: list[str] = []
    profiles = list(dict.fromkeys(r.profile for r in results))
    for name in profiles:
        rows = [r for r in results if r.profile == name]
        lines.append(f"profile: {name}")
        lines.append(
            f"  {'condition':36s} {'paper cm':>9s} {'model cm':>9s} {'dev':>7s}"
            f" {'paper %':>8s} {'model %':>8s} {'dev pts':>8s}"
        )
        for r in rows:
            gt = ">" if r.lower_bound else " "
            dev = r.error_deviation
            dev_s = "-" if math.isinf(dev) else f"{100 * dev:+.0f}%"
            lines.append(
                f"  {r.condition:36s} {gt}{r.paper_mean_error_cm:8.1f} "
                f"{_num(r.mean_error_cm, '9.2f')} {dev_s:>7s} {gt}{r.paper_failure_rate_pct:7.0f}"
                f" {r.failure_rate_pct:8.1f} {r.failure_deviation_pts:+8.1f}"
            )
        w = worst_deviation(rows)
        err_s = "none valid" if math.isinf(w.error_rel) else f"{100 * w.error_rel:+.0f}%"
        lines.append(f"  worst mean-error deviation: {err_s} ({w.error_condition})")
        lines.append(
            f"  worst failure-rate deviation: {w.failure_pts:+.1f} points ({w.failure_condition})"
        )
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def format_json(results: Sequence[RowResult]) -> str:
    """``--format json``: a list of row objects."""
    return json.dumps([r.to_json() for r in results], indent=2)


PLOT_LUX = tuple(float(x) for x in range(0, 70_001, 2500))
PLOT_R = (0.1, 0.3, 0.5, 0.7, 0.9)


def write_plots(
    profiles: Sequence[Profile], out_dir: Path, readings: int, seed: int | None
) -> list[Path]:
    """Write Fig. 2 (error vs lux per R) and Fig. 3 (error vs angle per R) for each profile.

    Each point pools the cells of the other factor over ``PAPER_GRID`` (angles for Fig. 2,
    lux levels for Fig. 3), as Table I does; a second panel shows the failure rate.

    Raises:
        ModuleNotFoundError: if matplotlib (the ``plot`` extra) is not installed.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for profile in profiles:
        for fig_no, (xs, xlabel, other) in enumerate(
            (
                (PLOT_LUX, "illumination (lux)", PAPER_GRID.theta_deg),
                (PAPER_GRID.theta_deg, "incidence angle (deg)", PAPER_GRID.lux),
            ),
            start=2,
        ):
            fig, (ax_e, ax_f) = plt.subplots(2, 1, sharex=True, figsize=(7, 7))
            for r_val in PLOT_R:
                if fig_no == 2:
                    grid = SweepGrid(xs, (r_val,), other)
                else:
                    grid = SweepGrid(other, (r_val,), xs)
                lux, r, t = grid.mesh()
                stats = simulate_cells(profile, lux, r, t, readings, np.random.default_rng(seed))
                shape = (len(grid.lux), len(grid.theta_deg))
                err = stats.abs_error_sum_cm.reshape(shape)
                val = stats.valid.reshape(shape)
                axis = 1 if fig_no == 2 else 0
                with np.errstate(invalid="ignore", divide="ignore"):
                    mean = err.sum(axis=axis) / val.sum(axis=axis)
                fail = 100.0 * (1.0 - val.sum(axis=axis) / (val.shape[axis] * readings))
                ax_e.plot(xs, mean, marker=".", label=f"R = {r_val:.1f}")
                ax_f.plot(xs, fail, marker=".", label=f"R = {r_val:.1f}")
            ax_e.set_ylabel("mean absolute error (cm)")
            ax_f.set_ylabel("failure rate (%)")
            ax_f.set_xlabel(xlabel)
            ax_e.set_yscale("log")
            ax_e.legend()
            ax_e.set_title(f"Fig. {fig_no} ({profile.name} profile): error vs {xlabel}")
            path = out_dir / f"fig{fig_no}_{profile.name}.png"
            fig.tight_layout()
            fig.savefig(path, dpi=100)
            plt.close(fig)
            written.append(path)
    return written
