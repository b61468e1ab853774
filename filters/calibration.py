"""Calibration maths: amp_ref and the noise constants of paper eq. 2 from a still target.

How this works. A still target of known reflectivity R, square to the beam or at a
known incidence angle theta, at a known distance d, has the strength

    S = R cos(theta) (2 m / d)^2

(paper eq. 1, with the d^2 fall-off of a target that fills the beam, docs/filter.md
"S includes distance"; S = 1 is a white target square to the beam at 2 m, the
definition of ``FilterConfig.amp_ref``), so its readings give

    amp_ref = median(amp) / S.

The readings scatter with sigma = c / S, c = sigma0 + k L (paper eqs 2-3), and the
sensor rounds them to its 1 cm output step. On a still target they are independent,
and once the noise dithers the steps (sigma from half a step up) their variance is
sigma^2 + q with q = step^2 / 12 (Sheppard's correction, as in noise.py). The spread
is taken from the second differences of consecutive readings,
d2 = z - 2 z1 + z2, var(d2) = 6 (sigma^2 + q), so that a slow drift of the target
(a card held by hand, a tripod settling) drops out:

    sigma^2 = mean(d2^2) / 6 - q,     c = sigma S,
    sigma0 = c - k L                  (L from a lux meter at the target; 0 in the dark)
    k = (c - sigma0) / L              (sigma0 from an earlier run in the dark).

Robust, but not with the MAD: the readings are whole centimetres, so their MAD is a
whole centimetre too, and MAD / 0.6745 reads 3.0 cm for any noise from 2.6 to 3.3 cm
(1000 readings, wherever the target sits). Instead the second differences beyond
``TRIM_SCALES`` robust standard deviations (median |d2| / 0.6745, at least
``TRIM_FLOOR_STEPS`` steps) are dropped before the mean square: a multipath spike
(two targets in the beam, M05 p.10) makes three of them, and dropping a normal
sample's tail beyond 3.5 sd (the nearest cut the median's whole-centimetre
granularity gives, at a noise of 0.8 step) loses 0.5 % of its variance.

Below half a step the steps hide the noise: a target exactly between two centimetres
and almost no noise splits the readings evenly between the two, variance step^2 / 4,
which reads as 0.41 step after the correction; a target on a centimetre reads 0.
Worked out exactly for a normal noise, no noise below half a step reads as half a step
or more wherever the target sits, and from half a step up the corrected spread is
within 2 % of the truth (1 % from 0.55 step); so below ``SPREAD_MIN_STEPS`` none is
given.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

REF_DISTANCE_M = 2.0
"""Distance at which S = R cos(theta): ``FilterConfig.amp_ref`` is the amp of a white
target square to the beam at 2 m (filters/config.py, AMP_REF_DEFAULT)."""

SPREAD_MIN_STEPS = 0.5
"""Below this reading noise, in output steps, no spread is given (our choice: the
smallest noise for which the step correction holds to 2 % wherever the target sits
between two steps; the module docstring says why it fails below)."""

TRIM_SCALES = 5.0
"""Second differences beyond this many robust standard deviations are dropped as
spikes (our choice: far enough out that a normal sample loses under 0.5 % of its
variance even where the median's whole-centimetre granularity puts the cut at 3.5 sd)."""

TRIM_FLOOR_STEPS = 3.0
"""The cut is never nearer than this many output steps (our choice: when most second
differences are 0, median |d2| is 0 and a cut at 5 x 0 would drop the steps' own
scatter; a multipath spike, 30 cm or more in the simulator, still falls beyond it)."""

MIN_DIFFERENCES = 20
"""Fewer second differences give no spread (our choice: 20 give it to about 22 %)."""

D2_MEAN_SQUARE_VARIANCE = 2.0 * (1.0 + 2.0 * ((4.0 / 6.0) ** 2 + (1.0 / 6.0) ** 2))
"""n var(mean(d2^2)) / var(d2)^2 for normal, independent readings: 2 for independent
samples, times 1 + 2 (rho1^2 + rho2^2) because consecutive second differences share
readings (rho1 = -4/6, rho2 = 1/6). About 3.9: a second difference costs twice the
readings a plain variance would, the price of ignoring drift."""

MEDIAN_VARIANCE = math.pi / 2.0
"""n var(median) / sd^2 for a normal sample (the median's asymptotic efficiency)."""

MAD_TO_SD = 1.4826  # sd of a normal sample over its median absolute deviation


@dataclass(frozen=True, slots=True)
class Figure:
    """A measured value and its one-sigma uncertainty from the number of readings.

    Attributes:
        value: the figure, in its unit (metres, metres per lux, amp).
        err: one standard deviation of it, same unit; the scatter of the readings
            only (an error in the stated reflectivity, distance or lux is not in it).
    """

    value: float
    err: float


@dataclass(frozen=True, slots=True)
class Spread:
    """The one-sigma noise of single readings of a still target.

    Attributes:
        sd_m: the readings' standard deviation with the output step's share taken
            out, metres; None when ``below_step`` or with fewer than
            ``MIN_DIFFERENCES`` second differences.
        below_step: the noise is under ``SPREAD_MIN_STEPS`` output steps: the steps
            hide it.
        differences: second differences of consecutive usable readings used.
        dropped: second differences dropped as spikes.
        repeat_share: fraction of the readings on their most common step (near 1:
            the readings repeat one centimetre).
    """

    sd_m: Figure | None
    below_step: bool
    differences: int
    dropped: int
    repeat_share: float


def target_strength(reflectivity: float, angle_deg: float, distance_m: float) -> float:
    """S = R cos(theta) (2 m / d)^2 of a target that fills the beam (module docstring).

    Args:
        reflectivity: R, 0 to 1.
        angle_deg: incidence angle theta, degrees.
        distance_m: distance d to the target, metres.
    """
    g = REF_DISTANCE_M / distance_m
    return reflectivity * math.cos(math.radians(angle_deg)) * g * g


def amp_ref_of(amps: Sequence[int], strength: float) -> Figure:
    """amp_ref = median(amp) / S, with the median's uncertainty.

    The median rather than the mean: the odd reading with a spike in its amp moves
    it by at most one rank.

    Raises:
        ValueError: no amps, or a strength that is not positive.
    """
    if not amps or not strength > 0:
        raise ValueError("amp_ref needs amps and a positive strength")
    median = statistics.median(amps)
    sd = MAD_TO_SD * statistics.median(abs(a - median) for a in amps)
    err = math.sqrt(MEDIAN_VARIANCE / len(amps)) * sd
    return Figure(median / strength, err / strength)


def reading_spread(distances_m: Sequence[float | None], resolution_m: float) -> Spread:
    """The noise of single readings of a still target, from their second differences.

    Args:
        distances_m: the readings in the order the sensor sent them, metres; None for
            one that is not usable (no distance, flagged by the sensor), which breaks
            the chain of consecutive readings.
        resolution_m: the sensor's output step, metres (1 cm; ``FilterConfig``).
    """
    d2: list[float] = []
    for z2, z1, z in zip(distances_m, distances_m[1:], distances_m[2:], strict=False):
        if z is not None and z1 is not None and z2 is not None:
            d2.append(z - 2.0 * z1 + z2)
    steps = Counter(round(z / resolution_m) for z in distances_m if z is not None)
    repeat = max(steps.values()) / steps.total() if steps else 0.0
    if len(d2) < MIN_DIFFERENCES:
        return Spread(None, False, len(d2), 0, repeat)
    scale = statistics.median(abs(x) for x in d2) / statistics.NormalDist().inv_cdf(0.75)
    cut = max(TRIM_SCALES * scale, TRIM_FLOOR_STEPS * resolution_m)
    kept = [x * x for x in d2 if abs(x) <= cut]
    n = len(kept)
    dropped = len(d2) - n
    mean_square = math.fsum(kept) / n
    q = resolution_m * resolution_m / 12.0
    var = mean_square / 6.0 - q
    if var < (SPREAD_MIN_STEPS * resolution_m) ** 2:
        return Spread(None, True, n, dropped, repeat)
    sd = math.sqrt(var)
    var_err = mean_square / 6.0 * math.sqrt(D2_MEAN_SQUARE_VARIANCE / n)
    return Spread(Figure(sd, var_err / (2.0 * sd)), False, n, dropped, repeat)


def noise_at_unit_strength(spread: Figure, strength: float) -> Figure:
    """c = sigma S, metres: the noise a reading of this target would have at S = 1.

    Paper eq. 3 makes a reading's noise c / S, so c is the spread times S.
    """
    return Figure(spread.value * strength, spread.err * strength)


def sigma0_of(c: Figure, lux: float, k_m_per_lux: float) -> Figure:
    """sigma0 = c - k L, metres: paper eq. 2 at zero light, with k taken as known.

    The uncertainty is c's; an error in k or in the lux reading adds to it.
    """
    return Figure(c.value - k_m_per_lux * lux, c.err)


def k_of(c: Figure, lux: float, sigma0_m: float) -> Figure:
    """k = (c - sigma0) / L, metres per lux: paper eq. 2, with sigma0 taken as known.

    The uncertainty is c's; an error in sigma0 or in the lux reading adds to it.

    Raises:
        ValueError: ``lux`` is not positive (in the dark, the light's share is 0).
    """
    if not lux > 0:
        raise ValueError(f"k needs light on the target, got {lux!r} lux")
    return Figure((c.value - sigma0_m) / lux, c.err / lux)
