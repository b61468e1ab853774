"""Dropout policy: the hard gates, their hysteresis, and the integer amp thresholds.

How this works. One reading is a dropout when any of these holds (docs/tfluna.md
section 4; paper section III); ``RangeFilter.step`` applies them inline:

    amp == 0xFFFF                        saturated     (M05 p.14)
    amp >  32768                         high_ambient  (M05 p.14: ambient overexposure)
    amp <  amp_min  or  S < S_min        weak_signal   (M05 p.16; paper S_min = 0.05)
    no distance, signal not weak         no_distance
    distance below / above [0.2, 8] m    too_close / too_far  (M05 p.10; paper section III)

Hysteresis (our addition; the paper has sharp thresholds): once a reading was weak,
the next ones stay weak until amp >= amp_min (1 + h) and S >= S_min (1 + h); once
out of range, until the distance is range_hysteresis_m inside the gate. Readings in
these bands are still physically valid, so the filter learns from them; only the
published status stays ``dropout``. Likewise a distance up to ``range_feed_margin_m``
beyond max_range_m feeds the filter though it is not published: dropping it would
censor the noise and bias the estimate of a target just inside the limit (a target
at 8.1 m would be tracked at 7.95 m from the readings that happen to fall below 8 m).

``high_ambient`` from the lux estimate marks output ``degraded`` (not a dropout: the
estimate is usable, only noisier), entered above lux_high_ambient and left below
lux_high_ambient (1 - h). amp > 32768 is the sensor's own binary flag and has no band.
"""

from __future__ import annotations

import math


def band_edge(threshold: float, h: float) -> float:
    """``threshold * (1 + h)``, the far edge of a hysteresis band, to 12 significant
    digits: in floats 100 * 1.1 is 110.00000000000001 and 0.05 * 1.1 is
    0.05500000000000001, which kept amp 110 inside a band documented to end there."""
    return float(f"{threshold * (1.0 + h):.12g}")


def first_amp_at_least(amp_min: float, s_min: float, inv_amp_ref: float) -> int:
    """The smallest integer amp that is at least ``amp_min`` and whose S = amp *
    ``inv_amp_ref`` is at least ``s_min``.

    amp is an integer, so the two thresholds of a gate (on amp and on S) are one
    integer threshold; searched with the very float product the filter computes S
    with, so the gate decides exactly as comparing S would.
    """
    amp = max(math.ceil(amp_min), math.floor(s_min / inv_amp_ref) - 2, 0)
    while amp * inv_amp_ref < s_min:
        amp += 1
    return amp
