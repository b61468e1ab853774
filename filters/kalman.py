"""Constant-velocity Kalman filter with an innovation gate and step confirmation.

How this works. State (x, v): range in metres and its rate in m/s. Between frames
dt apart (white-acceleration model, spectral density qa in m^2/s^3):

    x <- x + v dt
    P <- F P F' + qa [[dt^3/3, dt^2/2], [dt^2/2, dt]]

A reading z with variance r (from the paper's noise model, eqs 2-3, see lux.py) has
innovation e = z - x and predicted variance s = P00 + r. If e^2 > g^2 s (g = 4, a
Gaussian reading fails this once in 16 000) the reading is an outlier and leaves
the state alone: an isolated multipath spike vanishes. If ``step_confirm``
consecutive outliers (at most ``RUN_GAP_MAX`` frames that do not feed the filter
between two of them) lie on the same side and agree with each other
(|z_i - z_j| within g sqrt(r_i + r_j)), the target really moved (an obstacle
stepped in): the track restarts at their mean with their variance and a zero
speed, so a step is followed after ``step_confirm - 1`` frames. Not in the paper,
which does not filter at all; its section VI recommends "dynamic SNR-based filtering".

Plain floats and __slots__: at 250 Hz on a Pi Zero 2 a 2x2 numpy filter would cost
more in call overhead than the arithmetic.
"""

from __future__ import annotations

RUN_GAP_MAX = 2
"""Frames that do not feed the filter (no distance, a weak or saturated signal) that may
sit between two outliers of one run. A marginal target, weak every other frame, still
confirms its step; two spikes 0.3 s apart, dropouts between them, are two spikes (they
once confirmed a step and a range 1.5 m off went out as ``ok``)."""

ACCEPTED = 0
OUTLIER = 1
RESTARTED = 2


class Tracker:
    """CV Kalman filter, gate and step logic; all state is public floats."""

    __slots__ = (
        "_confirm",
        "_gate2",
        "_qa",
        "_run_gap",
        "_run_last",
        "_run_n",
        "_run_r",
        "_run_rsum",
        "_run_sign",
        "_run_sum",
        "_v0var",
        "active",
        "p00",
        "p01",
        "p11",
        "v",
        "x",
    )

    def __init__(
        self,
        accel_psd: float,
        gate_sigmas: float,
        step_confirm: int,
        init_speed_sigma_m_s: float,
    ) -> None:
        self._qa = accel_psd
        self._gate2 = gate_sigmas * gate_sigmas
        self._confirm = step_confirm
        self._v0var = init_speed_sigma_m_s * init_speed_sigma_m_s
        self.reset()

    def reset(self) -> None:
        """No track."""
        self.active = False
        self.x = 0.0
        self.v = 0.0
        self.p00 = 0.0
        self.p01 = 0.0
        self.p11 = 0.0
        self._run_n = 0
        self._run_sum = 0.0
        self._run_rsum = 0.0
        self._run_last = 0.0
        self._run_r = 0.0
        self._run_sign = False
        self._run_gap = 0

    def start(self, z_m: float, r_m2: float) -> None:
        """Begin a track at reading ``z_m`` (variance ``r_m2``) with unknown speed."""
        self.active = True
        self.x = z_m
        self.v = 0.0
        self.p00 = r_m2
        self.p01 = 0.0
        self.p11 = self._v0var
        self._run_n = 0

    def skip(self) -> None:
        """A frame that does not feed the filter came: past ``RUN_GAP_MAX`` of them the
        run of outliers ends."""
        if self._run_n:
            self._run_gap += 1
            if self._run_gap > RUN_GAP_MAX:
                self._run_n = 0

    def predict(self, dt_s: float) -> None:
        """Move the state ``dt_s`` seconds ahead."""
        if dt_s <= 0.0:
            return
        p01 = self.p01
        p11 = self.p11
        q = self._qa * dt_s
        self.x += self.v * dt_s
        self.p00 += dt_s * (2.0 * p01 + dt_s * p11) + q * dt_s * dt_s * (1.0 / 3.0)
        self.p01 = p01 + dt_s * p11 + 0.5 * q * dt_s
        self.p11 = p11 + q

    def update(self, z_m: float, r_m2: float) -> int:
        """Fuse one reading; returns ACCEPTED, OUTLIER or RESTARTED."""
        p00 = self.p00
        s = p00 + r_m2
        e = z_m - self.x
        if e * e > self._gate2 * s:
            sign = e > 0.0
            d = z_m - self._run_last
            if (
                self._run_n
                and sign == self._run_sign
                and d * d <= self._gate2 * (r_m2 + self._run_r)
            ):
                self._run_n += 1
                self._run_sum += z_m
                self._run_rsum += r_m2
            else:
                self._run_n = 1
                self._run_sum = z_m
                self._run_rsum = r_m2
                self._run_sign = sign
            self._run_last = z_m
            self._run_r = r_m2
            self._run_gap = 0
            if self._run_n >= self._confirm:
                n = self._run_n
                self.start(self._run_sum / n, self._run_rsum / (n * n))
                return RESTARTED
            return OUTLIER
        self._run_n = 0
        p01 = self.p01
        k0 = p00 / s
        k1 = p01 / s
        self.x += k0 * e
        self.v += k1 * e
        self.p00 = p00 - k0 * p00
        p11 = self.p11 - k1 * p01
        if p11 < 0.0:  # rounding, when r is tiny next to P: keep P positive semi-definite
            self.p01 = self.p11 = 0.0
        else:
            self.p01 = p01 - k0 * p01
            self.p11 = p11
        return ACCEPTED
