"""The calibration maths (lunad.filters.calibration) on drawn readings with a known noise."""

from __future__ import annotations

import random
import statistics

import pytest

from lunad.filters.calibration import (
    MIN_DIFFERENCES,
    SPREAD_MIN_STEPS,
    Figure,
    amp_ref_of,
    k_of,
    noise_at_unit_strength,
    reading_spread,
    sigma0_of,
    target_strength,
)

STEP_M = 0.01  # the TF-Luna's output step, DS p.2


def readings(
    sigma_m: float,
    n: int,
    rng: random.Random,
    at_m: float = 3.0,
    drift_m: float = 0.0,
    spike_rate: float = 0.0,
) -> list[float | None]:
    """``n`` readings of a target at ``at_m`` with normal noise, rounded to the 1 cm step;
    ``drift_m`` moves the target linearly over the run, ``spike_rate`` adds 0.3-2 m."""
    out: list[float | None] = []
    for i in range(n):
        z = at_m + drift_m * i / n + rng.gauss(0.0, sigma_m)
        if rng.random() < spike_rate:
            z += rng.uniform(0.3, 2.0)
        out.append(round(z / STEP_M) * STEP_M)
    return out


@pytest.mark.parametrize("sigma_steps", [0.55, 0.8, 1.0, 3.0, 8.0])
def test_the_spread_is_right_wherever_the_target_sits(sigma_steps: float) -> None:
    """From half a step up, the step correction holds between any two centimetres."""
    rng = random.Random(1)
    for offset in (0.0, 0.25, 0.5):  # where the target sits between two centimetres
        sp = reading_spread(
            readings(sigma_steps * STEP_M, 20_000, rng, at_m=3.0 + offset * STEP_M), STEP_M
        )
        assert sp.sd_m is not None and not sp.below_step
        assert sp.sd_m.value == pytest.approx(sigma_steps * STEP_M, rel=0.03)


@pytest.mark.parametrize("sigma_steps", [0.0, 0.1, 0.3, 0.45])
def test_below_half_a_step_no_spread_is_given(sigma_steps: float) -> None:
    """A target between two centimetres with almost no noise splits its readings
    between them, which would read as 0.41 step: the steps hide the noise, so no
    figure at all."""
    rng = random.Random(2)
    for offset in (0.0, 0.25, 0.5):
        z = readings(sigma_steps * STEP_M, 5000, rng, at_m=3.0 + offset * STEP_M)
        if sigma_steps == 0.0 and offset == 0.5:  # a tiny noise flips every reading
            z = [3.0 + STEP_M * rng.randrange(2) for _ in range(5000)]
        sp = reading_spread(z, STEP_M)
        assert sp.sd_m is None and sp.below_step, (sigma_steps, offset)
    assert SPREAD_MIN_STEPS == 0.5


def test_a_drifting_target_and_multipath_spikes_do_not_move_it() -> None:
    """10 cm of drift in 2000 readings (a hand-held card) and 1 % of spikes of 0.3-2 m."""
    rng = random.Random(3)
    sp = reading_spread(readings(0.02, 2000, rng, drift_m=0.1, spike_rate=0.01), STEP_M)
    assert sp.sd_m is not None and sp.sd_m.value == pytest.approx(0.02, rel=0.06)
    assert 40 <= sp.dropped <= 70  # three second differences per spike
    plain = statistics.stdev(z for z in readings(0.02, 2000, rng, drift_m=0.1) if z is not None)
    assert plain > 0.035  # what the readings' own standard deviation would say


def test_the_uncertainty_matches_the_scatter_of_repeated_runs() -> None:
    rng = random.Random(4)
    for sigma_m, n in ((0.008, 300), (0.03, 300), (0.03, 60)):
        runs = [reading_spread(readings(sigma_m, n, rng), STEP_M).sd_m for _ in range(300)]
        values = [r.value for r in runs if r is not None]
        errs = [r.err for r in runs if r is not None]
        assert len(values) == 300
        assert statistics.stdev(values) == pytest.approx(statistics.mean(errs), rel=0.2)


def test_unusable_readings_break_the_chain() -> None:
    rng = random.Random(5)
    z = readings(0.02, 100, rng)
    z[10] = z[50] = None
    sp = reading_spread(z, STEP_M)
    assert sp.differences == 98 - 6  # each gap costs the three differences through it
    few = reading_spread([z[0], None] * 40, STEP_M)
    assert few.sd_m is None and not few.below_step and few.differences == 0
    z = readings(0.02, MIN_DIFFERENCES + 2, rng)
    assert reading_spread(z[:-1], STEP_M).sd_m is None
    sp = reading_spread(z, STEP_M)
    assert sp.differences == MIN_DIFFERENCES and sp.sd_m is not None


def test_strength_amp_ref_and_the_noise_constants() -> None:
    assert target_strength(0.9, 0.0, 2.0) == pytest.approx(0.9)
    assert target_strength(0.3, 0.0, 3.0) == pytest.approx(0.3 * 4 / 9)
    assert target_strength(1.0, 60.0, 1.0) == pytest.approx(2.0)
    amp = amp_ref_of([1800, 1790, 1810, 1805, 1795, 60000, 1800], 0.9)
    assert amp.value == pytest.approx(2000.0) and 0 < amp.err < 10
    with pytest.raises(ValueError):
        amp_ref_of([], 0.9)
    c = noise_at_unit_strength(Figure(0.03, 0.001), 0.15)
    assert isinstance(c, Figure) and (c.value, c.err) == pytest.approx((0.0045, 0.00015))
    assert sigma0_of(c, 2000.0, 2.5e-7).value == pytest.approx(0.004)
    k = k_of(Figure(0.0115, 0.0003), 30_000.0, 0.004)
    assert k.value == pytest.approx(2.5e-7) and k.err == pytest.approx(1e-8)
    with pytest.raises(ValueError, match="light"):
        k_of(c, 0.0, 0.004)
