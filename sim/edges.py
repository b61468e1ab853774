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
"""

from __future__ import annotations

from collections.abc import Callable

from lunad.sim.physics import Truth

EDGE_OLD_SHARES = (2.0 / 3.0, 1.0 / 3.0)
"""Share of the returned light still from the old surface in the readings that follow
a distance step, one entry per reading (our choice: two readings, as a beam 2 degrees
wide crossing an edge at a robot's turning speed of about 90 deg/s blends for 20 ms,
5 frames at 250 Hz, of which the middle ones mix most)."""
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
