"""Constant-velocity Kalman filter, innovation gate and step confirmation (filters/kalman.py)."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from lunad.filters import ACCEPTED, OUTLIER, RESTARTED, Tracker

DT = 0.004  # 250 Hz


def tracker(confirm: int = 2) -> Tracker:
    return Tracker(accel_psd=0.5, gate_sigmas=4.0, step_confirm=confirm, init_speed_sigma_m_s=1.0)


def test_predict_moves_state_and_grows_covariance() -> None:
    t = tracker()
    t.start(2.0, 1e-4)
    t.v = 1.0
    p0 = t.p00
    t.predict(0.1)
    assert abs(t.x - 2.1) < 1e-12
    assert t.p00 > p0 and t.p11 > 1.0


def run_cv(seed: int, speed: float, sigma: float, n: int = 1500) -> float:
    """Mean normalised estimation error squared of the position over the last frames."""
    rng = random.Random(seed)
    t = tracker()
    truth = 3.0
    t.start(truth + rng.gauss(0, sigma), sigma * sigma)
    nees = []
    for k in range(n):
        truth += speed * DT
        t.predict(DT)
        t.update(truth + rng.gauss(0, sigma), sigma * sigma)
        if k > 300:
            nees.append((t.x - truth) ** 2 / t.p00)
    return sum(nees) / len(nees)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    st.integers(min_value=0, max_value=10_000),
    st.floats(min_value=-1.0, max_value=1.0),
    st.floats(min_value=0.003, max_value=0.1),
)
def test_filter_is_consistent_on_constant_velocity(seed: int, speed: float, sigma: float) -> None:
    """Mean NEES near 1. Consecutive NEES values are strongly correlated, so one run has
    few independent samples: average four runs, and derandomize so the band is a fixed,
    reproducible check rather than a search for the one seed in a thousand outside it."""
    nees = sum(run_cv(seed * 4 + i, speed, sigma) for i in range(4)) / 4
    assert 0.5 < nees < 1.6, nees


def test_isolated_spike_is_an_outlier_and_leaves_the_state() -> None:
    t = tracker()
    t.start(2.0, 1e-4)
    for _ in range(50):
        t.predict(DT)
        assert t.update(2.0, 1e-4) == ACCEPTED
    x = t.x
    t.predict(DT)
    assert t.update(3.0, 1e-4) == OUTLIER
    assert t.x == x
    t.predict(DT)
    assert t.update(2.0, 1e-4) == ACCEPTED


def test_step_restarts_after_confirming_outliers() -> None:
    t = tracker(confirm=2)
    t.start(4.0, 1e-4)
    for _ in range(50):
        t.predict(DT)
        t.update(4.0, 1e-4)
    t.predict(DT)
    assert t.update(1.2, 1e-4) == OUTLIER
    t.predict(DT)
    assert t.update(1.21, 1e-4) == RESTARTED
    assert abs(t.x - 1.205) < 1e-9
    assert t.v == 0.0


def test_disagreeing_outliers_do_not_restart() -> None:
    t = tracker(confirm=2)
    t.start(4.0, 1e-4)
    for z in (5.0, 3.0, 5.5, 2.5):
        t.predict(DT)
        assert t.update(z, 1e-4) == OUTLIER
    assert abs(t.x - 4.0) < 1e-6
