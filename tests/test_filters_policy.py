"""Hard gates and their hysteresis bands, as RangeFilter applies them (filters/policy.py)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from lunad.filters import FilterConfig, RangeFilter, Reason
from lunad.filters.policy import first_amp_at_least

CFG = FilterConfig()
FRAME_NS = 4_000_000
GATE_REASONS = {
    Reason.SATURATED,
    Reason.HIGH_AMBIENT,
    Reason.WEAK_SIGNAL,
    Reason.NO_DISTANCE,
    Reason.TOO_CLOSE,
    Reason.TOO_FAR,
}


class Gates:
    """Feeds one RangeFilter frame by frame and reports the gate reasons of each."""

    def __init__(self, config: FilterConfig = CFG) -> None:
        self.flt = RangeFilter(config)
        self.k = 0

    def __call__(self, raw_m: float | None, amp: int) -> tuple[Reason, ...]:
        est = self.flt.step(raw_m, amp, self.k * FRAME_NS)
        self.k += 1
        return tuple(r for r in est.reasons if r in GATE_REASONS)

    @property
    def fed(self) -> bool:
        """Whether a reading has fed the filter (a track started)."""
        return self.flt.active


def test_clean_reading_passes_and_feeds_the_filter() -> None:
    g = Gates()
    assert g(2.0, 1500) == ()
    assert g.fed


def test_each_hard_gate_names_its_reason() -> None:
    cases = [
        ((2.0, 0xFFFF), (Reason.SATURATED,)),
        ((2.0, 40000), (Reason.HIGH_AMBIENT,)),
        ((None, 50), (Reason.WEAK_SIGNAL,)),
        ((None, 1500), (Reason.NO_DISTANCE,)),
        ((0.15, 1500), (Reason.TOO_CLOSE,)),
        ((8.2, 1500), (Reason.TOO_FAR,)),
        ((0.15, 50), (Reason.WEAK_SIGNAL, Reason.TOO_CLOSE)),
        ((8.2, 50), (Reason.WEAK_SIGNAL, Reason.TOO_FAR)),
    ]
    for (raw, amp), want in cases:
        assert Gates()(raw, amp) == want, (raw, amp)


def test_s_min_applies_when_amp_ref_makes_it_stricter_than_amp_min() -> None:
    cfg = FilterConfig(amp_ref=4000.0)  # S_min 0.05 -> amp 200
    assert Gates(cfg)(2.0, 150) == (Reason.WEAK_SIGNAL,)
    assert Gates(cfg)(2.0, 205) == ()


def test_weak_band_holds_until_amp_clears_the_hysteresis() -> None:
    g = Gates()  # band: amp 100 .. 110
    assert g(None, 95) == (Reason.WEAK_SIGNAL,)
    assert g(3.0, 105) == (Reason.WEAK_SIGNAL,)
    assert g.fed, "a reading inside the band is valid data for the filter"
    assert g(3.0, 112) == ()
    assert g(3.0, 105) == (), "above the threshold without a prior weak: no band"


def test_range_band_holds_until_well_inside() -> None:
    g = Gates()
    assert g(8.02, 500) == (Reason.TOO_FAR,)
    assert g.fed, "just beyond the range still feeds the filter"
    assert g(7.97, 500) == (Reason.TOO_FAR,)
    assert g(7.90, 500) == ()
    assert g(0.22, 500) == (), "not latched: inside the gate is inside"
    assert g(0.15, 500) == (Reason.TOO_CLOSE,)
    assert g(0.22, 500) == (Reason.TOO_CLOSE,), "latched: 5 cm inside the gate to leave"
    assert g(0.26, 500) == ()


def test_far_beyond_the_range_does_not_feed_the_filter() -> None:
    g = Gates()
    assert g(9.5, 500) == (Reason.TOO_FAR,)
    assert not g.fed


@given(st.lists(st.integers(min_value=100, max_value=109), min_size=1, max_size=50))
def test_no_flapping_inside_the_weak_band(amps: list[int]) -> None:
    g = Gates()
    g(None, 90)
    for amp in amps:
        assert Reason.WEAK_SIGNAL in g(3.0, amp)


@given(
    st.one_of(st.none(), st.floats(min_value=0.0, max_value=12.0)),
    st.integers(min_value=0, max_value=0xFFFF),
)
def test_invalid_readings_never_pass(raw_m: float | None, amp: int) -> None:
    reasons = Gates()(raw_m, amp)
    invalid = raw_m is None or amp < 100 or amp > 32768 or not CFG.min_range_m <= raw_m <= 8.0
    assert bool(reasons) == invalid


@given(
    st.floats(min_value=1.0, max_value=60_000.0),
    st.floats(min_value=1e-4, max_value=2.0),
    st.floats(min_value=0.0, max_value=5000.0),
    st.integers(min_value=0, max_value=0xFFFF),
)
def test_integer_threshold_decides_as_comparing_s(
    amp_ref: float, s_min: float, amp_min: float, amp: int
) -> None:
    inv = 1.0 / amp_ref
    t = first_amp_at_least(amp_min, s_min, inv)
    for a in (amp, t - 2, t - 1, t, t + 1):
        if a >= 0:
            strong = not (a < amp_min or a * inv < s_min)
            assert (a >= t) == strong, (a, t)


def test_the_weak_band_ends_at_amp_110_as_documented() -> None:
    """docs/filter.md: readings stay weak until amp >= 110 and S >= 0.055. In floats
    100 * 1.1 is 110.00000000000001, which moved the edge to 111."""
    g = Gates()
    g(None, 95)
    assert g(3.0, 110) == ()
