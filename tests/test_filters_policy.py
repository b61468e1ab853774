"""Hard gates, their hysteresis bands, and the ambient flag (filters/policy.py)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from lunad.filters import DropoutPolicy, FilterConfig, Reason
from lunad.filters.policy import first_amp_at_least

CFG = FilterConfig()


def gate(policy: DropoutPolicy, raw_m: float | None, amp: int) -> tuple[Reason, ...]:
    return policy.gate(raw_m, amp)


def test_clean_reading_passes_and_is_usable() -> None:
    p = DropoutPolicy(CFG)
    assert gate(p, 2.0, 1500) == ()
    assert p.usable


def test_each_hard_gate_names_its_reason() -> None:
    cases = [
        ((2.0, 0xFFFF), (Reason.SATURATED,)),
        ((2.0, 40000), (Reason.HIGH_AMBIENT,)),
        ((None, 50), (Reason.WEAK_SIGNAL,)),
        ((None, 1500), (Reason.OUT_OF_RANGE,)),
        ((0.15, 1500), (Reason.OUT_OF_RANGE,)),
        ((8.2, 1500), (Reason.OUT_OF_RANGE,)),
    ]
    for (raw, amp), want in cases:
        p = DropoutPolicy(CFG)
        assert gate(p, raw, amp) == want, (raw, amp)


def test_s_min_applies_when_amp_ref_makes_it_stricter_than_amp_min() -> None:
    cfg = FilterConfig(amp_ref=4000.0)  # S_min 0.05 -> amp 200
    p = DropoutPolicy(cfg)
    assert p.gate(2.0, 150) == (Reason.WEAK_SIGNAL,)
    assert DropoutPolicy(cfg).gate(2.0, 205) == ()


def test_weak_band_holds_until_amp_clears_the_hysteresis() -> None:
    p = DropoutPolicy(CFG)  # band: amp 100 .. 110
    assert gate(p, None, 95) == (Reason.WEAK_SIGNAL,)
    assert gate(p, 3.0, 105) == (Reason.WEAK_SIGNAL,)
    assert p.usable, "a reading inside the band is valid data for the filter"
    assert gate(p, 3.0, 112) == ()
    assert gate(p, 3.0, 105) == (), "above the threshold without a prior weak: no band"


def test_range_band_holds_until_well_inside() -> None:
    p = DropoutPolicy(CFG)
    assert gate(p, 8.02, 500) == (Reason.OUT_OF_RANGE,)
    assert p.usable, "just beyond the range still feeds the filter"
    assert gate(p, 7.97, 500) == (Reason.OUT_OF_RANGE,)
    assert gate(p, 7.90, 500) == ()
    assert gate(p, 9.5, 500) == (Reason.OUT_OF_RANGE,)
    assert not p.usable


@given(st.lists(st.integers(min_value=100, max_value=109), min_size=1, max_size=50))
def test_no_flapping_inside_the_weak_band(amps: list[int]) -> None:
    p = DropoutPolicy(CFG)
    gate(p, None, 90)
    for amp in amps:
        assert Reason.WEAK_SIGNAL in gate(p, 3.0, amp)


@given(
    st.one_of(st.none(), st.floats(min_value=0.0, max_value=12.0)),
    st.integers(min_value=0, max_value=0xFFFF),
)
def test_invalid_readings_never_pass(raw_m: float | None, amp: int) -> None:
    p = DropoutPolicy(CFG)
    reasons = gate(p, raw_m, amp)
    invalid = raw_m is None or amp < 100 or amp > 32768 or not CFG.min_range_m <= raw_m <= 8.0
    assert bool(reasons) == invalid


def test_high_ambient_has_hysteresis() -> None:
    p = DropoutPolicy(CFG)
    assert not p.high_ambient(19_000.0)
    assert p.high_ambient(21_000.0)
    assert p.high_ambient(19_000.0), "inside the band: stays high"
    assert not p.high_ambient(17_000.0)


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
    from lunad.filters import RangeFilter

    p = DropoutPolicy(CFG)
    gate(p, None, 95)
    assert gate(p, 3.0, 110) == ()
    flt = RangeFilter(CFG)
    flt.step(None, 95, 0)
    assert flt.step(3.0, 110, 4_000_000).reasons == ()
