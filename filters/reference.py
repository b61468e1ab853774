"""The cleaning pipeline composed from its documented pieces: the filter's specification.

``RangeFilter`` (range_filter.py), which the daemon and ``lunad eval`` run, does the
same computation in one flat function; tests/test_filters_equivalence.py checks
that both give equal estimates, float for float, over every scenario. This one is
the readable form: change the filter here and in the pieces first, then make
``RangeFilter`` agree. ``lunad bench`` reports what each costs per frame.

How this works, per frame (DESIGN.md "Data flow of one reading"):

1. S = amp / amp_ref (paper eq. 1, with amp_ref from calibration).
2. Hard gates with hysteresis (policy.py) -> ``dropout``. A reading inside a
   hysteresis band, or a little beyond the range, is still fed to the filter, only
   not published; an estimate outside the range is not published either.
3. Constant-velocity Kalman filter (kalman.py). Each reading's variance is
   r = ((sigma0 + k L_hat) / S)^2 + resolution^2 / 12: the paper's eqs 2-3 with
   the lux estimate in place of the unknown L, plus the 1 cm quantisation
   (our addition; it dominates at high S). The innovation gate marks isolated
   spikes ``outlier``: the frame publishes the prediction, ``degraded``.
4. Lux estimator (lux.py) learns sigma0 + k L from the same innovations.
5. ``stale`` when no reading has been accepted for ``stale_after_s``; the next
   accepted reading then restarts the track.
6. Zone (zone.py) from L_hat, S and the published sigma.

The published sigma is sqrt(P00), floored at ``sigma_floor_m`` (the 1 cm output
steps leave a bias that averaging cannot remove).
"""

from __future__ import annotations

from math import sqrt

from lunad.filters.config import FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status
from lunad.filters.kalman import OUTLIER, Tracker
from lunad.filters.lux import LuxEstimator
from lunad.filters.policy import DropoutPolicy
from lunad.filters.zone import ZoneClassifier

_OUTLIER = (Reason.OUTLIER,)
_OUTLIER_AMBIENT = (Reason.OUTLIER, Reason.HIGH_AMBIENT)
_AMBIENT = (Reason.HIGH_AMBIENT,)
_NONE: tuple[Reason, ...] = ()
_STALE = (Reason.STALE,)
_OUT_OF_RANGE = (Reason.OUT_OF_RANGE,)
_OK = Status.OK
_DEGRADED = Status.DEGRADED
_DROPOUT = Status.DROPOUT
_new = tuple.__new__
"""Builds an ``Estimate`` from a tuple without the ``NamedTuple``'s generated Python
``__new__``: one C call instead of a Python frame, on every frame."""


class ReferenceFilter:
    """Turns raw readings into estimates, one method call per piece; pure.

    Same interface and results as ``RangeFilter``. Not thread-safe.
    """

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = c = config or FilterConfig()
        self._inv_amp_ref = 1.0 / c.amp_ref
        self._q_m2 = c.resolution_m * c.resolution_m / 12.0
        self._stale_ns = round(c.stale_after_s * 1e9)
        self._floor = c.sigma_floor_m
        self._min_m = c.min_range_m
        self._max_m = c.max_range_m
        self.policy = DropoutPolicy(c)
        self.tracker = Tracker(c.accel_psd, c.gate_sigmas, c.step_confirm, c.init_speed_sigma_m_s)
        self.lux = LuxEstimator(c)
        self.zones = ZoneClassifier(c)
        self._last_t_ns: int | None = None
        self._last_accept_ns = 0
        self._have_lux = False

    def reset(self) -> None:
        """Forget all state (after a reconnect)."""
        self.policy.reset()
        self.tracker.reset()
        self.lux.reset()
        self.zones.reset()
        self._last_t_ns = None
        self._last_accept_ns = 0
        self._have_lux = False

    def step_known_sigma(
        self, raw_m: float | None, amp: int, t_mono_ns: int, sigma_m: float
    ) -> Estimate:
        """As ``RangeFilter.step_known_sigma``: the reading's noise given, not estimated."""
        if not sigma_m > 0.0:
            raise ValueError(f"sigma_m must be above 0 metres, got {sigma_m!r}")
        return self.step(raw_m, amp, t_mono_ns, sigma_m)

    def step(
        self, raw_m: float | None, amp: int, t_mono_ns: int, sigma_known: float = 0.0
    ) -> Estimate:
        """Clean one reading; arguments (metres, amp, nanoseconds) and result as
        ``RangeFilter.step``."""
        t = t_mono_ns
        s = amp * self._inv_amp_ref
        last = self._last_t_ns
        if last is None:
            self._last_t_ns = self._last_accept_ns = t
            dt = 0.0
        elif t >= last:
            self._last_t_ns = t
            dt = (t - last) * 1e-9
        elif last - t > self._stale_ns:  # a clock started again: a recording across a
            self.reset()  # reboot; start afresh, as the daemon did after it
            self._last_t_ns = self._last_accept_ns = t
            dt = 0.0
        else:  # stamped before the last frame: taken as at its time, not counted twice
            t = last
            dt = 0.0
        pol = self.policy
        tr = self.tracker
        reasons = pol.gate(raw_m, amp)
        outlier = False
        if pol.usable and raw_m is not None:
            q = self._q_m2
            r = (sigma_known * sigma_known if sigma_known > 0.0 else self.lux.c2 / (s * s)) + q
            if tr.active and t - self._last_accept_ns <= self._stale_ns:
                tr.predict(dt)
                if sigma_known <= 0.0:
                    self.lux.update(raw_m - tr.x, tr.p00, s, q, dt)
                    self._have_lux = True
                outlier = tr.update(raw_m, r) == OUTLIER
            else:
                tr.start(raw_m, r)
            if not outlier:
                self._last_accept_ns = t
        elif tr.active:
            tr.predict(dt)
            tr.skip()
        if not reasons and tr.active:
            x = tr.x
            if self._min_m <= x <= self._max_m:
                sigma = sqrt(tr.p00)
                if sigma < self._floor:
                    sigma = self._floor
                if self._have_lux:
                    lux_est = self.lux
                    lux: float | None = lux_est.lux
                    lux_zone = lux_est.lux_zone
                    ambient = pol.high_ambient(lux_zone)
                else:
                    lux = None
                    lux_zone = 0.0
                    ambient = False
                zone = self.zones.classify(lux_zone, s, sigma)
                if outlier:
                    reasons = _OUTLIER_AMBIENT if ambient else _OUTLIER
                elif ambient:
                    reasons = _AMBIENT
                else:
                    return _new(Estimate, (x, sigma, lux, s, _OK, _NONE, zone))
                return _new(Estimate, (x, sigma, lux, s, _DEGRADED, reasons, zone))
            reasons = _OUT_OF_RANGE
        lux = self.lux.lux if self._have_lux else None
        if t - self._last_accept_ns > self._stale_ns:
            reasons = (*reasons, Reason.STALE) if reasons else _STALE
        return _new(Estimate, (None, None, lux, s, _DROPOUT, reasons, self.zones.dropout()))
