"""RangeFilter (flat, what the daemon runs) computes exactly what ReferenceFilter
(composed from the documented pieces) computes: equal estimates, float for float."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lunad.filters import Estimate, FilterConfig, RangeFilter, ReferenceFilter
from lunad.sim.evaluate import simulate
from lunad.sim.scenario import builtin_scenarios, load_scenario

FIXED_SIGMA_M = 0.005

Step = tuple[float | None, int, int, float]
"""One call: raw_m, amp, t_mono_ns, sigma_known (0: estimate the noise)."""


def run_both(config: FilterConfig, steps: list[Step], reset_at: int = -1) -> None:
    """Feed ``steps`` to both filters; assert every estimate and the end state equal."""
    flat, ref = RangeFilter(config), ReferenceFilter(config)
    for i, (raw_m, amp, t_ns, sigma) in enumerate(steps):
        if i == reset_at:
            flat.reset()
            ref.reset()
        a: Estimate = flat.step(raw_m, amp, t_ns, sigma)
        b: Estimate = ref.step(raw_m, amp, t_ns, sigma)
        assert a == b, f"frame {i}: {steps[i]}"
        assert tuple(map(type, a)) == tuple(map(type, b)), f"frame {i}"
    assert (flat.x, flat.v, flat.p00, flat.p01, flat.p11) == (
        ref.tracker.x,
        ref.tracker.v,
        ref.tracker.p00,
        ref.tracker.p01,
        ref.tracker.p11,
    )
    assert (flat.c2, flat.c2_zone, flat.zones.zone) == (ref.lux.c2, ref.lux.c2_zone, ref.zones.zone)


@pytest.mark.parametrize("scale", [0.5, 1.0, 2.0])
@pytest.mark.parametrize("name", builtin_scenarios())
def test_equal_on_every_scenario(name: str, scale: float) -> None:
    run = simulate(load_scenario(name), scale, seed=0)
    frames = list(zip(run.raw_m, run.amp, run.t_ns, run.readings, strict=True))
    true_sigma = [rd.sigma_m if rd.sigma_m is not None else 1.0 for *_, rd in frames]
    for sigmas in ([0.0] * len(frames), true_sigma, [FIXED_SIGMA_M] * len(frames)):
        steps = [(z, amp, t, sig) for (z, amp, t, _), sig in zip(frames, sigmas, strict=True)]
        run_both(FilterConfig(), steps, reset_at=len(steps) // 2)


readings = st.one_of(
    st.none(),
    st.floats(0.0, 10.0, allow_nan=False),
    st.sampled_from([0.2, 0.25, 7.95, 8.0, 8.05, 9.0]),
)
amps = st.one_of(
    st.integers(0, 70_000),
    st.sampled_from([0, 99, 100, 110, 111, 32768, 32769, 65535]),
    st.integers(1500, 2500),
)
gaps_ns = st.sampled_from([0, 1, 4_000_000, 4_000_000, 4_000_000, 30_000_000, 600_000_000])
sigmas = st.sampled_from([0.0, 0.0, 0.0, 0.005, 0.3])


@st.composite
def streams(draw: st.DrawFn) -> list[Step]:
    """Readings around a slowly moving target, with spikes, gaps, dropouts and jumps."""
    n = draw(st.integers(1, 120))
    truth = draw(st.floats(0.1, 9.0))
    t = draw(st.integers(0, 10**12))
    out: list[Step] = []
    for _ in range(n):
        truth += draw(st.sampled_from([0.0, 0.0, 0.001, -0.001, 0.5, -0.5]))
        z = draw(st.one_of(st.just(truth), st.just(truth + 0.01), readings))
        t += draw(gaps_ns)
        out.append((z, draw(amps), t, draw(sigmas)))
    return out


configs = st.builds(
    FilterConfig,
    amp_ref=st.sampled_from([2000.0, 777.7, 5000.0]),
    stale_after_s=st.sampled_from([0.5, 0.05]),
    step_confirm=st.integers(1, 4),
    lux_init=st.sampled_from([0.0, 30_000.0]),
    lux_tau_s=st.sampled_from([0.1, 0.001]),
    gate_sigmas=st.sampled_from([4.0, 1.0]),
    lux_high_ambient=st.sampled_from([20_000.0, 100.0]),
)


@settings(max_examples=300, deadline=None)
@given(config=configs, steps=streams(), reset_at=st.integers(-1, 60))
def test_equal_on_any_stream(config: FilterConfig, steps: list[Step], reset_at: int) -> None:
    run_both(config, steps, reset_at)
