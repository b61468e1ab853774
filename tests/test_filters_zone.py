"""Zone classification with hysteresis (filters/zone.py)."""

from __future__ import annotations

from lunad.filters import FilterConfig, Zone, ZoneClassifier


def test_zones_follow_the_papers_stable_region() -> None:
    z = ZoneClassifier(FilterConfig())
    assert z.classify(500.0, 0.9, 0.004) is Zone.STABLE
    z.reset()
    assert z.classify(15_000.0, 0.9, 0.004) is Zone.MARGINAL
    z.reset()
    assert z.classify(500.0, 0.2, 0.004) is Zone.MARGINAL
    z.reset()
    assert z.classify(500.0, 0.05, 0.004) is Zone.UNRELIABLE
    z.reset()
    assert z.classify(60_000.0, 0.9, 0.004) is Zone.UNRELIABLE
    z.reset()
    assert z.classify(500.0, 0.9, 0.2) is Zone.UNRELIABLE


def test_hysteresis_keeps_a_zone_near_its_threshold() -> None:
    z = ZoneClassifier(FilterConfig())
    assert z.classify(500.0, 0.40, 0.004) is Zone.STABLE
    assert z.classify(500.0, 0.33, 0.004) is Zone.STABLE, "inside the band"
    assert z.classify(500.0, 0.27, 0.004) is Zone.MARGINAL
    assert z.classify(500.0, 0.36, 0.004) is Zone.STABLE


def test_leaving_unreliable_needs_margin() -> None:
    z = ZoneClassifier(FilterConfig())
    assert z.classify(500.0, 0.09, 0.004) is Zone.UNRELIABLE
    assert z.classify(500.0, 0.11, 0.004) is Zone.UNRELIABLE
    assert z.classify(500.0, 0.13, 0.004) is Zone.MARGINAL
    assert z.dropout() is Zone.UNRELIABLE


def test_zone_does_not_flap_on_a_static_indoor_scene() -> None:
    """Regression (seen in `lunad demo`): on a strong return indoors the fast lux estimate
    spreads by klux from frame to frame; the zone uses the slower average and holds.
    Among published estimates, that is: a multipath spike is a dropout frame, whose
    zone is ``unreliable`` by definition (docs/messages.md)."""
    import itertools
    import random

    from lunad.filters import RangeFilter
    from lunad.sim.physics import RealisticSensor, Truth

    f = RangeFilter()
    model = RealisticSensor()
    rng = random.Random(5)
    truth = Truth(distance_m=1.21, reflectivity=0.8, angle_deg=0.0, lux=300.0)
    zones = []
    dropouts = 0
    for k in range(2000):  # 20 s at 100 Hz
        r = model.sample(truth, rng)
        est = f.step(r.dist_cm / 100 if r.dist_cm else None, r.amp, k * 10_000_000)
        if k >= 200:
            if est.range_m is None:
                dropouts += 1
            else:
                zones.append(est.zone)
    assert dropouts < 0.01 * 1800
    changes = sum(a != b for a, b in itertools.pairwise(zones))
    assert changes <= 2, changes
    assert zones.count("stable") > 0.95 * len(zones)
