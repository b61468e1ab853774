"""Online lux estimator (filters/lux.py)."""

from __future__ import annotations

import math
import random

import pytest

from lunad.filters import FilterConfig, LuxEstimator
from lunad.filters.lux import clipped_square_mean

CFG = FilterConfig()
DT = 0.004  # 250 Hz
Q = CFG.resolution_m**2 / 12


def feed(
    est: LuxEstimator,
    c_true: float,
    n: int,
    rng: random.Random,
    s: float = 0.3,
    spike_p: float = 0.0,
) -> None:
    sd = math.sqrt((c_true / s) ** 2 + Q)
    for _ in range(n):
        e = rng.gauss(0.0, sd)
        if rng.random() < spike_p:
            e += rng.uniform(0.3, 2.0)
        est.update(e, 0.0, s, Q, DT)


def c_of(lux: float, scale: float = 1.0) -> float:
    return scale * (CFG.sigma0_m + CFG.k_m_per_lux * lux)


def test_clipping_bias_constant() -> None:
    assert clipped_square_mean(2.5) == pytest.approx(0.9776, abs=1e-3)
    assert clipped_square_mean(40.0) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize(("start", "target"), [(0.0, 30_000.0), (60_000.0, 2_000.0)])
def test_converges_within_half_a_second(start: float, target: float) -> None:
    est = LuxEstimator(FilterConfig(lux_init=start))
    errors = []
    for seed in range(8):
        est.reset()
        feed(est, c_of(target), 125, random.Random(seed))
        errors.append(abs(est.c_m / c_of(target) - 1.0))
    assert sum(errors) / len(errors) < 0.12, errors


def test_lux_estimate_is_right_on_average() -> None:
    est = LuxEstimator(CFG)
    rng = random.Random(1)
    feed(est, c_of(40_000.0), 200, rng)
    vals = []
    for _ in range(400):
        feed(est, c_of(40_000.0), 5, rng)
        vals.append(est.lux)
    assert sum(vals) / len(vals) == pytest.approx(40_000.0, rel=0.1)


def test_robust_to_spikes() -> None:
    est = LuxEstimator(CFG)
    rng = random.Random(2)
    feed(est, c_of(5_000.0), 2_000, rng, spike_p=0.01)
    assert est.c_m == pytest.approx(c_of(5_000.0), rel=0.25)


def test_wrong_noise_scale_is_absorbed_and_lux_is_biased_as_documented() -> None:
    est = LuxEstimator(CFG)
    rng = random.Random(3)
    feed(est, c_of(0.0, scale=2.0), 2_000, rng)
    assert est.c_m == pytest.approx(2 * CFG.sigma0_m, rel=0.15)
    assert est.lux == pytest.approx(CFG.sigma0_m / CFG.k_m_per_lux, rel=0.4)


def test_quieter_sensor_goes_below_sigma0_and_lux_clips_at_zero() -> None:
    est = LuxEstimator(CFG)
    feed(est, c_of(0.0, scale=0.5), 2_000, random.Random(4))
    assert est.c_m == pytest.approx(0.5 * CFG.sigma0_m, rel=0.2)
    assert est.lux == 0.0
