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
