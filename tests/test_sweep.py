"""Paper and calibrated profiles, Table I side by side, lunad sweep, its plots and --fit."""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lunad.daemon.cli import sweep as cmd_sweep
from lunad.daemon.errors import EX_CONFIG, EX_UNAVAILABLE
from lunad.sim.fit import BoundCheck, check_claims, format_claims, nelder_mead
from lunad.sim.paper_model import (
    CALIBRATED_DEFAULT,
    PAPER_CENTIMETRES,
    PAPER_METRES,
    expected_cells,
    norm_cdf,
    simulate_cells,
)
from lunad.sim.sweep import (
    PAPER_GRID,
    build_figure,
    expected_sweep,
    figure_data,
    run_sweep,
    worst_deviation,
)
from lunad.sim.table1 import FIT_ROWS, TABLE1_ROWS, TEXT_TRENDS

SEED = 2024
# What the committed fit reaches on the seeded sweep (docs/paper-model.md), plus margin
# for sampling noise: every two-sided row's mean error within 27 %, failure within 10 points.
CAL_ERROR_TOL = 0.27
CAL_FAILURE_TOL_PTS = 10.0


@pytest.fixture(scope="module")
def calibrated_rows():
    return run_sweep(CALIBRATED_DEFAULT, PAPER_GRID, 1000, SEED)


@pytest.fixture(scope="module")
def paper_rows():
    return {r.condition: r for r in run_sweep(PAPER_METRES, PAPER_GRID, 1000, SEED)}


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="lunad")
    cmd_sweep.add_parser(parser.add_subparsers())
    return parser.parse_args(["sweep", *argv])


def test_table1_has_the_papers_fourteen_rows() -> None:
    assert len(TABLE1_ROWS) == 14 and len(FIT_ROWS) == 13
    assert [r.mean_error_cm for r in TABLE1_ROWS[:4]] == [1.5, 3.2, 5.8, 6.9]
    assert TABLE1_ROWS[-1].lower_bound


@pytest.mark.parametrize("row", FIT_ROWS, ids=lambda r: r.condition)
def test_calibrated_row_within_fit_tolerance(calibrated_rows, row) -> None:
    got = next(r for r in calibrated_rows if r.condition == row.condition)
    assert abs(got.error_deviation) <= CAL_ERROR_TOL, got
    assert abs(got.failure_deviation_pts) <= CAL_FAILURE_TOL_PTS, got


def test_calibrated_worst_case_meets_papers_lower_bounds(calibrated_rows) -> None:
    worst = calibrated_rows[-1]
    assert worst.mean_error_cm > 9.0 and 35.0 < worst.failure_rate_pct < 100.0


def test_calibrated_has_no_dropouts_in_the_dark() -> None:
    stats = simulate_cells(
        CALIBRATED_DEFAULT,
        np.zeros(3),
        np.array([0.1, 0.5, 0.9]),
        np.array([85.0, 45.0, 0.0]),
        500,
        np.random.default_rng(1),
    )
    assert np.all(stats.valid == 500)


def test_sampled_sweep_agrees_with_expectation(calibrated_rows) -> None:
    exact = expected_sweep(CALIBRATED_DEFAULT)
    for sampled, e in zip(calibrated_rows, exact, strict=True):
        assert sampled.mean_error_cm == pytest.approx(e.mean_error_cm, rel=0.05)
        # the worst-case row has 4 cells: 2 points is 3 binomial sd
        assert sampled.failure_rate_pct == pytest.approx(e.failure_rate_pct, abs=2.0)


def test_sweep_is_reproducible_with_a_seed() -> None:
    a = run_sweep(CALIBRATED_DEFAULT, PAPER_GRID, 50, 7)
    b = run_sweep(CALIBRATED_DEFAULT, PAPER_GRID, 50, 7)
    c = run_sweep(CALIBRATED_DEFAULT, PAPER_GRID, 50, 8)
    assert a == b and a != c


def test_paper_profile_worst_case_cell_drops_every_reading(paper_rows) -> None:
    worst = paper_rows["L>50000, R=0.1, theta>75 (worst)"]
    assert worst.failure_rate_pct == 100.0 and math.isnan(worst.mean_error_cm)


def test_paper_profile_in_metres_misses_table1_by_orders_of_magnitude(paper_rows) -> None:
    low = paper_rows["0-5000 lux (low)"]
    assert low.mean_error_cm > 10 * low.paper_mean_error_cm
    assert low.failure_rate_pct > 5.0  # Table I: 0 %
    assert all(
        r.mean_error_cm > 5 * r.paper_mean_error_cm
        for r in paper_rows.values()
        if not r.lower_bound
    )


def test_paper_profile_in_centimetres_has_failure_flat_in_lux() -> None:
    rows = expected_sweep(PAPER_CENTIMETRES)
    lux_fail = [r.failure_rate_pct for r in rows if r.group == "illumination"]
    assert max(lux_fail) - min(lux_fail) < 1.0  # Table I: 0 -> 21 %
    assert min(lux_fail) > 5.0  # the S < 0.05 cells drop even in the dark


def test_paper_profile_errors_grow_with_lux_and_fall_with_r(paper_rows) -> None:
    lux = [paper_rows[r.condition].mean_error_cm for r in FIT_ROWS[:4]]
    refl = [paper_rows[r.condition].mean_error_cm for r in FIT_ROWS[4:9]]
    assert lux == sorted(lux) and refl == sorted(refl, reverse=True)


def test_worst_deviation_reports_largest_row(calibrated_rows) -> None:
    w = worst_deviation(calibrated_rows)
    assert abs(w.error_rel) == max(abs(r.error_deviation) for r in calibrated_rows[:-1])


def test_expected_cells_matches_closed_form_gate() -> None:
    # R 1, angle 0, sigma 1 m (metres reading, L = 9900): P(-1.8 <= e <= 6) = Phi(6) - Phi(-1.8)
    stats = expected_cells(PAPER_METRES, np.array([9900.0]), np.array([1.0]), np.array([0.0]))
    assert stats.valid[0] == pytest.approx(float(norm_cdf(6.0) - norm_cdf(-1.8)), abs=1e-6)


def test_norm_cdf_known_values() -> None:
    assert norm_cdf(np.array([0.0, 1.96, -1.96])) == pytest.approx([0.5, 0.975, 0.025], abs=1e-4)


def test_nelder_mead_finds_quadratic_minimum() -> None:
    x, fx = nelder_mead(lambda v: float(np.sum((v - np.array([1.0, -2.0])) ** 2)), np.zeros(2))
    assert x == pytest.approx([1.0, -2.0], abs=1e-3) and fx < 1e-6


def test_claims_hold_for_worst_case_and_white_target_error() -> None:
    claims = {c.name.split(" (")[0]: c for c in check_claims(CALIBRATED_DEFAULT)}
    assert claims["worst case"].holds
    assert claims["R = 0.9 stays accurate up to 70 klux"].mean_error_cm < 2.0


def test_json_schema_single_profile(capsys) -> None:
    assert (
        cmd_sweep.run(_parse(["--profile", "calibrated", "--format", "json", "--readings", "20"]))
        == 0
    )
    objs = json.loads(capsys.readouterr().out)
    assert len(objs) == len(TABLE1_ROWS)
    keys = {
        "condition",
        "mean_error_cm",
        "failure_rate_pct",
        "paper_mean_error_cm",
        "paper_failure_rate_pct",
    }
    assert all(set(o) == keys for o in objs)
    assert all(isinstance(o["failure_rate_pct"], float) for o in objs)


def test_json_schema_both_profiles_has_profile_key(capsys) -> None:
    assert cmd_sweep.run(_parse(["--format", "json", "--readings", "20"])) == 0
    objs = json.loads(capsys.readouterr().out)
    assert {o["profile"] for o in objs} == {"paper", "calibrated"}
    worst = [o for o in objs if o["profile"] == "paper" and "worst" in o["condition"]]
    assert worst[0]["mean_error_cm"] is None  # every reading dropped -> null, not NaN


def test_table_output_names_both_profiles_and_worst(capsys) -> None:
    assert cmd_sweep.run(_parse(["--readings", "20"])) == 0
    out = capsys.readouterr().out
    assert "profile: paper" in out and "profile: calibrated" in out
    assert out.count("worst mean-error deviation") == 2


def test_bad_readings_is_an_argparse_error(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        _parse(["--readings", "0"])
    assert exc.value.code == 2


PLOT_READINGS = 20  # enough for every cell to have readings; the plots' numbers are not tested


def _lunad(argv: list[str], preamble: str = "pass", env_path: Path | None = None):
    """``lunad`` in a fresh interpreter, after ``preamble`` (e.g. one that blocks an import)."""
    code = f"import sys; {preamble}; from lunad.daemon.cli import main; sys.exit(main({argv!r}))"
    env = None
    if env_path is not None:
        import os

        env = {**os.environ, "PYTHONPATH": str(env_path)}
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env=env,
    )


def test_plot_without_matplotlib_fails_before_the_sweep(tmp_path) -> None:
    # sys.modules["matplotlib"] = None makes every import of it fail, as when it is absent.
    # Default readings: had the sweep run, its table would be on stdout (before any plot).
    out_dir = tmp_path / "figs"
    proc = _lunad(["sweep", "--plot", str(out_dir)], "sys.modules['matplotlib'] = None")
    assert proc.returncode == EX_UNAVAILABLE, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "--plot needs matplotlib" in lines[0]
    assert "pip install 'lunad[plot]'" in lines[0]
    assert ".venv/bin/pip install matplotlib" in lines[0]
    assert proc.stdout == ""
    assert not out_dir.exists()


def test_plot_dir_that_cannot_be_made_fails_before_the_sweep(tmp_path) -> None:
    # An empty matplotlib on PYTHONPATH passes the import check without the real one.
    shim = tmp_path / "shim" / "matplotlib"
    shim.mkdir(parents=True)
    for name in ("__init__.py", "figure.py", "ticker.py"):
        (shim / name).write_text("")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    proc = _lunad(["sweep", "--plot", str(blocker / "figs")], env_path=tmp_path / "shim")
    assert proc.returncode == EX_CONFIG, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot create" in lines[0] and str(blocker) in lines[0]
    assert proc.stdout == ""


@pytest.fixture(scope="module")
def calibrated_figures():
    return figure_data(CALIBRATED_DEFAULT, PLOT_READINGS, SEED)


def test_figure_data_carries_table1_next_to_the_model(calibrated_figures) -> None:
    fig2, fig3, fig_r = calibrated_figures
    assert [f.stem for f in calibrated_figures] == [
        "fig2_calibrated",
        "fig3_calibrated",
        "table1_r_calibrated",
    ]
    paper = {r.condition: r for r in TABLE1_ROWS}
    by_group = {
        "illumination": fig2.rows,
        "reflectivity": fig_r.rows,
    }
    for group, marks in by_group.items():
        want = [r.condition for r in TABLE1_ROWS if r.group == group]
        assert [m.result.condition for m in marks] == want
    assert [m.result.condition for m in fig3.rows] == [
        r.condition for r in TABLE1_ROWS if r.group in ("angle", "combined")
    ]
    every = [m for f in calibrated_figures for m in f.rows]
    assert len(every) == len(TABLE1_ROWS)
    for m in every:
        row = paper[m.result.condition]
        assert m.result.paper_mean_error_cm == row.mean_error_cm
        assert m.result.paper_failure_rate_pct == row.failure_rate_pct
    # the model's markers are the numbers `lunad sweep` prints for the same readings and seed
    printed = {
        r.condition: r for r in run_sweep(CALIBRATED_DEFAULT, PAPER_GRID, PLOT_READINGS, SEED)
    }
    assert all(m.result == printed[m.result.condition] for m in every)
    # the lux rows sit across their lux intervals
    assert [(m.x_lo, m.x_hi) for m in fig2.rows] == [
        (0, 5000),
        (5000, 20000),
        (20000, 50000),
        (50000, 70000),
    ]
    assert [len(f.trends) for f in calibrated_figures] == [
        sum(t.figure == 2 for t in TEXT_TRENDS),
        sum(t.figure == 3 for t in TEXT_TRENDS),
        0,
    ]


def test_figure_captions_state_what_is_pooled(calibrated_figures) -> None:
    for f in calibrated_figures:
        assert "D = 2 m" in f.caption
        assert f"{PLOT_READINGS} readings a cell" in f.caption and f"seed {SEED}" in f.caption
        assert f"{PAPER_GRID.cells} cells" in f.caption
        assert "18 levels, 0-85 deg in steps of 5" in f.caption
        assert "12 levels: 0, 1k, 2.5k, 5k" in f.caption
        assert "9 levels, 0.1-0.9 in steps of 0.1" in f.caption
    assert "29 levels, 0-70k lux in steps of 2.5k" in calibrated_figures[0].caption


def _line(ax, label: str):
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert len(found) == 1, [ln.get_label() for ln in ax.get_lines()]
    return found[0]


def test_plot_draws_table1_and_text_bounds_on_the_model_axes(calibrated_figures) -> None:
    pytest.importorskip("matplotlib")
    fig2_data, fig3_data, _ = calibrated_figures
    fig = build_figure(fig2_data)
    ax_e, ax_f = fig.axes
    lux_rows = [r for r in TABLE1_ROWS if r.group == "illumination"]
    for ax, want in (
        (ax_e, [r.mean_error_cm for r in lux_rows]),
        (ax_f, [r.failure_rate_pct for r in lux_rows]),
    ):
        paper = _line(ax, "paper Table I")
        assert list(paper.get_ydata()) == want
        assert list(paper.get_xdata()) == [2500, 12500, 35000, 60000]
        assert paper.get_linestyle() == "None" and paper.get_marker() == "s"
        assert _line(ax, "model, pooled as Table I").get_marker() == "s"
        assert _line(ax, "model, R 0.1").get_marker() == "None"
        _line(ax, "model, all R")
        _line(ax, "paper text (bound)")
    texts = [t.get_text() for t in fig.texts]
    assert any("Fig. 2 equivalent" in t for t in texts)
    assert any(t.replace("\n", " ") == fig2_data.caption for t in texts)
    fig.draw_without_rendering()
    # readable ticks: plain numbers on the log error axis, 10k-style on the lux axis
    y_labels = [t.get_text() for t in ax_e.get_yticklabels() if t.get_text()]
    assert len(y_labels) >= 3 and all(re.fullmatch(r"\d+(\.\d+)?", t) for t in y_labels)
    x_labels = [t.get_text() for t in ax_f.get_xticklabels() if t.get_text()]
    assert "10k" in x_labels and "70k" in x_labels

    fig3 = build_figure(fig3_data)
    worst = _line(fig3.axes[0], "paper Table I worst case (lower bound)")
    assert list(worst.get_ydata()) == [9.0] and worst.get_marker() == "^"
    assert list(_line(fig3.axes[1], "paper Table I").get_ydata()) == [2, 10, 25, 31]


def test_plot_writes_three_pngs_per_profile(tmp_path, capsys) -> None:
    pytest.importorskip("matplotlib")
    out_dir = tmp_path / "figs"
    argv = ["--profile", "calibrated", "--readings", "5", "--plot", str(out_dir)]
    assert cmd_sweep.run(_parse(argv)) == 0
    names = sorted(p.name for p in out_dir.iterdir())
    assert names == ["fig2_calibrated.png", "fig3_calibrated.png", "table1_r_calibrated.png"]
    assert all((out_dir / n).read_bytes()[:4] == b"\x89PNG" for n in names)
    assert capsys.readouterr().err.count("wrote ") == 3


_VERDICT = re.compile(r"^\s*(PASS|FAIL) ")


def test_fit_claim_lines_state_their_criterion() -> None:
    claims = check_claims(CALIBRATED_DEFAULT)
    text = format_claims(claims)
    verdicts = [ln for ln in text.splitlines() if _VERDICT.match(ln)]
    assert len(verdicts) == sum(len(c.bounds) for c in claims) == 2 * len(claims)
    assert "FAIL" in text and "PASS" in text  # the committed profile misses some bounds
    lines = iter(verdicts)
    for c in claims:
        for b in c.bounds:
            line = next(lines)
            assert line.split()[0] == ("PASS" if b.holds else "FAIL")
            assert f"{b.value:.2f} {b.unit}" in line  # the measured value
            assert line.endswith(f"; criterion: {b.criterion()}")  # the bound judged by
            assert [f"{x:g} {b.unit}" in line for x in (b.lo, b.hi) if x is not None] in (
                [True],
                [True, True],
            )
            assert re.search(f"{b.quantity} (<=|>=)|<= {b.quantity}", line), line
    assert "FAIL failure rate 5.15 %; criterion: failure rate <= 2 %" in text


def test_bound_check_without_a_valid_reading_fails_and_says_so() -> None:
    b = BoundCheck("mean error", "cm", math.nan, 9.0, None)
    assert not b.holds
    assert b.line() == "FAIL mean error none valid; criterion: mean error >= 9 cm"
    assert BoundCheck("failure rate", "%", 40.0, 35.0, 95.0).line() == (
        "PASS failure rate 40.00 %; criterion: 35 % <= failure rate <= 95 %"
    )


@pytest.mark.slow
def test_fit_prints_every_claim_with_its_criterion(capsys) -> None:
    assert cmd_sweep.run(_parse(["--fit"])) == 0
    out = capsys.readouterr().out
    verdicts = [ln for ln in out.splitlines() if _VERDICT.match(ln)]
    assert verdicts and all("criterion: " in ln for ln in verdicts)


def test_help_runs_in_a_subprocess() -> None:
    code = (
        "import argparse,sys; from lunad.daemon.cli import sweep as cmd_sweep;"
        "p=argparse.ArgumentParser(prog='lunad'); cmd_sweep.add_parser(p.add_subparsers());"
        "p.parse_args(['sweep','--help'])"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0
    assert "examples:" in proc.stdout and "--fit" in proc.stdout
    assert "lunad sweep --plot figs/" in proc.stdout
    assert "pip install 'lunad[plot]'" in proc.stdout
    assert "exit status:" in proc.stdout and "69 --plot without matplotlib" in proc.stdout
