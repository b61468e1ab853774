"""Online ambient-light estimator: L_hat from the spread of S-normalised residuals.

How this works. Paper eqs 2-3 say one reading has noise sigma = (sigma0 + k L) / S.
Write c = sigma0 + k L (the noise at S = 1, metres). The filter's innovation
e = z - x_pred has variance

    V = P_pred + c^2 / S^2 + q          (q = resolution^2 / 12, the 1 cm steps)

so each reading gives an unbiased sample of c^2:  (e^2 - P_pred - q) S^2. We average
these with an exponential window of time constant tau (0.1 s: 25 frames at 250 Hz;
after 0.5 s less than 1 % of the old level remains, and c_hat scatters by about
10 % from frame to frame, since the window holds about 50 readings), and then

    L_hat = (c_hat - sigma0) / k        (published clipped at 0)

Robustness (spikes, steps): before it enters the average, e^2 is winsorised at
(2.5^2) V_hat, using the current estimate; a multipath spike or a step then moves
c^2 by a bounded step instead of dragging it by orders of magnitude: at most
alpha (6.25 / kappa - 1), 22 % at 250 Hz, where c^2 / S^2 makes most of V_hat, and
more where P00 and q do (a strong near target, c^2 far below sigma0^2: x6.4 in one
spike); that c^2 sits far below what the zone and the ambient flag act on, and
lux_zone (tau 1 s) moves about 2 % at 30 klux. kappa = E[min(Z^2, 2.5^2)] = 0.978
removes the clipping's bias for Gaussian noise. The same clip bounds how fast c_hat
can grow when it is far too small (x1.1 per frame in c at 250 Hz), so a sudden sun
still converges in a few dozen frames. Departure from the paper: it treats L as
known; here it is inferred.

Gaps: after frames went missing, the gap's length would give the next sample a large
weight (``dt / tau``, up to 0.5), though one sample says no more after a gap than
before it: a sample of a variance scatters by 140 %, so with half the weight c^2
moved by 70 % (one standard deviation) at once. A sample weighs at most
``WEIGHT_GROWTH_MAX`` times the one before it. And when P_pred dominates V the
sample scatters with it too: such a residual is not learnt from at all
(``PRED_SKIP_RATIO``).

A sensor whose constants differ from the configured sigma0 and k (``noise_scale``)
is absorbed: the filter only ever uses c_hat, which is measured. L_hat is then biased:
with constants scaled by f, L_hat = (f - 1) sigma0 / k + f L. Internally c_hat may
go below sigma0 (a quieter sensor); only the published lux is clipped at 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lunad.filters.config import FilterConfig

C2_FLOOR_FRACTION = 0.01  # c_hat never below sigma0 / 10: keeps R positive and learnable
WEIGHT_GROWTH_MAX = 2.0
"""A sample's averaging time (``dt``) is at most this many times the previous one's
(our choice): after a 0.1 s gap at 250 Hz the next sample weighs 0.08, not 0.5, and a
change of frame rate is followed within a few frames."""
PRED_SKIP_RATIO = 2.0
"""A residual whose predicted position variance exceeds this many times the reading's
own variance (c^2 / S^2 + q) is not learnt from (our choice). Its sample of c^2 then
scatters over 9 times as much as one from a well-known position, (P + m)^2 against
m^2: clipped at 2.5 sigma of V, one such sample with P ten times m could still move
c^2 5.7-fold at the capped weight of 0.08. It happens after gaps; with the weight uncapped,
one residual after a gap put L_hat above 20 klux in a 100 lux room, or pulled c^2 to
its floor so that the filter took the readings' noise for motion. A steady stream
gets there only on a track's first frames (26 and 39 of 173108 frames of the
built-in scenarios, noise x2 and x0.5, seeds 0-4), and ``lunad eval`` prints the same
figures with and without the skip (docs/filter.md, "Gaps and stalls")."""


def lux_of(c2: float, sigma0_m: float, k_m_per_lux: float) -> float:
    """L_hat = (c_hat - sigma0) / k from c_hat^2 (m^2), in lux, clipped at 0."""
    lux = (math.sqrt(c2) - sigma0_m) / k_m_per_lux
    return lux if lux > 0.0 else 0.0


def clipped_square_mean(clip_sigmas: float) -> float:
    """E[min(Z^2, c^2)] for standard normal Z: the bias of a winsorised variance."""
    c = clip_sigmas
    inside = math.erf(c / math.sqrt(2.0))
    pdf = math.exp(-0.5 * c * c) / math.sqrt(2.0 * math.pi)
    return inside - 2.0 * c * pdf + c * c * (1.0 - inside)


@dataclass(frozen=True, slots=True)
class LuxConstants:
    """What the estimator derives from its configuration once; shared with the flat
    ``RangeFilter``, which copies these into its own slots.

    Attributes:
        clip2: square of the winsorising bound, in innovation variances.
        inv_kappa: 1 / E[min(Z^2, clip^2)], the clipping's bias correction.
        c2_init: starting c^2, m^2 (the configured ``lux_init``).
        lux_init: the lux that ``c2_init`` reads as.
        c2_floor: lowest c^2, m^2 (``C2_FLOOR_FRACTION`` sigma0^2).
    """

    clip2: float
    inv_kappa: float
    c2_init: float
    lux_init: float
    c2_floor: float

    @classmethod
    def of(cls, config: FilterConfig) -> LuxConstants:
        """The constants for ``config``."""
        c_init = config.sigma0_m + config.k_m_per_lux * config.lux_init
        c2_init = c_init * c_init
        return cls(
            clip2=config.lux_clip_sigmas * config.lux_clip_sigmas,
            inv_kappa=1.0 / clipped_square_mean(config.lux_clip_sigmas),
            c2_init=c2_init,
            lux_init=lux_of(c2_init, config.sigma0_m, config.k_m_per_lux),
            c2_floor=C2_FLOOR_FRACTION * config.sigma0_m * config.sigma0_m,
        )


class LuxEstimator:
    """Tracks c = sigma0 + k L from innovations; reports L_hat in lux.

    Attributes:
        c2: estimated c^2, m^2 (c: noise at S = 1, unclipped; may be below sigma0^2).
        c2_zone: the same averaged over ``lux_zone_tau_s``.
        lux: ambient light estimate, lux, clipped at 0 (time constant ``lux_tau_s``).
            On a strong return (S near 1) ambient light adds little to the noise, so
            this spreads by several klux from frame to frame even indoors; see
            ``lux_zone``.
        lux_zone: the same from ``c2_zone``, lux: what the zone and the
            ``high_ambient`` decision use, so that they do not flap on sampling noise.
    """

    __slots__ = (
        "_c2_floor",
        "_c2_init",
        "_clip2",
        "_dt_last",
        "_inv_kappa",
        "_k",
        "_lux_init",
        "_sigma0",
        "_tau_s",
        "_tau_zone_s",
        "c2",
        "c2_zone",
        "lux",
        "lux_zone",
    )

    def __init__(self, config: FilterConfig) -> None:
        self._sigma0 = config.sigma0_m
        self._k = config.k_m_per_lux
        self._tau_s = config.lux_tau_s
        self._tau_zone_s = config.lux_zone_tau_s
        derived = LuxConstants.of(config)
        self._clip2 = derived.clip2
        self._inv_kappa = derived.inv_kappa
        self._c2_init = derived.c2_init
        self._lux_init = derived.lux_init
        self._c2_floor = derived.c2_floor
        self.reset()

    def reset(self) -> None:
        """Back to the configured initial light level."""
        self.c2 = self.c2_zone = self._c2_init
        self.lux = self.lux_zone = self._lux_init
        self._dt_last = math.inf
        """The averaging time of the last sample learnt from, seconds."""

    @property
    def c_m(self) -> float:
        """Estimated noise at S = 1, metres (sigma0 + k L_hat, unclipped)."""
        return math.sqrt(self.c2)

    def update(self, innov_m: float, p_pred_m2: float, s: float, q_m2: float, dt_s: float) -> None:
        """Learn from one innovation.

        Args:
            innov_m: z - x_pred, metres.
            p_pred_m2: predicted variance of the state's position, m^2.
            s: strength S of the reading.
            q_m2: variance of the quantisation, m^2.
            dt_s: time since the previous frame, seconds (sets the averaging weight,
                up to ``WEIGHT_GROWTH_MAX`` times the previous sample's).

        Skipped when ``dt_s`` is not positive (no time to average over) and when the
        prediction is too uncertain to tell noise from its own error
        (``PRED_SKIP_RATIO``: after a gap in the frames, or a track's first frame).
        """
        if dt_s <= 0.0:
            return
        s2 = s * s
        c2 = self.c2
        if p_pred_m2 > PRED_SKIP_RATIO * (c2 / s2 + q_m2):
            return
        v = p_pred_m2 + c2 / s2 + q_m2
        e2 = innov_m * innov_m
        lim = self._clip2 * v
        if e2 > lim:
            e2 = lim
        sample = (e2 * self._inv_kappa - p_pred_m2 - q_m2) * s2
        dt_max = WEIGHT_GROWTH_MAX * self._dt_last
        if dt_s > dt_max:
            dt_s = dt_max
        self._dt_last = dt_s
        a = dt_s / self._tau_s
        c2 += (a if a < 0.5 else 0.5) * (sample - c2)
        if c2 < self._c2_floor:
            c2 = self._c2_floor
        self.c2 = c2
        lux = (math.sqrt(c2) - self._sigma0) / self._k
        self.lux = lux if lux > 0.0 else 0.0
        c2 = self.c2_zone
        a = dt_s / self._tau_zone_s
        c2 += (a if a < 0.5 else 0.5) * (sample - c2)
        if c2 < self._c2_floor:
            c2 = self._c2_floor
        self.c2_zone = c2
        lux = (math.sqrt(c2) - self._sigma0) / self._k
        self.lux_zone = lux if lux > 0.0 else 0.0
