"""The realistic sensor profile and the paper profile (sim/physics.py)."""

from __future__ import annotations

import ast
import inspect
import math
import random
import statistics

import numpy as np
import pytest

from lunad.sim import physics
from lunad.sim.physics import AMP_REF, PaperSensor, RawReading, RealisticSensor, Truth


def quiet(**kw: float) -> RealisticSensor:
    return RealisticSensor(spike_probability=0.0, amp_noise=0.0, **kw)


def test_amp_falls_with_distance_squared_and_cos_theta() -> None:
    s = quiet()
    rng = random.Random(0)
    a2 = s.sample(Truth(2.0, 0.5, 0.0, 0.0), rng).amp
    a4 = s.sample(Truth(4.0, 0.5, 0.0, 0.0), rng).amp
    a60 = s.sample(Truth(2.0, 0.5, 60.0, 0.0), rng).amp
    assert a2 == round(AMP_REF * 0.5)
    assert a4 == pytest.approx(a2 / 4, abs=1)
    assert a60 == pytest.approx(a2 / 2, abs=1)


def test_sensor_rules_weak_saturated_ambient() -> None:
    s = quiet()
    rng = random.Random(1)
    weak = s.sample(Truth(9.0, 0.9, 0.0, 0.0), rng)
    assert weak.amp < 100 and weak.dist_cm == 0 and weak.sigma_m is None
    sat = s.sample(Truth(0.2, 0.9, 0.0, 0.0), rng)
    assert sat.amp == 0xFFFF
    assert s.sample(Truth(0.5, 0.9, 0.0, 0.0), rng).amp == 28800
    assert s.sample(Truth(0.4, 0.9, 0.0, 0.0), rng).amp == 30000, "M05 p.14 normal maximum"
    sun = s.sample(Truth(2.0, 0.9, 0.0, 75_000.0), rng)
    assert 32768 < sun.amp < 0xFFFF


def test_readings_are_whole_centimetres_within_dist_max() -> None:
    s = RealisticSensor()
    rng = random.Random(2)
    for d in (0.3, 2.0, 8.3):
        rd = s.sample(Truth(d, 0.9, 0.0, 0.0), rng)
        assert isinstance(rd.dist_cm, int) and 0 <= rd.dist_cm <= 900


@pytest.mark.parametrize(("amp", "datasheet_cm"), [(2000, 0.5), (1000, 1.0), (400, 2.0)])
def test_noise_near_the_datasheet_repeatability(amp: int, datasheet_cm: float) -> None:
    s = quiet()
    r = 0.5
    d = 2.0 * math.sqrt(AMP_REF * r / amp)
    rng = random.Random(3)
    dists = [s.sample(Truth(d, r, 0.0, 0.0), rng).dist_cm for _ in range(4000)]
    assert statistics.pstdev(dists) == pytest.approx(datasheet_cm, rel=0.25)


@pytest.mark.parametrize("scale", [0.5, 1.0, 2.0])
def test_per_reading_sigma_follows_the_paper_structure(scale: float) -> None:
    s = RealisticSensor(scale, spike_probability=0.0, amp_noise=0.0)
    truth = Truth(1.7, 0.3, 20.0, 30_000.0)
    rng = random.Random(4)
    rds = [s.sample(truth, rng) for _ in range(4000)]
    strength = rds[0].amp / AMP_REF
    want = scale * (physics.REALISTIC_SIGMA0_M + physics.REALISTIC_K_M_PER_LUX * 30_000) / strength
    assert rds[0].sigma_m == pytest.approx(want)
    spread = statistics.pstdev(rd.dist_cm / 100 for rd in rds)
    assert spread == pytest.approx(math.hypot(want, 0.01 / math.sqrt(12)), rel=0.08)


def test_spikes_are_rare_and_push_the_reading_long() -> None:
    s = RealisticSensor(amp_noise=0.0)
    rng = random.Random(5)
    rds = [s.sample(Truth(2.0, 0.9, 0.0, 0.0), rng) for _ in range(20_000)]
    spikes = [rd for rd in rds if rd.spike]
    assert 0.0005 < len(spikes) / len(rds) < 0.005
    assert all(rd.dist_cm >= 200 + 25 for rd in spikes)


def test_paper_sensor_still_works_and_reports_its_sigma() -> None:
    rd = PaperSensor().sample(Truth(2.0, 0.5, 0.0, 0.0), random.Random(6))
    assert isinstance(rd, RawReading)
    assert rd.amp == 1000
    assert rd.sigma_m == pytest.approx(0.01 / 0.5)


def test_physics_never_imports_the_filters() -> None:
    tree = ast.parse(inspect.getsource(physics))
    names = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)] + [
        a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names
    ]
    assert not any("filters" in n for n in names)


def test_noise_scale_must_be_positive() -> None:
    with pytest.raises(ValueError, match="noise_scale"):
        RealisticSensor(0.0)


@pytest.mark.parametrize(("reflectivity", "angle_deg"), [(0.0499, 0.0), (0.0498, 0.0), (0.1, 60.1)])
def test_paper_sensor_drops_strength_below_0_05_before_rounding_amp(
    reflectivity: float, angle_deg: float
) -> None:
    """S in [0.04975, 0.05) rounds to amp 100, yet the paper drops S < 0.05 (eq. 1), as
    the vectorised paper profile does; it used to be reported."""
    from lunad.sim.paper_model import PAPER_METRES

    truth = Truth(2.0, reflectivity, angle_deg, 0.0)
    rd = PaperSensor().sample(truth, random.Random(0))
    assert rd.amp == 100 and rd.dist_cm == 0 and rd.sigma_m is None
    detect = PAPER_METRES.detect_probability(
        np.array([0.0]), np.array([reflectivity]), np.array([angle_deg])
    )
    assert detect[0] == 0.0
    assert PaperSensor().sample(Truth(2.0, 0.05, 0.0, 0.0), random.Random(0)).dist_cm > 0


@pytest.mark.parametrize("model", [PaperSensor(), quiet()], ids=["paper", "realistic"])
def test_models_draw_a_distance_down_to_the_amp_threshold_they_are_given(
    model: PaperSensor | RealisticSensor,
) -> None:
    """The sensor's threshold is settable (ID 0x22); below the default 100 a model must
    still measure, or a lowered threshold would report nothing."""
    truth = Truth(2.0, 0.04, 0.0, 0.0)  # amp 80
    weak = model.sample(truth, random.Random(7))
    assert (weak.dist_cm, weak.amp, weak.sigma_m) == (0, 80, None)
    lowered = model.sample(truth, random.Random(7), amp_threshold=50)
    assert lowered.amp == 80 and lowered.sigma_m is not None and 100 <= lowered.dist_cm <= 300
    assert model.sample(truth, random.Random(7), amp_threshold=80).sigma_m is not None
    assert model.sample(truth, random.Random(7), amp_threshold=90).sigma_m is None
