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
    assert zones.count(Zone.STABLE) > 0.95 * len(zones)


def test_the_filters_inline_zones_are_the_classifiers() -> None:
    """RangeFilter.step applies the zone rules inline (one call less on every frame);
    replaying ZoneClassifier on what each frame published must give the same zone, on
    runs that cross every threshold both ways. An outlier's zone is judged on the
    track's own sigma (docs/filter.md), which the filter keeps in ``p00``."""
    import math

    from lunad.filters import RangeFilter, Reason
    from lunad.sim.evaluate import simulate
    from lunad.sim.scenario import load_scenario

    config = FilterConfig()
    runs = [
        list(zip(run.raw_m, run.amp, run.t_ns, strict=True))
        for name in ("sun_ramp", "room_sweep", "obstacles", "beyond_range")
        for world in ("paper", "shot")
        for run in (simulate(load_scenario(name), world, 1.0, 0),)
    ]
    # A strong return, then one weak enough for S < 0.1 (stable straight to unreliable).
    runs.append([(2.0, 3000 if k < 300 else 150, k * 4_000_000) for k in range(400)])
    seen: set[tuple[Zone, Zone]] = set()
    for frames in runs:
        f = RangeFilter(config)
        ref = ZoneClassifier(config)
        for z, amp, t in frames:
            before = f.zone
            est = f.step(z, amp, t)
            if est.range_m is None:
                assert est.zone is Zone.UNRELIABLE and f.zone is Zone.UNRELIABLE
                continue
            assert est.sigma_m is not None
            sigma = est.sigma_m
            if Reason.OUTLIER in est.reasons:
                sigma = max(math.sqrt(f.p00), config.sigma_floor_m)
            ref.zone = before
            assert ref.classify(est.lux_est or 0.0, est.strength, sigma) is est.zone
            assert f.zone is est.zone
            seen.add((before, est.zone))
    changes = {(a, b) for a, b in seen if a is not b}
    assert len(changes) == 6, f"every change between zones must be played: {changes}"
