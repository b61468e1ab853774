"""The per-frame cleaning pipeline: hard gates only, until the adaptive filter lands."""

from __future__ import annotations

from lunad.filters.config import AMP_AMBIENT, AMP_SATURATED, FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status, Zone


class RangeFilter:
    """Turns raw readings into published estimates; pure, one call per frame."""

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = config or FilterConfig()
        self._inv_amp_ref = 1.0 / self.config.amp_ref

    def step(self, raw_m: float | None, amp: int, t_mono_ns: int) -> Estimate:
        """Clean one reading.

        Args:
            raw_m: distance the sensor reported, metres, or None when it reported none.
            amp: the sensor's signal strength.
            t_mono_ns: monotonic receive time, nanoseconds.
        """
        c = self.config
        s = amp * self._inv_amp_ref
        reasons: list[Reason] = []
        if amp == AMP_SATURATED:
            reasons.append(Reason.SATURATED)
        elif amp > AMP_AMBIENT:
            reasons.append(Reason.HIGH_AMBIENT)
        elif amp < c.amp_min or s < c.s_min:
            reasons.append(Reason.WEAK_SIGNAL)
        if raw_m is None or not c.min_range_m <= raw_m <= c.max_range_m:
            if not reasons:
                reasons.append(Reason.OUT_OF_RANGE)
        if reasons:
            return Estimate(None, None, None, s, Status.DROPOUT, tuple(reasons), Zone.UNRELIABLE)
        return Estimate(raw_m, None, None, s, Status.OK, (), Zone.STABLE)

    def reset(self) -> None:
        """Forget all state (after a reconnect)."""
