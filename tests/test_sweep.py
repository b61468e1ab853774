"""Issue 3 parts 1-2: paper and calibrated profiles, Table I side by side, lunad sweep."""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from lunad.daemon import cmd_sweep
from lunad.sim.fit import check_claims, nelder_mead
from lunad.sim.paper_model import (
    CALIBRATED_DEFAULT,
    PAPER_CENTIMETRES,
    PAPER_METRES,
    expected_cells,
    norm_cdf,
    simulate_cells,
)
from lunad.sim.sweep import PAPER_GRID, expected_sweep, run_sweep, worst_deviation
from lunad.sim.table1 import FIT_ROWS, TABLE1_ROWS

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


def test_plot_without_matplotlib_is_one_clear_line(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    rc = cmd_sweep.run(_parse(["--profile", "paper", "--readings", "5", "--plot", str(tmp_path)]))
    err = capsys.readouterr().err
    assert rc == 1 and "matplotlib" in err and len(err.strip().splitlines()) == 1


def test_help_runs_in_a_subprocess() -> None:
    code = (
        "import argparse,sys; from lunad.daemon import cmd_sweep;"
        "p=argparse.ArgumentParser(prog='lunad'); cmd_sweep.add_parser(p.add_subparsers());"
        "p.parse_args(['sweep','--help'])"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0
    assert "examples:" in proc.stdout and "--fit" in proc.stdout
