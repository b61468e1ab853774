"""An independent reference filter for ``lunad eval``: a textbook Kalman filter told the truth.

What it is. A constant-velocity Kalman filter on the range, state (x, v) in metres and
metres per second, written from the textbook white-noise-acceleration model (Bar-Shalom,
Li and Kirubarajan, "Estimation with Applications to Tracking and Navigation", Wiley
2001, ch. 6, the continuous white noise acceleration model) and nothing else:

    predict   F = [[1, dt], [0, 1]]
              Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]      q: accel PSD, m^2/s^3
    measure   z = x + w,   R = sigma^2 + (0.01 m)^2 / 12  true sigma plus 1 cm quantisation
    gate      |z - x| > g sqrt(P00 + R)  ->  reading rejected (predict only)
    restart   after ``reset_after`` rejected readings in a row: x = z, v = 0,
              P = diag(R, (1 m/s)^2) at the latest rejected reading

A reading counts as missing (predict only) when the sensor's own validity rule says so
(amp below 100 or above 32768, docs/tfluna.md section 4) or the distance is outside
[0.2, 9.0] m. From the first accepted reading on, every frame publishes x and sqrt(P00)
(the prediction on a missing or rejected reading); ``max_coast_s`` optionally ends a
track that has gone that long without an accepted reading.

Why it is independent. lunad's filter (``lunad.filters``) must not judge itself: this
module shares no code, constant or noise law with it and never imports it. It does not
estimate the noise from amp or ambient light at all; it is *told* each reading's true
one-sigma noise (``RawReading.sigma_m``), which only a simulator knows.

What it is told that lunad is not: the true per-reading sigma, and, through
:func:`tuned_oracle`, the process noise q that was best in hindsight for the very run
it is scored on (chosen from :data:`Q_GRID_M2_S3` by the caller's score against the
truth). It is an optimistic bound, not a competitor: a fair filter should come close to
it, not beat it.

Plain Python floats on the per-reading path, as everywhere in lunad (docs/architecture.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from lunad.sim.physics import AMP_AMBIENT, AMP_WEAK, DIST_MAX_CM

RESOLUTION_M = 0.01  # output step of the default 9-byte/cm frame, DS p.2 (docs/tfluna.md section 5)
QUANT_VAR_M2 = RESOLUTION_M * RESOLUTION_M / 12.0
"""Variance of rounding to whole centimetres, m^2 (uniform error over one step)."""

RANGE_MIN_M = 0.2  # blind zone, M05 p.10 (docs/tfluna.md section 4)
RANGE_MAX_M = DIST_MAX_CM / 100.0  # default Dist_max 900 cm, M05 p.16 (docs/tfluna.md section 4)
INIT_SPEED_SIGMA_M_S = 1.0
"""One-sigma speed uncertainty of a fresh track, m/s (our choice: a person walking or a
robot driving; the first few readings pin it down)."""

DEFAULT_GATE_SIGMAS = 4.0
"""Innovation gate, in sigmas of the innovation (our choice: a reading this far out is
1 in 16 000 under the model, so the gate almost never throws away a good reading)."""

DEFAULT_RESET_AFTER = 2
"""Rejected readings in a row after which the track restarts (our choice: one spike is
ignored, two agreeing readings mean the target moved)."""

Q_GRID_M2_S3: tuple[float, ...] = tuple(10.0 ** (-4.0 + 7.0 * i / 11.0) for i in range(12))
"""The process-noise values :func:`tuned_oracle` tries, m^2/s^3: 12 values log-spaced from
1e-4 to 1e3 (a factor of about 4.3 apart). Our choice, to span every scenario: with
white acceleration of density q the speed wanders by sqrt(q T) in T seconds, so 1e-4 is a
target still to 3 cm/s over 10 s (a static wall) and 1e3 lets the speed change by 10 m/s
in 0.1 s (a target that reverses at 3 m/s, a step that the gate did not catch); beyond
that the filter barely smooths at 250 Hz."""


def _measurement(
    raw_m: float | None, amp: int, sigma_m: float | None
) -> tuple[float, float] | None:
    """(z in metres, R in m^2) for a usable reading, None for a missing one.

    Usable: the sensor's validity rule holds (100 <= amp <= 32768, docs/tfluna.md
    section 4; 65535, overexposure, is above it), the distance is inside
    [RANGE_MIN_M, RANGE_MAX_M] and the true sigma is known.
    """
    if raw_m is None or sigma_m is None or not (math.isfinite(sigma_m) and sigma_m >= 0.0):
        return None
    if amp < AMP_WEAK or amp > AMP_AMBIENT or not RANGE_MIN_M <= raw_m <= RANGE_MAX_M:
        return None
    return raw_m, sigma_m * sigma_m + QUANT_VAR_M2


class OracleKalman:
    """Constant-velocity Kalman filter on the range, told the true per-reading sigma.

    Args:
        accel_psd_m2_s3: q, the spectral density of the white acceleration, m^2/s^3
            (0 allowed: a target moving at constant speed).
        gate_sigmas: a reading whose innovation exceeds this many innovation sigmas is
            rejected.
        reset_after: after this many rejected readings in a row the track restarts at the
            latest one. Missing readings between them neither count nor break the run.
        max_coast_s: when set, a track that has gone this long without an accepted
            reading is dropped: the filter publishes (None, None) until a usable reading
            starts a new one. None (the default) coasts for ever, publishing the
            prediction, so a long dropout (a target beyond range) is scored on a
            prediction that a daemon would not publish.

    Raises:
        ValueError: for a negative or non-finite q, a gate that is not positive,
            ``reset_after`` below 1 or a ``max_coast_s`` that is not positive.
    """

    __slots__ = (
        "_gate2",
        "_max_coast_ns",
        "_p00",
        "_p01",
        "_p11",
        "_q",
        "_rejected",
        "_reset_after",
        "_t_ns",
        "_t_ok_ns",
        "_track",
        "_v",
        "_x",
    )

    def __init__(
        self,
        accel_psd_m2_s3: float,
        gate_sigmas: float = DEFAULT_GATE_SIGMAS,
        reset_after: int = DEFAULT_RESET_AFTER,
        *,
        max_coast_s: float | None = None,
    ) -> None:
        if not (math.isfinite(accel_psd_m2_s3) and accel_psd_m2_s3 >= 0.0):
            raise ValueError(f"accel_psd_m2_s3 must be finite and >= 0, got {accel_psd_m2_s3!r}")
        if not gate_sigmas > 0.0:
            raise ValueError(f"gate_sigmas must be positive, got {gate_sigmas!r}")
        if reset_after < 1:
            raise ValueError(f"reset_after must be at least 1, got {reset_after!r}")
        if max_coast_s is not None and not max_coast_s > 0.0:
            raise ValueError(f"max_coast_s must be positive or None, got {max_coast_s!r}")
        self._max_coast_ns = None if max_coast_s is None else round(max_coast_s * 1e9)
        self._q = float(accel_psd_m2_s3)
        self._gate2 = float(gate_sigmas) * float(gate_sigmas)
        self._reset_after = reset_after
        self._track = False
        self._x = 0.0
        self._v = 0.0
        self._p00 = 0.0
        self._p01 = 0.0
        self._p11 = 0.0
        self._t_ns = 0
        self._t_ok_ns = 0
        self._rejected = 0

    @property
    def accel_psd_m2_s3(self) -> float:
        """q, the white-acceleration spectral density, m^2/s^3."""
        return self._q

    @property
    def velocity_m_s(self) -> float | None:
        """Estimated range rate, m/s (None before the first accepted reading)."""
        return self._v if self._track else None

    def _start(self, z: float, r: float, t_ns: int) -> None:
        self._track = True
        self._x = z
        self._v = 0.0
        self._p00 = r
        self._p01 = 0.0
        self._p11 = INIT_SPEED_SIGMA_M_S * INIT_SPEED_SIGMA_M_S
        self._t_ns = t_ns
        self._t_ok_ns = t_ns
        self._rejected = 0

    def _predict(self, t_ns: int) -> None:
        if t_ns <= self._t_ns:
            # A repeated or backwards time stamp: no time has passed that we know of.
            return
        dt = (t_ns - self._t_ns) * 1e-9
        self._t_ns = t_ns
        q = self._q
        p01 = self._p01
        p11 = self._p11
        dt2 = dt * dt
        self._x += self._v * dt
        self._p00 += dt * (2.0 * p01 + dt * p11) + q * dt2 * dt / 3.0
        self._p01 = p01 + dt * p11 + 0.5 * q * dt2
        self._p11 = p11 + q * dt

    def step(
        self, raw_m: float | None, amp: int, t_ns: int, sigma_m: float | None
    ) -> tuple[float | None, float | None]:
        """Take one frame; return (estimate_m, sigma_m), or (None, None) before a track.

        Args:
            raw_m: reported distance, metres, or None when the sensor reported none.
            amp: reported amp.
            t_ns: frame time, nanoseconds (any monotonic origin).
            sigma_m: the reading's true one-sigma noise before quantisation, metres, or
                None when unknown (the reading is then treated as missing).

        Returns:
            The range estimate and its one-sigma uncertainty sqrt(P00), metres. Every frame
            after the first accepted reading publishes one: on a missing or rejected
            reading it is the prediction.
        """
        m = _measurement(raw_m, amp, sigma_m)
        if (
            self._track
            and self._max_coast_ns is not None
            and t_ns - self._t_ok_ns > self._max_coast_ns
        ):
            self._track = False
        if not self._track:
            if m is None:
                return None, None
            self._start(m[0], m[1], t_ns)
            return self._x, math.sqrt(self._p00)
        self._predict(t_ns)
        if m is not None:
            z, r = m
            p00 = self._p00
            p01 = self._p01
            s = p00 + r
            e = z - self._x
            if e * e > self._gate2 * s:
                self._rejected += 1
                if self._rejected >= self._reset_after:
                    self._start(z, r, t_ns)
            else:
                self._rejected = 0
                self._t_ok_ns = t_ns
                k0 = p00 / s
                k1 = p01 / s
                self._x += k0 * e
                self._v += k1 * e
                self._p00 = p00 - k0 * p00
                self._p01 = p01 - k0 * p01
                self._p11 -= k1 * p01
        return self._x, math.sqrt(self._p00)


def run_oracle(
    raw_m: Sequence[float | None],
    amp: Sequence[int],
    t_ns: Sequence[int],
    sigma_m: Sequence[float | None],
    accel_psd: float,
    *,
    max_coast_s: float | None = None,
) -> tuple[list[float | None], list[float | None]]:
    """Run one fresh :class:`OracleKalman` with process noise ``accel_psd`` over a run.

    Args:
        raw_m, amp, t_ns, sigma_m: per frame, as :meth:`OracleKalman.step` takes them
            (distances and sigmas in metres, times in nanoseconds); equal lengths.
        accel_psd: q, m^2/s^3.
        max_coast_s: as for :class:`OracleKalman`; None coasts for ever.

    Returns:
        Estimates and sigmas per frame, metres (None before the first accepted reading,
        and after ``max_coast_s`` without one).

    Raises:
        ValueError: when the sequences differ in length.
    """
    flt = OracleKalman(accel_psd, max_coast_s=max_coast_s)
    step = flt.step
    est: list[float | None] = []
    sig: list[float | None] = []
    put_e = est.append
    put_s = sig.append
    for z, a, t, s in zip(raw_m, amp, t_ns, sigma_m, strict=True):
        e, p = step(z, a, t, s)
        put_e(e)
        put_s(p)
    return est, sig


def tuned_oracle(
    raw_m: Sequence[float | None],
    amp: Sequence[int],
    t_ns: Sequence[int],
    sigma_m: Sequence[float | None],
    score: Callable[[list[float | None], list[float | None]], float],
    *,
    grid: Sequence[float] = Q_GRID_M2_S3,
    max_coast_s: float | None = None,
) -> tuple[float, list[float | None], list[float | None]]:
    """The oracle with the process noise that was best in hindsight for this run.

    Runs :func:`run_oracle` once per value of ``grid`` and keeps the one whose
    ``score(estimates, sigmas)`` is lowest (``lunad eval`` passes the RMSE against the
    truth away from steps). This is hindsight tuning per run: no real filter can know
    the truth it is scored on, which is the point of an oracle.

    Args:
        raw_m, amp, t_ns, sigma_m: per frame, as for :func:`run_oracle`.
        score: lower is better; NaN counts as worst.
        grid: the q values to try, m^2/s^3; :data:`Q_GRID_M2_S3` by default.
        max_coast_s: as for :class:`OracleKalman`; None coasts for ever.

    Returns:
        (best q in m^2/s^3, its estimates, its sigmas). On a tie the value that comes
        first in ``grid`` wins (the smaller q for the default grid); when no score is
        finite, the first grid value is returned.

    Raises:
        ValueError: for an empty grid or sequences of different lengths.
    """
    if not grid:
        raise ValueError("grid must hold at least one process-noise value")
    best: tuple[float, list[float | None], list[float | None]] | None = None
    best_score = math.inf
    for q in grid:
        est, sig = run_oracle(raw_m, amp, t_ns, sigma_m, q, max_coast_s=max_coast_s)
        sc = score(est, sig)
        if math.isnan(sc):
            sc = math.inf
        if best is None or sc < best_score:
            best = (q, est, sig)
            best_score = sc
    assert best is not None  # grid is not empty
    return best
