"""Readings at an edge: the beam on two surfaces at once.

How this works. The TF-Luna's beam is 2 degrees wide (docs/tfluna.md): 7 cm across at
2 m. When the surface under it changes (a person steps into it, a sweep crosses a
doorway, a robot turns past a corner) the footprint lies on both surfaces for a
moment, and the sensor returns one distance for the light of both. A time-of-flight
sensor that measures the phase or the centroid of the returned light reports, for
two returns close enough to blend, about their mean weighted by the light each
returns (our model; the datasheet says nothing of it), with an amp that is the sum.
That reading is of neither surface.

``mixed_truth`` turns that into a single ``Truth`` any sensor physics can draw a
reading from: the weighted distance, the summed signal (as an equivalent
reflectivity at normal incidence) and the light of the surface the beam moves to, so
each world draws its own noise for the amp the mixed reading has. The truth to judge
an estimate against stays the beam centre's surface (the new one): a mixed reading is
an error of the sensor, which the filter should not publish as good.

``edge_view`` applies it to a scenario in time, for ``lunad eval`` and the virtual
sensor alike: the readings drawn within ``EDGE_READING_S`` per share after a distance
jump see both surfaces.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence

from lunad.sim.physics import Truth

EDGE_OLD_SHARES = (2.0 / 3.0, 1.0 / 3.0)
"""Share of the returned light still from the old surface in the readings that follow
a distance step, one entry per reading (our choice: two readings, as a beam 2 degrees
wide crossing an edge at a robot's turning speed of about 90 deg/s blends for 20 ms,
5 frames at 250 Hz, of which the middle ones mix most)."""
EDGE_READING_S = 0.004
"""Time after a jump each entry of ``EDGE_OLD_SHARES`` lasts, seconds: one reading at
250 Hz, the rate the built-in scenarios run at. At another rate a reading takes the
share of the moment it is drawn: the blend is the beam's, not the sensor's."""
JUST_BEFORE_S = 1e-6  # how long before a jump the surface it leaves is looked up
MIN_EDGE_M = 0.05
"""Steps in distance smaller than this, metres, are not edges: the two surfaces lie
within the sensor's own noise of each other."""


def mixed_truth(
    amp_of: Callable[[Truth], float], old: Truth, new: Truth, old_share: float
) -> Truth:
    """The ``Truth`` whose reading is that of a beam on ``old`` and ``new`` at once.

    Args:
        amp_of: the world's amp for a truth, before jitter and limits.
        old: the surface the beam leaves.
        new: the surface the beam moves to (the beam centre's).
        old_share: share of the footprint still on ``old``, 0..1.

    Returns:
        A truth at the light-weighted mean distance, whose amp is the sum of the two
        surfaces' shares, at normal incidence; ``new`` itself when neither returns light.
    """
    p_old = old_share * amp_of(old)
    p_new = (1.0 - old_share) * amp_of(new)
    total = p_old + p_new
    if total <= 0.0:
        return new
    distance = (p_old * old.distance_m + p_new * new.distance_m) / total
    unit = amp_of(Truth(distance, 1.0, 0.0, new.lux))
    if unit <= 0.0:
        return new
    return Truth(distance, total / unit, 0.0, new.lux)


def edge_view(
    step_times_s: Sequence[float],
    truth_at: Callable[[float], Truth],
    amp_of: Callable[[Truth], float],
    length_s: float | None = None,
) -> Callable[[float, Truth], Truth]:
    """What the beam sees at a time, given the truth then: the truth itself, or within
    ``len(EDGE_OLD_SHARES) * EDGE_READING_S`` after a distance jump of ``MIN_EDGE_M`` or
    more, the ``mixed_truth`` of the surfaces before and after it.

    Args:
        step_times_s: the instants the distance jumps (``Scenario.step_times_s``).
        truth_at: the truth at a time, seconds (``Scenario.truth_at``).
        amp_of: the world's amp for a truth.
        length_s: a scenario played in a loop: times are taken modulo this.

    Returns:
        ``view(t_s, truth)``, which returns ``truth`` itself (the same object) when the
        beam sees a single surface.
    """
    steps = tuple(sorted(step_times_s))
    span = len(EDGE_OLD_SHARES)

    def view(t_s: float, truth: Truth) -> Truth:
        t = t_s % length_s if length_s else t_s
        i = bisect_right(steps, t + 1e-9) - 1  # a frame drawn at the jump's instant sees it
        if i < 0:
            return truth
        k = int((t - steps[i]) / EDGE_READING_S + 1e-6)
        if k >= span:
            return truth
        old = truth_at(steps[i] - JUST_BEFORE_S)
        if abs(old.distance_m - truth.distance_m) < MIN_EDGE_M:
            return truth
        return mixed_truth(amp_of, old, truth, EDGE_OLD_SHARES[k])

    return view
