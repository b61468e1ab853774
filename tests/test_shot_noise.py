"""The shot-noise world (sim/shot_noise.py): its own noise law, the sensor's wire rules."""

from __future__ import annotations

import ast
import inspect
import math
import random
import statistics

import pytest

from lunad.sim import shot_noise
from lunad.sim.physics import RealisticSensor, Truth
from lunad.sim.shot_noise import SHOT_REF_DISTANCE_M, ShotNoiseSensor

QUANT_VAR_M2 = 0.01**2 / 12.0  # rounding to whole centimetres


def quiet(**kw: float) -> ShotNoiseSensor:
    return ShotNoiseSensor(amp_noise=0.0, spike_probability=0.0, **kw)


@pytest.mark.parametrize("lux", [0.0, 30_000.0])
@pytest.mark.parametrize("s", [0.3, 1.0, 3.0])
def test_empirical_noise_matches_sigma_of(s: float, lux: float) -> None:
    sensor = ShotNoiseSensor()
    rng = random.Random(f"{s}:{lux}")
    errs: list[float] = []
    sigmas: list[float] = []
    for _ in range(20_000):
        # A random offset inside one centimetre makes the rounding error uniform and
        # independent of the noise (var + 1/12 cm^2); R keeps S fixed at every distance.
        d = 1.0 + rng.random() * 0.01
        r = s * (d / SHOT_REF_DISTANCE_M) ** 2
        truth = Truth(d, r, 0.0, lux)
        rd = sensor.sample(truth, rng)
        assert rd.sigma_m is not None and rd.dist_cm > 0
        if rd.spike:
            continue
        errs.append(rd.dist_cm / 100.0 - d)
        sigmas.append(rd.sigma_m)
    sigma = sigmas[0]
    assert max(sigmas) - min(sigmas) < 1e-9 * sigma, "noise follows the true S, not the amp"
    assert sigma == pytest.approx(sensor.sigma_of(Truth(1.0, s * (1.0 / 1.5) ** 2, 0.0, lux)))
    measured = math.sqrt(statistics.pvariance(errs, mu=0.0) - QUANT_VAR_M2)
    assert measured == pytest.approx(sigma, rel=0.05)


def test_the_law_itself() -> None:
    sensor = quiet()
    at = SHOT_REF_DISTANCE_M
    assert sensor.sigma_of(Truth(at, 1.0, 0.0, 0.0)) == pytest.approx(math.hypot(0.005, 0.002))
    dark4 = sensor.sigma_of(Truth(at, 0.25, 0.0, 0.0))
    assert dark4 == pytest.approx(math.hypot(0.005 / 0.5, 0.002)), "1/sqrt(S) in the dark"
    sun = sensor.sigma_of(Truth(at, 1.0, 0.0, 60_000.0))
    assert sun == pytest.approx(math.hypot(0.005 * math.sqrt(1.0 + 0.336 * 60), 0.002))
    assert quiet(noise_scale=2.0).sigma_of(Truth(at, 1.0, 0.0, 0.0)) == pytest.approx(
        2.0 * math.hypot(0.005, 0.002)
    )
    assert math.isinf(sensor.sigma_of(Truth(at, 0.0, 0.0, 0.0))), "no signal, no reading"


def test_not_the_realistic_law() -> None:
    """At equal amp the two worlds disagree, and by a different amount in sun and dark."""
    shot = quiet()
    real = RealisticSensor(spike_probability=0.0, amp_noise=0.0)
    ratios = []
    for lux in (0.0, 40_000.0):
        truth_shot = Truth(3.0, 0.9, 0.0, lux)
        amp = round(shot.amp_of(truth_shot))
        ratios.append(shot.sigma_of(truth_shot) / real.sigma_of(Truth(3.0, 0.9, 0.0, lux), amp))
    assert abs(ratios[0] - ratios[1]) > 0.2 * ratios[0]


def test_amp_falls_with_distance_squared() -> None:
    sensor = quiet()
    rng = random.Random(0)
    a1 = sensor.sample(Truth(1.5, 0.8, 0.0, 0.0), rng).amp
    a3 = sensor.sample(Truth(3.0, 0.8, 0.0, 0.0), rng).amp
    a6 = sensor.sample(Truth(4.5, 0.8, 0.0, 0.0), rng).amp
    a60 = sensor.sample(Truth(1.5, 0.8, 60.0, 0.0), rng).amp
    assert a1 == 1200, "1500 amp per unit of S at 1.5 m"
    assert a3 == pytest.approx(a1 / 4, abs=1)
    assert a6 == pytest.approx(a1 / 9, abs=1)
    assert a60 == pytest.approx(a1 / 2, abs=1)


def test_amp_jitter_is_about_five_percent() -> None:
    sensor = ShotNoiseSensor(spike_probability=0.0)
    rng = random.Random(1)
    amps = [sensor.sample(Truth(1.5, 0.8, 0.0, 0.0), rng).amp for _ in range(4000)]
    assert statistics.fmean(amps) == pytest.approx(1200, rel=0.01)
    assert statistics.stdev(amps) / 1200 == pytest.approx(0.05, rel=0.1)


def test_below_threshold_reports_no_distance() -> None:
    sensor = quiet()
    rng = random.Random(2)
    far = sensor.sample(Truth(6.0, 0.9, 0.0, 0.0), rng)  # amp 84
    assert far.amp < 100 and far.dist_cm == 0 and far.sigma_m is None
    near = sensor.sample(Truth(5.0, 0.9, 0.0, 0.0), rng)  # amp 122
    assert near.amp >= 100 and near.dist_cm > 0 and near.sigma_m is not None
    raised = sensor.sample(Truth(5.0, 0.9, 0.0, 0.0), rng, amp_threshold=200)
    assert raised.dist_cm == 0 and raised.sigma_m is None
    dark = sensor.sample(Truth(2.0, 0.0, 0.0, 0.0), rng)
    assert dark.amp == 0 and dark.dist_cm == 0


def test_sensor_rules_saturated_strong_ambient_and_dist_max() -> None:
    sensor = quiet()
    rng = random.Random(3)
    assert sensor.sample(Truth(0.2, 0.9, 0.0, 0.0), rng).amp == 0xFFFF
    assert sensor.sample(Truth(0.3, 0.9, 0.0, 0.0), rng).amp == 30000, "M05 p.14 normal maximum"
    sun = sensor.sample(Truth(2.0, 0.9, 0.0, 75_000.0), rng)
    assert 32768 < sun.amp < 0xFFFF
    retro = sensor.sample(Truth(12.0, 10.0, 0.0, 0.0), rng)
    assert retro.dist_cm == 900


def test_readings_are_whole_centimetres_and_spikes_read_long() -> None:
    sensor = ShotNoiseSensor(spike_probability=0.5)
    rng = random.Random(4)
    spikes = 0
    for _ in range(2000):
        rd = sensor.sample(Truth(2.0, 0.9, 0.0, 0.0), rng)
        assert isinstance(rd.dist_cm, int)
        if rd.spike:
            spikes += 1
            assert 2.0 + 0.15 <= rd.dist_cm / 100.0 <= 2.0 + 1.55
    assert 800 < spikes < 1200


def test_a_seeded_run_repeats() -> None:
    truths = [Truth(1.0 + 0.01 * i, 0.7, 20.0, 1000.0 * i) for i in range(100)]
    a = [ShotNoiseSensor().sample(t, rng) for rng in [random.Random(5)] for t in truths]
    b = [ShotNoiseSensor().sample(t, rng) for rng in [random.Random(5)] for t in truths]
    assert a == b


def test_noise_scale_must_be_positive() -> None:
    with pytest.raises(ValueError):
        ShotNoiseSensor(0.0)


def test_shot_noise_never_imports_the_filters() -> None:
    tree = ast.parse(inspect.getsource(shot_noise))
    names = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)] + [
        a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names
    ]
    assert not [n for n in names if "filters" in n]
