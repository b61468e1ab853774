"""The independent oracle filter (sim/oracle.py) on streams whose truth and sigma we know."""

from __future__ import annotations

import ast
import inspect
import itertools
import math
import random
from collections.abc import Callable, Sequence

import pytest

from lunad.sim import oracle
from lunad.sim.oracle import Q_GRID_M2_S3, OracleKalman, run_oracle, tuned_oracle

RATE_HZ = 250.0
AMP_OK = 1000


def frame_ns(i: int) -> int:
    return round(i * 1e9 / RATE_HZ)


def stream(
    truth: Sequence[float], sigma_m: float, seed: int
) -> tuple[list[float | None], list[int], list[int], list[float | None]]:
    """Readings of ``truth`` with Gaussian noise ``sigma_m``, rounded to whole cm."""
    rng = random.Random(seed)
    raw: list[float | None] = [round((d + rng.gauss(0.0, sigma_m)) * 100.0) / 100.0 for d in truth]
    n = len(truth)
    return raw, [AMP_OK] * n, [frame_ns(i) for i in range(n)], [sigma_m] * n


def rmse_against(
    truth: Sequence[float], skip: int
) -> Callable[[list[float | None], list[float | None]], float]:
    def score(est: list[float | None], sig: list[float | None]) -> float:
        sq = [(e - t) ** 2 for e, t in zip(est[skip:], truth[skip:], strict=True) if e is not None]
        return math.sqrt(sum(sq) / len(sq)) if sq else math.inf

    return score


def test_grid_is_twelve_log_spaced_values_from_1e_4_to_1e3() -> None:
    assert len(Q_GRID_M2_S3) == 12
    assert Q_GRID_M2_S3[0] == pytest.approx(1e-4) and Q_GRID_M2_S3[-1] == pytest.approx(1e3)
    ratios = {round(b / a, 9) for a, b in itertools.pairwise(Q_GRID_M2_S3)}
    assert len(ratios) == 1


def test_static_target_sigma_settles_rmse_beats_raw_and_coverage_is_honest() -> None:
    sigma = 0.02
    d = 2.0037
    settle = 1000
    inside = judged = 0
    for seed in range(4):
        truth = [d] * 6000
        raw, amp, t, sig = stream(truth, sigma, seed)
        est, out_sig = run_oracle(raw, amp, t, sig, 1e-2)
        tail = [s for s in out_sig[settle:] if s is not None]
        assert len(tail) == len(truth) - settle
        assert max(tail) - min(tail) < 0.01 * tail[-1], "sigma converged"
        assert tail[-1] < 0.3 * sigma
        errs = [e - d for e in est[settle:] if e is not None]
        rmse = math.sqrt(sum(e * e for e in errs) / len(errs))
        assert rmse < 0.3 * sigma
        raw_err = [r - d for r in raw[settle:] if r is not None]
        assert rmse < 0.3 * math.sqrt(sum(e * e for e in raw_err) / len(raw_err))
        judged += len(errs)
        inside += sum(abs(e) <= 2.0 * s for e, s in zip(errs, tail, strict=True))
    assert 0.90 <= inside / judged <= 0.99


def test_a_one_metre_step_is_followed_within_reset_after_plus_one_frames() -> None:
    reset_after = 2
    for seed in range(5):
        truth = [2.0] * 1000 + [3.0] * 20
        raw, amp, t, sig = stream(truth, 0.01, seed)
        flt = OracleKalman(1.0, reset_after=reset_after)
        est = [flt.step(z, a, tt, s)[0] for z, a, tt, s in zip(raw, amp, t, sig, strict=True)]
        after = est[1000 : 1000 + reset_after + 1]
        assert any(e is not None and abs(e - 3.0) <= 0.15 for e in after), after
        assert all(e is not None and abs(e - 3.0) <= 0.15 for e in est[1000 + reset_after :])


def test_one_spike_is_rejected_and_the_track_holds() -> None:
    truth = [2.0] * 500
    raw, amp, t, sig = stream(truth, 0.01, 7)
    raw[400] = 3.2
    est, _ = run_oracle(raw, amp, t, sig, 1.0)
    assert est[400] is not None and abs(est[400] - 2.0) < 0.02


def test_tuned_oracle_picks_a_larger_q_for_a_fast_reversing_target() -> None:
    n = 5000
    static = [2.5] * n
    # 3 m/s at the centre, reversing smoothly at 1 and 4 m (peak acceleration 6 m/s^2).
    moving = [2.5 + 1.5 * math.sin(2.0 * i / RATE_HZ) for i in range(n)]
    q_static, est_s, sig_s = tuned_oracle(*stream(static, 0.01, 1), rmse_against(static, 250))
    q_moving, est_m, _ = tuned_oracle(*stream(moving, 0.01, 1), rmse_against(moving, 250))
    assert q_static in Q_GRID_M2_S3 and q_moving in Q_GRID_M2_S3
    assert q_moving > q_static
    assert q_static <= 1e-2
    assert len(est_s) == len(sig_s) == n and len(est_m) == n
    # What it returns is the run of the q it names.
    again, _ = run_oracle(*stream(moving, 0.01, 1), q_moving)
    assert again == est_m


def test_tuned_oracle_keeps_the_first_of_equal_scores_and_survives_nan() -> None:
    raw, amp, t, sig = stream([2.0] * 50, 0.01, 0)
    q, _, _ = tuned_oracle(raw, amp, t, sig, lambda e, s: 1.0)
    assert q == Q_GRID_M2_S3[0]
    q, _, _ = tuned_oracle(raw, amp, t, sig, lambda e, s: math.nan)
    assert q == Q_GRID_M2_S3[0]
    with pytest.raises(ValueError):
        tuned_oracle(raw, amp, t, sig, lambda e, s: 1.0, grid=())


def test_a_missing_reading_predicts_with_the_velocity() -> None:
    flt = OracleKalman(1.0)
    speed = 1.0
    for i in range(500):
        flt.step(1.0 + speed * i / RATE_HZ, AMP_OK, frame_ns(i), 0.002)
    v = flt.velocity_m_s
    assert v is not None and v == pytest.approx(speed, abs=0.05)
    last, last_sig = flt.step(1.0 + speed * 499 / RATE_HZ, AMP_OK, frame_ns(499), 0.002)
    assert last is not None and last_sig is not None
    for k in range(1, 4):
        e, s = flt.step(None, AMP_OK, frame_ns(499 + k), None)
        assert e is not None and s is not None
        assert e == pytest.approx(last + v * k / RATE_HZ, abs=1e-9)
        assert s > last_sig


@pytest.mark.parametrize(
    ("raw_m", "amp", "sigma_m"),
    [
        (3.0, 99, 0.01),  # weak: below the amp threshold
        (3.0, 32769, 0.01),  # ambient overexposure
        (3.0, 0xFFFF, 0.01),  # saturated
        (0.19, AMP_OK, 0.01),  # blind zone
        (9.01, AMP_OK, 0.01),  # beyond Dist_max
        (None, AMP_OK, 0.01),  # no distance
        (3.0, AMP_OK, None),  # sigma unknown
        (3.0, AMP_OK, math.nan),
    ],
)
def test_invalid_readings_are_predicted_over(
    raw_m: float | None, amp: int, sigma_m: float | None
) -> None:
    fresh = OracleKalman(1.0)
    assert fresh.step(raw_m, amp, 0, sigma_m) == (None, None), "no track from a bad reading"
    flt = OracleKalman(1.0)
    e0, _ = flt.step(2.0, AMP_OK, 0, 0.01)
    e1, _ = flt.step(raw_m, amp, frame_ns(1), sigma_m)
    e2, _ = flt.step(raw_m, amp, frame_ns(2), sigma_m)
    e3, _ = flt.step(raw_m, amp, frame_ns(3), sigma_m)
    assert e0 == e1 == e2 == e3 == 2.0, "v = 0 at the start: the prediction stays put"


def test_amp_limits_themselves_are_valid() -> None:
    for amp in (100, 32768):
        flt = OracleKalman(1.0)
        e, s = flt.step(2.0, amp, 0, 0.01)
        assert e == 2.0
        assert s == pytest.approx(math.sqrt(0.01**2 + 0.01**2 / 12)), "sigma^2 + 1 cm^2 / 12"


def test_no_time_passing_means_no_prediction() -> None:
    flt = OracleKalman(1.0)
    flt.step(2.0, AMP_OK, frame_ns(10), 0.01)
    _, s0 = flt.step(None, AMP_OK, frame_ns(10), None)
    _, s1 = flt.step(None, AMP_OK, frame_ns(9), None)
    _, s2 = flt.step(None, AMP_OK, frame_ns(11), None)
    assert s0 is not None and s1 is not None and s2 is not None
    assert s0 == s1 < s2


def test_bad_arguments_raise() -> None:
    with pytest.raises(ValueError):
        OracleKalman(-1.0)
    with pytest.raises(ValueError):
        OracleKalman(math.inf)
    with pytest.raises(ValueError):
        OracleKalman(1.0, gate_sigmas=0.0)
    with pytest.raises(ValueError):
        OracleKalman(1.0, reset_after=0)
    with pytest.raises(ValueError):
        run_oracle([2.0], [AMP_OK, AMP_OK], [0], [0.01], 1.0)


def test_oracle_never_imports_the_filters() -> None:
    tree = ast.parse(inspect.getsource(oracle))
    names = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)] + [
        a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names
    ]
    assert not [n for n in names if "filters" in n]
    assert not [n for n in names if n.startswith("numpy")], "plain floats per step"


def test_without_a_coast_limit_the_prediction_runs_on_and_with_one_it_stops() -> None:
    readings = [(2.0 + 0.004 * i, AMP_OK, frame_ns(i), 0.002) for i in range(250)]
    gap = [(None, AMP_OK, frame_ns(250 + i), None) for i in range(100)]
    back = (3.5, AMP_OK, frame_ns(350), 0.002)
    forever = OracleKalman(1.0)
    limited = OracleKalman(1.0, max_coast_s=0.2)
    for flt in (forever, limited):
        for z, a, t, s in readings:
            flt.step(z, a, t, s)
    coasting = [forever.step(*g) for g in gap]
    stopped = [limited.step(*g) for g in gap]
    assert all(e is not None for e, _ in coasting)
    assert all(e is not None for e, _ in stopped[:50]), "0.2 s at 250 Hz"
    assert all(r == (None, None) for r in stopped[51:])
    e, sig = limited.step(*back)
    assert e == 3.5 and sig is not None, "a fresh track at the first usable reading"
    with pytest.raises(ValueError):
        OracleKalman(1.0, max_coast_s=0.0)
