"""Dropout policy: hard gates with hysteresis, the ambient flag, staleness.

How this works. One reading is a dropout when any of these holds (DESIGN.md data
flow; TFLUNA.md section 4; paper section III):

    amp == 0xFFFF                      saturated     (M05 p.14)
    amp >  32768                       high_ambient  (M05 p.14: ambient overexposure)
    amp <  amp_min  or  S < S_min      weak_signal   (M05 p.16; paper S_min = 0.05)
    distance none or outside [0.2, 8]  out_of_range  (M05 p.10; paper section III)

Hysteresis (our addition; the paper has sharp thresholds): once a reading was weak,
the next ones stay weak until amp >= amp_min (1 + h) and S >= S_min (1 + h); once
out of range, until the distance is range_hysteresis_m inside the gate. Readings in
these bands are still physically valid, so the filter may learn from them; only
the published status stays ``dropout``. Likewise a distance up to
``range_feed_margin_m`` beyond max_range_m is fed to the filter though not
published: dropping it would censor the noise and bias the estimate of a target
just inside the limit (a target at 8.1 m would be tracked at 7.95 m from the
readings that happen to fall below 8 m). That keeps a target hovering at a threshold
from flapping between ok and dropout every other frame.

``high_ambient`` from the lux estimate marks output ``degraded`` (not a dropout:
the estimate is usable, only noisier), entered above lux_high_ambient and left
below lux_high_ambient (1 - h). amp > 32768 is the sensor's own binary flag and
has no band.
"""

from __future__ import annotations

import math

from lunad.filters.config import AMP_AMBIENT, AMP_SATURATED, FilterConfig
from lunad.filters.estimate import Reason

NO_REASONS: tuple[Reason, ...] = ()
_SATURATED = (Reason.SATURATED,)
_AMBIENT = (Reason.HIGH_AMBIENT,)
_WEAK = (Reason.WEAK_SIGNAL,)
_OUT = (Reason.OUT_OF_RANGE,)
_WEAK_OUT = (Reason.WEAK_SIGNAL, Reason.OUT_OF_RANGE)


class DropoutPolicy:
    """Hard gates with hysteresis; one call per frame, state on the object.

    After :meth:`gate`, :attr:`usable` says whether the reading may feed the filter
    (it passes the gates without their hysteresis bands).
    """

    __slots__ = (
        "_amp_strong",
        "_amp_strong_again",
        "_lux_enter",
        "_lux_exit",
        "_max_feed",
        "_max_in",
        "_max_m",
        "_min_in",
        "_min_m",
        "ambient",
        "out_of_range",
        "usable",
        "weak",
    )

    def __init__(self, config: FilterConfig) -> None:
        h = config.hysteresis
        inv_amp_ref = 1.0 / config.amp_ref
        self._amp_strong = first_amp_at_least(config.amp_min, config.s_min, inv_amp_ref)
        self._amp_strong_again = first_amp_at_least(
            band_edge(config.amp_min, h), band_edge(config.s_min, h), inv_amp_ref
        )
        self._min_m = config.min_range_m
        self._max_m = config.max_range_m
        self._min_in = config.min_range_m + config.range_hysteresis_m
        self._max_in = config.max_range_m - config.range_hysteresis_m
        self._max_feed = config.max_range_m + config.range_feed_margin_m
        self._lux_enter = config.lux_high_ambient
        self._lux_exit = config.lux_high_ambient * (1.0 - h)
        self.reset()

    def reset(self) -> None:
        """Forget the latched states."""
        self.weak = False
        self.out_of_range = False
        self.ambient = False
        self.usable = False

    def gate(self, raw_m: float | None, amp: int) -> tuple[Reason, ...]:
        """Reasons this reading is a dropout (empty tuple: publish it).

        Args:
            raw_m: reported distance, metres, or None when the sensor reported none.
            amp: reported signal strength (its S = amp / amp_ref is checked through
                the integer thresholds worked out once in ``__init__``).
        """
        if amp > AMP_AMBIENT:
            self.usable = False
            return _SATURATED if amp == AMP_SATURATED else _AMBIENT
        weak = amp < (self._amp_strong_again if self.weak else self._amp_strong)
        self.weak = weak
        if raw_m is None:
            self.usable = False
            return _WEAK if weak else _OUT
        if self.out_of_range:
            out = raw_m < self._min_in or raw_m > self._max_in
        else:
            out = raw_m < self._min_m or raw_m > self._max_m
        self.out_of_range = out
        self.usable = amp >= self._amp_strong and self._min_m <= raw_m <= self._max_feed
        if weak:
            return _WEAK_OUT if out else _WEAK
        return _OUT if out else NO_REASONS

    def high_ambient(self, lux: float) -> bool:
        """Whether the lux estimate says ambient light is high, with hysteresis."""
        if self.ambient:
            self.ambient = lux > self._lux_exit
        else:
            self.ambient = lux > self._lux_enter
        return self.ambient


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
