"""Operating zone: stable / marginal / unreliable, with hysteresis.

How this works. The paper (section IV.D, section V, Table I) finds sub-centimetre,
dropout-free operation for lux < 10 klux, R > 0.5 and incidence < 45 deg, and severe
degradation past 50 klux or on dark, oblique targets. We cannot observe R and the
angle separately, only their product in S = R cos(theta) (paper eq. 1; S = 1 at the
calibration distance), so the zone uses the three things the filter knows:

    stable      L_hat < 10 klux  and  S >= 0.35  and  sigma <= 2 cm
    unreliable  L_hat > 50 klux  or   S <  0.10  or   sigma > 10 cm   (or no estimate)
    marginal    otherwise

0.35 is R cos(theta) at the corner of the paper's region (0.5 cos 45 deg). Departure:
our S also falls with distance squared (amp does), so a white target far away counts
as a dark one, which matches its noise. Hysteresis: a zone is left only when the
values are beyond its thresholds by the relative band ``zone_hysteresis``.
"""

from __future__ import annotations

from dataclasses import dataclass

from lunad.filters.config import FilterConfig
from lunad.filters.estimate import Zone

_STABLE = Zone.STABLE
_MARGINAL = Zone.MARGINAL
_UNRELIABLE = Zone.UNRELIABLE


@dataclass(frozen=True, slots=True)
class ZoneLimits:
    """The thresholds of the zones and of their hysteresis bands (lux, S, metres).

    ``*_stay`` keep a ``stable`` zone, ``*_leave`` let an ``unreliable`` one go; both
    are the plain thresholds moved outward by ``zone_hysteresis``. ``RangeFilter.step``
    applies them inline, as :meth:`ZoneClassifier.classify` does.
    """

    lux_stable: float
    s_stable: float
    sig_stable: float
    lux_stable_stay: float
    s_stable_stay: float
    sig_stable_stay: float
    lux_unrel: float
    s_unrel: float
    sig_unrel: float
    lux_unrel_leave: float
    s_unrel_leave: float
    sig_unrel_leave: float

    @classmethod
    def from_config(cls, config: FilterConfig) -> ZoneLimits:
        """The limits ``config`` sets."""
        up = 1.0 + config.zone_hysteresis
        down = 1.0 - config.zone_hysteresis
        return cls(
            lux_stable=config.lux_stable_max,
            s_stable=config.s_stable_min,
            sig_stable=config.sigma_stable_max_m,
            lux_stable_stay=config.lux_stable_max * up,
            s_stable_stay=config.s_stable_min * down,
            sig_stable_stay=config.sigma_stable_max_m * up,
            lux_unrel=config.lux_unreliable,
            s_unrel=config.s_unreliable,
            sig_unrel=config.sigma_unreliable_m,
            lux_unrel_leave=config.lux_unreliable * down,
            s_unrel_leave=config.s_unreliable * up,
            sig_unrel_leave=config.sigma_unreliable_m * down,
        )


class ZoneClassifier:
    """Classifies each estimate; remembers the last zone for hysteresis."""

    __slots__ = ("limits", "zone")

    def __init__(self, config: FilterConfig) -> None:
        self.limits = ZoneLimits.from_config(config)
        self.zone = _UNRELIABLE

    def reset(self) -> None:
        """Start from ``unreliable``: nothing is known yet."""
        self.zone = _UNRELIABLE

    def classify(self, lux: float, s: float, sigma_m: float) -> Zone:
        """Zone of one estimate.

        Args:
            lux: ambient light estimate, lux.
            s: strength S = amp / amp_ref.
            sigma_m: one-sigma uncertainty of the estimate, metres.
        """
        lim = self.limits
        prev = self.zone
        if prev is _UNRELIABLE:
            if not (
                lux < lim.lux_unrel_leave
                and s >= lim.s_unrel_leave
                and sigma_m <= lim.sig_unrel_leave
            ):
                return _UNRELIABLE
        elif lux > lim.lux_unrel or s < lim.s_unrel or sigma_m > lim.sig_unrel:
            self.zone = _UNRELIABLE
            return _UNRELIABLE
        if prev is _STABLE:
            stable = (
                lux < lim.lux_stable_stay
                and s >= lim.s_stable_stay
                and sigma_m <= lim.sig_stable_stay
            )
        else:
            stable = lux < lim.lux_stable and s >= lim.s_stable and sigma_m <= lim.sig_stable
        zone = _STABLE if stable else _MARGINAL
        self.zone = zone
        return zone

    def dropout(self) -> Zone:
        """Zone of a frame without an estimate (always unreliable)."""
        self.zone = _UNRELIABLE
        return _UNRELIABLE
