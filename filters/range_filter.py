"""The per-frame cleaning pipeline the daemon runs, as one flat function.

It computes exactly what ``ReferenceFilter`` (reference.py) computes from the
documented pieces: the gates with hysteresis (policy.py), the constant-velocity
Kalman filter with its innovation gate and step confirmation (kalman.py) and the lux
estimator (lux.py) are inlined; the zone is zone.py's own ``ZoneClassifier``. Read
those modules for the model and the paper's equations. tests/test_filters_equivalence.py
checks that both filters give equal estimates, float for float, on every built-in
scenario at three noise scales, in all three noise modes, and on arbitrary streams.

Why flat: every frame pays for this at 250 Hz, and a call per piece plus the hops
between five objects cost about an eighth of it. One function holding the state on one
object took 0.84-0.90x the time of the composed form (three scenarios, two runs;
``lunad bench`` prints the ratio, line "filter composed from its pieces";
docs/performance.md, "Session 4").
"""

from __future__ import annotations

from math import sqrt

from lunad.filters.config import AMP_AMBIENT, AMP_SATURATED, FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status, Zone
from lunad.filters.kalman import RUN_GAP_MAX
from lunad.filters.lux import PRED_SKIP_RATIO, WEIGHT_GROWTH_MAX, LuxConstants
from lunad.filters.policy import band_edge, first_amp_at_least
from lunad.filters.zone import ZoneClassifier

_SATURATED = (Reason.SATURATED,)
_AMBIENT = (Reason.HIGH_AMBIENT,)
_WEAK = (Reason.WEAK_SIGNAL,)
_OUT = (Reason.OUT_OF_RANGE,)
_WEAK_OUT = (Reason.WEAK_SIGNAL, Reason.OUT_OF_RANGE)
_OUTLIER = (Reason.OUTLIER,)
_OUTLIER_AMBIENT = (Reason.OUTLIER, Reason.HIGH_AMBIENT)
_NONE: tuple[Reason, ...] = ()
_STALE = (Reason.STALE,)
_OK = Status.OK
_DEGRADED = Status.DEGRADED
_DROPOUT = Status.DROPOUT
_UNRELIABLE = Zone.UNRELIABLE
_new = tuple.__new__
"""Builds an ``Estimate`` from a tuple without the ``NamedTuple``'s generated Python
``__new__``: one C call instead of a Python frame, on every frame."""


class RangeFilter:
    """Turns raw readings into published estimates; pure, one call per frame.

    Not thread-safe: one instance per sensor, called from the read loop. The state
    has the names of the pieces it comes from (``x``, ``p00``: kalman.py; ``c2``,
    ``lux``: lux.py; ``weak``: policy.py); the zone keeps its ``ZoneClassifier``, one
    call a published frame either way.
    """

    __slots__ = (
        "_amp_strong",
        "_amp_strong_again",
        "_c2_floor",
        "_c2_init",
        "_clip2",
        "_confirm",
        "_floor",
        "_gate2",
        "_have_lux",
        "_inv_amp_ref",
        "_inv_kappa",
        "_k",
        "_last_accept_ns",
        "_last_t_ns",
        "_lux_dt",
        "_lux_enter",
        "_lux_exit",
        "_lux_init",
        "_max_feed",
        "_max_in",
        "_max_m",
        "_min_in",
        "_min_m",
        "_q_m2",
        "_qa",
        "_run_gap",
        "_run_last",
        "_run_n",
        "_run_r",
        "_run_rsum",
        "_run_sign",
        "_run_sum",
        "_sigma0",
        "_stale_ns",
        "_tau_s",
        "_tau_zone_s",
        "_v0var",
        "active",
        "ambient",
        "c2",
        "c2_zone",
        "config",
        "lux",
        "lux_zone",
        "out_of_range",
        "p00",
        "p01",
        "p11",
        "v",
        "weak",
        "x",
        "zones",
    )

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = c = config or FilterConfig()
        h = c.hysteresis
        self._inv_amp_ref = inv_amp_ref = 1.0 / c.amp_ref
        self._q_m2 = c.resolution_m * c.resolution_m / 12.0
        self._stale_ns = round(c.stale_after_s * 1e9)
        self._floor = c.sigma_floor_m
        self._min_m = c.min_range_m
        self._max_m = c.max_range_m
        # policy.py
        self._amp_strong = first_amp_at_least(c.amp_min, c.s_min, inv_amp_ref)
        self._amp_strong_again = first_amp_at_least(
            band_edge(c.amp_min, h), band_edge(c.s_min, h), inv_amp_ref
        )
        self._min_in = c.min_range_m + c.range_hysteresis_m
        self._max_in = c.max_range_m - c.range_hysteresis_m
        self._max_feed = c.max_range_m + c.range_feed_margin_m
        self._lux_enter = c.lux_high_ambient
        self._lux_exit = c.lux_high_ambient * (1.0 - h)
        # kalman.py
        self._qa = c.accel_psd
        self._gate2 = c.gate_sigmas * c.gate_sigmas
        self._confirm = c.step_confirm
        self._v0var = c.init_speed_sigma_m_s * c.init_speed_sigma_m_s
        # lux.py
        self._sigma0 = c.sigma0_m
        self._k = c.k_m_per_lux
        self._tau_s = c.lux_tau_s
        self._tau_zone_s = c.lux_zone_tau_s
        lux = LuxConstants.of(c)
        self._clip2 = lux.clip2
        self._inv_kappa = lux.inv_kappa
        self._c2_init = lux.c2_init
        self._lux_init = lux.lux_init
        self._c2_floor = lux.c2_floor
        self.zones = ZoneClassifier(c)
        self.reset()

    def reset(self) -> None:
        """Forget all state (after a reconnect)."""
        self.weak = self.out_of_range = self.ambient = False
        self.active = False
        self.x = self.v = self.p00 = self.p01 = self.p11 = 0.0
        self._run_n = 0
        self._run_sum = self._run_rsum = self._run_last = self._run_r = 0.0
        self._run_sign = False
        self._run_gap = 0
        self.c2 = self.c2_zone = self._c2_init
        self.lux = self.lux_zone = self._lux_init
        self._lux_dt = float("inf")
        self.zones.reset()
        self._last_t_ns: int | None = None
        self._last_accept_ns = 0
        self._have_lux = False

    def step_known_sigma(
        self, raw_m: float | None, amp: int, t_mono_ns: int, sigma_m: float
    ) -> Estimate:
        """Like :meth:`step`, with the reading's noise given instead of estimated.

        For baselines (a fixed-noise filter, an oracle that knows the simulator's
        true per-reading sigma): the same gates, Kalman filter and step logic, only
        the measurement variance differs. ``sigma_m`` excludes the quantisation,
        which is added as in :meth:`step`. The lux estimator is not updated.

        Raises:
            ValueError: ``sigma_m`` is not above 0 (``step`` reads 0 as "estimate it").
        """
        if not sigma_m > 0.0:
            raise ValueError(f"sigma_m must be above 0 metres, got {sigma_m!r}")
        return self.step(raw_m, amp, t_mono_ns, sigma_m)

    def step(
        self, raw_m: float | None, amp: int, t_mono_ns: int, sigma_known: float = 0.0
    ) -> Estimate:
        """Clean one reading.

        Args:
            raw_m: distance the sensor reported, metres, or None when it reported none.
            amp: the sensor's signal strength.
            t_mono_ns: monotonic receive time, nanoseconds.
            sigma_known: leave at 0 (the noise is estimated); see ``step_known_sigma``.

        Returns:
            The estimate to publish for this frame.
        """
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

        # Gates with hysteresis (policy.py: DropoutPolicy.gate).
        z: float | None = None  # the reading, when it may feed the filter
        reasons: tuple[Reason, ...]
        if amp > AMP_AMBIENT:
            reasons = _SATURATED if amp == AMP_SATURATED else _AMBIENT
        else:
            weak = amp < (self._amp_strong_again if self.weak else self._amp_strong)
            self.weak = weak
            if raw_m is None:
                reasons = _WEAK if weak else _OUT
            else:
                if self.out_of_range:
                    out = raw_m < self._min_in or raw_m > self._max_in
                else:
                    out = raw_m < self._min_m or raw_m > self._max_m
                self.out_of_range = out
                if amp >= self._amp_strong and self._min_m <= raw_m <= self._max_feed:
                    z = raw_m
                if weak:
                    reasons = _WEAK_OUT if out else _WEAK
                else:
                    reasons = _OUT if out else _NONE

        outlier = False
        active = self.active
        if z is not None:
            q = self._q_m2
            c2 = self.c2
            r = (sigma_known * sigma_known if sigma_known > 0.0 else c2 / (s * s)) + q
            if active and t - self._last_accept_ns <= self._stale_ns:
                # Predict (kalman.py: Tracker.predict).
                x = self.x
                p00 = self.p00
                if dt > 0.0:
                    p01 = self.p01
                    p11 = self.p11
                    qd = self._qa * dt
                    x += self.v * dt
                    p00 += dt * (2.0 * p01 + dt * p11) + qd * dt * dt * (1.0 / 3.0)
                    self.p01 = p01 + dt * p11 + 0.5 * qd * dt
                    self.p11 = p11 + qd
                e = z - x
                # Lux estimate (lux.py: LuxEstimator.update).
                if sigma_known <= 0.0:
                    if dt > 0.0 and p00 <= PRED_SKIP_RATIO * r:
                        s2 = s * s
                        e2 = e * e
                        lim = self._clip2 * (p00 + c2 / s2 + q)
                        if e2 > lim:
                            e2 = lim
                        sample = (e2 * self._inv_kappa - p00 - q) * s2
                        c2_floor = self._c2_floor
                        w = WEIGHT_GROWTH_MAX * self._lux_dt
                        if dt < w:
                            w = dt
                        self._lux_dt = w
                        a = w / self._tau_s
                        c2 += (a if a < 0.5 else 0.5) * (sample - c2)
                        if c2 < c2_floor:
                            c2 = c2_floor
                        self.c2 = c2
                        lux = (sqrt(c2) - self._sigma0) / self._k
                        self.lux = lux if lux > 0.0 else 0.0
                        c2 = self.c2_zone
                        a = w / self._tau_zone_s
                        c2 += (a if a < 0.5 else 0.5) * (sample - c2)
                        if c2 < c2_floor:
                            c2 = c2_floor
                        self.c2_zone = c2
                        lux = (sqrt(c2) - self._sigma0) / self._k
                        self.lux_zone = lux if lux > 0.0 else 0.0
                    self._have_lux = True
                # Update, gate and step confirmation (kalman.py: Tracker.update).
                sp = p00 + r
                gate2 = self._gate2
                if e * e > gate2 * sp:
                    sign = e > 0.0
                    d = z - self._run_last
                    n = self._run_n
                    if n and sign == self._run_sign and d * d <= gate2 * (r + self._run_r):
                        n += 1
                        self._run_sum += z
                        self._run_rsum += r
                    else:
                        n = 1
                        self._run_sum = z
                        self._run_rsum = r
                        self._run_sign = sign
                    self._run_last = z
                    self._run_r = r
                    self._run_gap = 0
                    if n >= self._confirm:
                        self._start(self._run_sum / n, self._run_rsum / (n * n))
                        self._last_accept_ns = t
                    else:
                        self._run_n = n
                        self.x = x
                        self.p00 = p00
                        outlier = True
                else:
                    self._run_n = 0
                    p01 = self.p01
                    k0 = p00 / sp
                    k1 = p01 / sp
                    self.x = x + k0 * e
                    self.v += k1 * e
                    self.p00 = p00 - k0 * p00
                    p11 = self.p11 - k1 * p01
                    if p11 < 0.0:  # kalman.py: Tracker.update
                        self.p01 = self.p11 = 0.0
                    else:
                        self.p01 = p01 - k0 * p01
                        self.p11 = p11
                    self._last_accept_ns = t
            else:
                self._start(z, r)
                self._last_accept_ns = t
        elif active:
            if self._run_n:  # kalman.py: Tracker.skip
                gap = self._run_gap + 1
                self._run_gap = gap
                if gap > RUN_GAP_MAX:
                    self._run_n = 0
            if dt > 0.0:
                self._predict(dt)

        # Publish or not (ReferenceFilter.step), ambient flag and zone.
        if not reasons and self.active:
            x = self.x
            if self._min_m <= x <= self._max_m:
                sigma = sqrt(self.p00)
                if sigma < self._floor:
                    sigma = self._floor
                if self._have_lux:
                    lux_out: float | None = self.lux
                    lux_zone = self.lux_zone
                    if self.ambient:
                        ambient = self.ambient = lux_zone > self._lux_exit
                    else:
                        ambient = self.ambient = lux_zone > self._lux_enter
                else:
                    lux_out = None
                    lux_zone = 0.0
                    ambient = False
                zone = self.zones.classify(lux_zone, s, sigma)
                if outlier:
                    reasons = _OUTLIER_AMBIENT if ambient else _OUTLIER
                elif ambient:
                    reasons = _AMBIENT
                else:
                    return _new(Estimate, (x, sigma, lux_out, s, _OK, _NONE, zone))
                return _new(Estimate, (x, sigma, lux_out, s, _DEGRADED, reasons, zone))
            reasons = _OUT
        self.zones.zone = _UNRELIABLE
        if t - self._last_accept_ns > self._stale_ns:
            reasons = (*reasons, Reason.STALE) if reasons else _STALE
        lux_out = self.lux if self._have_lux else None
        return _new(Estimate, (None, None, lux_out, s, _DROPOUT, reasons, _UNRELIABLE))

    def _start(self, z_m: float, r_m2: float) -> None:
        """Begin a track at ``z_m`` (variance ``r_m2``) with unknown speed (Tracker.start)."""
        self.active = True
        self.x = z_m
        self.v = 0.0
        self.p00 = r_m2
        self.p01 = 0.0
        self.p11 = self._v0var
        self._run_n = 0

    def _predict(self, dt_s: float) -> None:
        """Move the state ``dt_s`` (> 0) seconds ahead without a reading (Tracker.predict)."""
        p01 = self.p01
        p11 = self.p11
        q = self._qa * dt_s
        self.x += self.v * dt_s
        self.p00 += dt_s * (2.0 * p01 + dt_s * p11) + q * dt_s * dt_s * (1.0 / 3.0)
        self.p01 = p01 + dt_s * p11 + 0.5 * q * dt_s
        self.p11 = p11 + q
