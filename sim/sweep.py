"""The paper's full factorial sweep and Table I side by side.

How this works: ``SweepGrid`` is the factorial grid (lux x R x theta, section III.1).
A profile from ``lunad.sim.paper_model`` turns every cell into N readings (or their
exact expectation); ``table1_results`` pools, for each Table I row, every reading of
every cell inside the row's intervals (``lunad.sim.table1``): the row's mean error is
the mean |error| over its valid readings, its failure rate the share of dropped
readings. Every cell counts once (uniform weighting). The worst deviation is taken
over the 13 two-sided rows: relative for the mean error, in percentage points for the
failure rate; the one-sided worst-case row only counts when it falls short.

``figure_data`` computes what ``lunad sweep --plot`` draws (the model's curves, Table I's
rows pooled both ways, the text's trends from ``lunad.sim.table1``) with numpy alone;
``build_figure`` draws it with matplotlib, the ``plot`` extra, imported only there.
"""

from __future__ import annotations

import itertools
import json
import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lunad.sim.paper_model import (
    D_TRUE_M,
    READINGS_PER_SCENARIO,
    CellStats,
    FloatArray,
    Profile,
    expected_cells,
    simulate_cells,
)
from lunad.sim.table1 import TABLE1_ROWS, TEXT_TRENDS, Table1Row, TextTrend

if TYPE_CHECKING:  # the plot extra: imported only by build_figure
    from matplotlib.figure import Figure

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
"""Fig. 2's x levels, lux: a 2.5-klux grid, finer than PAPER_GRID above 20 klux."""
PLOT_R = (0.1, 0.3, 0.5, 0.7, 0.9)
"""The reflectivities drawn as curves: those of Table I's R rows."""
PLOT_INSTALL = "pip install 'lunad[plot]' (in a checkout: .venv/bin/pip install matplotlib)"
"""How to get the ``plot`` extra, for the one-line error of ``--plot`` without it."""


@dataclass(frozen=True, slots=True)
class Curve:
    """One model curve of a figure: pooled values at each level of the x axis.

    Attributes:
        label: legend text.
        x: the x levels (lux, degrees or R).
        error_cm: mean absolute error of the valid readings pooled at each x, cm (NaN: none valid).
        failure_pct: share of dropped readings pooled at each x, percent.
        reflectivity: the curve's R, or None when it pools every R of the grid.
    """

    label: str
    x: tuple[float, ...]
    error_cm: FloatArray
    failure_pct: FloatArray
    reflectivity: float | None


@dataclass(frozen=True, slots=True)
class RowMark:
    """A Table I row placed on a figure's x axis, with the model pooled as the row is.

    Attributes:
        x_lo: start of the row's interval on the x axis (lux, degrees or R).
        x_hi: its end (equal to ``x_lo`` for an R row).
        result: the paper's and the model's values (``RowResult``).
    """

    x_lo: float
    x_hi: float
    result: RowResult

    @property
    def x_mid(self) -> float:
        """Where the marker goes: the middle of the interval."""
        return 0.5 * (self.x_lo + self.x_hi)


@dataclass(frozen=True, slots=True)
class FigureData:
    """Everything one plot shows, computed without matplotlib (so tests need none).

    Attributes:
        stem: file name without ``.png``.
        title: the figure's title.
        xlabel: the x axis label, with its unit.
        x_is_lux: the x axis is illuminance (ticks written as 10k, 20k, ...).
        curves: the model's curves.
        rows: Table I's rows on this x axis.
        trends: the paper text's bounds for this figure.
        caption: what every point pools, printed under the figure.
    """

    stem: str
    title: str
    xlabel: str
    x_is_lux: bool
    curves: tuple[Curve, ...]
    rows: tuple[RowMark, ...]
    trends: tuple[TextTrend, ...]
    caption: str


def _pooled(
    stats: CellStats, shape: tuple[int, int, int], axes: tuple[int, ...]
) -> tuple[FloatArray, FloatArray]:
    """(mean error cm, failure %) of the cells pooled over ``axes`` of a (lux, R, theta) grid."""
    err = stats.abs_error_sum_cm.reshape(shape).sum(axis=axes)
    valid = stats.valid.reshape(shape).sum(axis=axes)
    total = math.prod(shape[a] for a in axes) * stats.readings
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(valid > 0, err / valid, np.nan)
    return mean, 100.0 * (1.0 - valid / total)


def _shape(grid: SweepGrid) -> tuple[int, int, int]:
    return len(grid.lux), len(grid.reflectivity), len(grid.theta_deg)


def _curves(
    stats: CellStats, grid: SweepGrid, x: tuple[float, ...], x_axis: int
) -> tuple[Curve, ...]:
    """One curve per R of ``PLOT_R`` and one over every R, pooling the third factor."""
    shape = _shape(grid)
    other = 2 if x_axis == 0 else 0
    out = []
    for r_val in PLOT_R:
        j = grid.reflectivity.index(r_val)
        sub = CellStats(
            stats.abs_error_sum_cm.reshape(shape)[:, j : j + 1, :],
            stats.valid.reshape(shape)[:, j : j + 1, :],
            stats.readings,
        )
        err, fail = _pooled(sub, (shape[0], 1, shape[2]), (1, other))
        out.append(Curve(f"model, R {r_val:.1f}", x, err, fail, r_val))
    err, fail = _pooled(stats, shape, (1, other))
    out.append(Curve("model, all R", x, err, fail, None))
    return tuple(out)


def _k(lux: float) -> str:
    """Illuminance as a tick label: 0, 500, 1k, 2.5k, 70k."""
    return f"{lux / 1000:g}k" if lux >= 1000 else f"{lux:g}"


def _levels(values: Sequence[float], unit: str, short: bool = False) -> str:
    """A grid's levels in words, e.g. ``18 levels, 0-85 deg in steps of 5``."""
    fmt = _k if short else (lambda v: f"{v:g}")
    unit_s = f" {unit}" if unit else ""
    steps = {round(b - a, 9) for a, b in itertools.pairwise(values)}
    if len(steps) == 1:
        return (
            f"{len(values)} levels, {fmt(values[0])}-{fmt(values[-1])}{unit_s}"
            f" in steps of {fmt(steps.pop())}"
        )
    return f"{len(values)} levels: {', '.join(fmt(v) for v in values)}{unit_s}"


def _log_subs(lo: float, hi: float) -> tuple[float, ...]:
    """Mantissas of the labelled ticks on a log axis from ``lo`` to ``hi``.

    1-2-5 over two decades or more; denser over less, so that a narrow range (say
    100-150 cm) still gets three or more plain-number labels instead of 1.4x10^2.
    """
    decades = math.log10(hi / lo) if lo > 0 and hi > lo else 0.0
    if decades >= 2.0:
        return (1.0, 2.0, 5.0)
    if decades >= 1.0:
        return (1.0, 2.0, 3.0, 5.0)
    return (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0)


def figure_data(
    profile: Profile, readings: int, seed: int | None, grid: SweepGrid = PAPER_GRID
) -> list[FigureData]:
    """The three plots of ``--plot`` for one profile: Fig. 2, Fig. 3 and Table I's R rows.

    The sweep grid is drawn with the same seed as ``run_sweep``, so the model's Table I
    markers are the numbers ``lunad sweep`` prints. Fig. 2's curves come from a second
    draw on ``PLOT_LUX`` (finer in lux), pooled over the grid's angles and reflectivities.
    """
    lux, r, t = grid.mesh()
    stats = simulate_cells(profile, lux, r, t, readings, np.random.default_rng(seed))
    results = table1_results(profile.name, stats, grid)
    marks = list(zip(TABLE1_ROWS, results, strict=True))
    g2 = SweepGrid(PLOT_LUX, grid.reflectivity, grid.theta_deg)
    lux2, r2, t2 = g2.mesh()
    stats2 = simulate_cells(profile, lux2, r2, t2, readings, np.random.default_rng(seed))

    seed_s = "a fresh seed" if seed is None else f"seed {seed}"
    model = (
        f"Model ({profile.name} profile): D = {D_TRUE_M:g} m, {readings} readings a cell, {seed_s}."
    )
    angles = _levels(grid.theta_deg, "deg")
    refl = _levels(grid.reflectivity, "")
    grid_lux = _levels(grid.lux, "lux", short=True)
    table = (
        f"Squares: Table I (filled: the paper; hollow: the model pooled the same way on the"
        f" sweep grid of {grid.cells} cells, lux {grid_lux}, R {refl}, angle {angles})."
    )
    bar = "The bar is the row's interval as sim/table1.py reads it."
    text = "Gray dashes: bounds the paper's text gives for its figure (triangle: above / below)."
    fig2 = FigureData(
        stem=f"fig2_{profile.name}",
        title=f"Fig. 2 equivalent: error and failure vs illumination ({profile.name} profile)",
        xlabel="illumination (lux)",
        x_is_lux=True,
        curves=_curves(stats2, g2, PLOT_LUX, 0),
        rows=tuple(
            RowMark(row.lux.lo, row.lux.hi, res)
            for row, res in marks
            if row.group == "illumination"
        ),
        trends=tuple(tr for tr in TEXT_TRENDS if tr.figure == 2),
        caption=(
            f"{model} Lines: each point pools, at one lux level ({_levels(PLOT_LUX, 'lux', True)}),"
            f" the angles ({angles}) for one R; 'all R' also pools R ({refl})."
            f" {table} {bar} Table I's lux rows pool every R and angle. {text}"
        ),
    )
    fig3 = FigureData(
        stem=f"fig3_{profile.name}",
        title=f"Fig. 3 equivalent: error and failure vs incidence angle ({profile.name} profile)",
        xlabel="incidence angle (deg)",
        x_is_lux=False,
        curves=_curves(stats, grid, grid.theta_deg, 2),
        rows=tuple(
            RowMark(row.theta_deg.lo, row.theta_deg.hi, res)
            for row, res in marks
            if row.group in ("angle", "combined")
        ),
        trends=tuple(tr for tr in TEXT_TRENDS if tr.figure == 3),
        caption=(
            f"{model} Lines: each point pools, at one angle, the sweep grid's lux levels"
            f" ({grid_lux}) for one R; 'all R' also pools R ({refl})."
            f" {table} {bar} Table I's angle rows pool every lux level and R; the triangle is its"
            f" worst-case row (L > 50 klux, R 0.1, angle > 75 deg), a lower bound. {text}"
        ),
    )
    err_r, fail_r = _pooled(stats, _shape(grid), (0, 2))
    fig_r = FigureData(
        stem=f"table1_r_{profile.name}",
        title=f"Table I reflectivity rows: error and failure vs R ({profile.name} profile)",
        xlabel="reflectivity R",
        x_is_lux=False,
        curves=(Curve("model, all lux and angles", grid.reflectivity, err_r, fail_r, None),),
        rows=tuple(
            RowMark(row.reflectivity.lo, row.reflectivity.hi, res)
            for row, res in marks
            if row.group == "reflectivity"
        ),
        trends=(),
        caption=(
            f"{model} Line: each point pools, at one R, the sweep grid's lux levels ({grid_lux})"
            f" and angles ({angles}), as Table I's R rows do. {table} The paper has no figure"
            " for R; its R rows are drawn here."
        ),
    )
    return [fig2, fig3, fig_r]


def require_matplotlib() -> None:
    """Import matplotlib, so that ``--plot`` can fail before the sweep runs.

    Raises:
        ImportError: if matplotlib (the ``plot`` extra) is missing or cannot be imported.
    """
    import matplotlib  # first: "No module named 'matplotlib'" when it is absent
    import matplotlib.figure
    import matplotlib.ticker  # noqa: F401


_PAPER = {"color": "black", "marker": "s", "markersize": 7, "linestyle": "none"}
_TREND = "0.45"  # gray of the text's bounds


def build_figure(data: FigureData) -> Figure:
    """Draw one ``FigureData``: mean error (log scale) above, failure rate below.

    A ``matplotlib.figure.Figure`` without pyplot: no global state, no display needed.
    """
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    fig = Figure(figsize=(11, 8.5), layout="constrained")
    ax_e, ax_f = fig.subplots(2, 1, sharex=True)
    for ax, attr, unit in ((ax_e, "error_cm", "cm"), (ax_f, "failure_pct", "%")):
        for i, c in enumerate(data.curves):
            style = (
                {"color": "black", "linewidth": 2.0}
                if c.reflectivity is None
                else {"color": f"C{i}", "linewidth": 1.4}
            )
            ax.plot(c.x, getattr(c, attr), label=c.label, **style)
        paper_attr = "paper_mean_error_cm" if attr == "error_cm" else "paper_failure_rate_pct"
        model_attr = "mean_error_cm" if attr == "error_cm" else "failure_rate_pct"
        for bound, label, marker in ((False, "paper Table I", "s"), (True, None, "^")):
            marks = [m for m in data.rows if m.result.lower_bound == bound]
            if not marks:
                continue
            paper = [getattr(m.result, paper_attr) for m in marks]
            model = [getattr(m.result, model_attr) for m in marks]
            xs = [m.x_mid for m in marks]
            ax.hlines(paper, [m.x_lo for m in marks], [m.x_hi for m in marks], color="black")
            ax.plot(
                xs,
                paper,
                **{**_PAPER, "marker": marker},
                label=label or "paper Table I worst case (lower bound)",
            )
            ax.plot(
                xs,
                model,
                **{**_PAPER, "marker": marker, "markerfacecolor": "none"},
                label="model, pooled as Table I" if not bound else "model, worst-case row",
            )
        labelled = False
        for tr in data.trends:
            if (tr.quantity == "error") != (attr == "error_cm"):
                continue
            ax.plot(
                [tr.x_lo, tr.x_hi],
                [tr.bound, tr.bound],
                color=_TREND,
                linestyle="--",
                marker="^" if tr.above else "v",
                label=None if labelled else "paper text (bound)",
            )
            labelled = True
            point = tr.x_lo == tr.x_hi  # a point: its label under it, clear of the segments
            ax.annotate(
                tr.label(),
                (tr.x_lo, tr.bound),
                textcoords="offset points",
                xytext=(0, -14) if point else (2, 4 if tr.above else -10),
                ha="center" if point else "left",
                fontsize=7,
                color=_TREND,
            )
        ax.set_ylabel(
            "mean absolute error (cm)" if attr == "error_cm" else f"failure rate ({unit})"
        )
        ax.grid(True, which="major", alpha=0.3)
    ax_e.set_yscale("log")
    ax_e.yaxis.set_major_locator(LogLocator(base=10, subs=_log_subs(*ax_e.get_ylim())))
    ax_e.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax_e.yaxis.set_minor_formatter(NullFormatter())
    ax_f.set_ylim(bottom=0.0)
    if data.x_is_lux:
        ax_f.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: _k(v)))
    ax_f.set_xlabel(data.xlabel)
    fig.suptitle(data.title)
    fig.supxlabel(textwrap.fill(data.caption, 150), x=0.01, ha="left", fontsize=8)
    fig.legend(*ax_e.get_legend_handles_labels(), loc="outside right center", fontsize=8)
    return fig


def write_plots(
    profiles: Sequence[Profile], out_dir: Path, readings: int, seed: int | None
) -> list[Path]:
    """Write each profile's ``figure_data`` as PNGs into ``out_dir``; returns their paths.

    Raises:
        ImportError: if matplotlib (the ``plot`` extra) is not installed.
        OSError: if ``out_dir`` cannot be created or a file cannot be written.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for profile in profiles:
        for data in figure_data(profile, readings, seed):
            fig = build_figure(data)
            path = out_dir / f"{data.stem}.png"
            fig.savefig(path, dpi=100)
            written.append(path)
    return written
