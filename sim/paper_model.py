"""Vectorised sensor models for the paper's sweep: the literal paper profile and a calibrated one.

How this works. Every model maps arrays of conditions (lux L, reflectivity R, incidence
angle theta in degrees) to per-cell statistics of N readings of a target at D_true = 2 m:
the summed absolute error of the valid readings (cm), the number of valid readings and N.
Two routes give the same statistics:

- ``simulate_cells`` draws the readings with a seeded ``numpy.random.Generator``
  (what the sweep prints), in chunks so that memory stays bounded;
- ``expected_cells`` gives their exact expectation per reading (no sampling), which the
  fit uses so that its objective is smooth and reproducible.

Paper profile (seed 000, section III, eqs 1-3, read literally):

    S = R cos(theta)                       (1)
    sigma = 0.01 + 0.0001 L                (2)  read in metres (D is in metres)
    D_meas = D_true + noise / S            (3)  noise ~ N(0, sigma)
    dropout when S < 0.05 or D_meas outside [0.2, 8.0] m

Calibrated profile (same structure, free exponents and a light-dependent threshold):

    S_r = R^alpha_r cos(theta)^m_r                         ranging strength (1)
    sigma_cm = (sigma0 + k L) ((1 + s0) / (S_r + s0))^p     noise (2) and (3)
    D_meas = D_true + sigma z,  z ~ N(0, 1)
    S_d = R^alpha_d cos(theta)^m_d                          detection strength (1)
    dropout when S_d exp(tau xi) < c (L / 10 klux)^q,  xi ~ N(0, 1),
            or D_meas outside [0.2, 8.0] m

With alpha = m = p = 1, s0 = 0 this is eq. 3 again; the per-reading amplitude
fluctuation exp(tau xi) turns the paper's hard S < 0.05 cut into a detection
probability, and its threshold grows with ambient light (zero in the dark, so that
low light loses no readings, as section V says). docs/paper-model.md has the fit.

This module never imports ``lunad.filters`` (docs/architecture.md: truth must not share code with
the estimator it judges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

D_TRUE_M = 2.0  # section III: true distance fixed at 2 m
RANGE_MIN_M = 0.2  # section III.3: valid range [0.2, 8.0] m
RANGE_MAX_M = 8.0
PAPER_SIGMA0 = 0.01  # eq. 2 constant term, unit as read (metres by default)
PAPER_K_PER_LUX = 0.0001  # eq. 2 slope per lux, unit as read
PAPER_S_MIN = 0.05  # section III: dropout when S < 0.05
READINGS_PER_SCENARIO = 1000  # section III.3: 1000 readings per scenario
SIGMA_UNIT_M = 1.0  # eq. 2 read in metres
SIGMA_UNIT_CM = 0.01  # eq. 2 read in centimetres
LUX_REF_THRESHOLD = 10_000.0  # calibrated threshold is quoted at 10 klux
CM_PER_M = 100.0

_CHUNK_ELEMENTS = 2_000_000  # readings drawn per chunk, bounds memory near 50 MB


@dataclass(frozen=True, slots=True)
class CellStats:
    """Statistics of N readings in each sweep cell (arrays of one shape).

    Attributes:
        abs_error_sum_cm: sum of |D_meas - D_true| over the valid readings, cm.
        valid: number of valid readings (expected number for ``expected_cells``).
        readings: readings per cell, N.
    """

    abs_error_sum_cm: FloatArray
    valid: FloatArray
    readings: int

    @property
    def mean_error_cm(self) -> FloatArray:
        """Mean absolute error of the valid readings per cell, cm (NaN if none is valid)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.valid > 0, self.abs_error_sum_cm / self.valid, np.nan)

    @property
    def failure_rate_pct(self) -> FloatArray:
        """Share of dropped readings per cell, percent."""
        return 100.0 * (1.0 - self.valid / self.readings)


class Profile(Protocol):
    """A sensor model the sweep can run: a noise level and a detection rule per cell."""

    @property
    def name(self) -> str:
        """Short name for tables and plots."""
        ...

    def error_sd_m(self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray) -> FloatArray:
        """Standard deviation of D_meas - D_true per cell, metres."""
        ...

    def detect_probability(
        self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray
    ) -> FloatArray:
        """Probability that one reading passes the strength test (before the range gate)."""
        ...

    def sample_detected(
        self,
        lux: FloatArray,
        r: FloatArray,
        theta_deg: FloatArray,
        readings: int,
        rng: np.random.Generator,
    ) -> NDArray[np.bool_]:
        """Draw the strength test for ``readings`` readings per cell: shape (cells, readings)."""
        ...


@dataclass(frozen=True, slots=True)
class PaperProfile:
    """Equations 1-3 of the paper, literally (seed 000, section III).

    Attributes:
        sigma_unit_m: metres per unit of eq. 2; 1.0 reads sigma in metres (default,
            the unit of D in eq. 3), 0.01 reads it in centimetres.
        s_min: strength threshold below which every reading drops (section III).
    """

    sigma_unit_m: float = SIGMA_UNIT_M
    s_min: float = PAPER_S_MIN
    name: str = "paper"

    def strength(self, r: FloatArray, theta_deg: FloatArray) -> FloatArray:
        """Eq. 1: S = R cos(theta)."""
        return np.asarray(r) * np.cos(np.radians(theta_deg))

    def error_sd_m(self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray) -> FloatArray:
        """Eqs 2-3: sigma / S, metres (infinite where S <= 0)."""
        s = self.strength(r, theta_deg)
        sigma_m = (PAPER_SIGMA0 + PAPER_K_PER_LUX * np.asarray(lux)) * self.sigma_unit_m
        with np.errstate(divide="ignore"):
            return np.where(s > 0, sigma_m / np.where(s > 0, s, 1.0), np.inf)

    def detect_probability(
        self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray
    ) -> FloatArray:
        """1 where S >= S_min, else 0: the paper's hard threshold."""
        s = self.strength(r, theta_deg) * np.ones_like(np.asarray(lux, dtype=float))
        return (s >= self.s_min).astype(float)

    def sample_detected(
        self,
        lux: FloatArray,
        r: FloatArray,
        theta_deg: FloatArray,
        readings: int,
        rng: np.random.Generator,
    ) -> NDArray[np.bool_]:
        """The threshold is deterministic, so no random numbers are drawn."""
        ok = self.detect_probability(lux, r, theta_deg) > 0.5
        return np.broadcast_to(ok[:, None], (ok.shape[0], readings))


@dataclass(frozen=True, slots=True)
class CalibratedProfile:
    """The paper's structure with free parameters fitted to Table I (``lunad sweep --fit``).

    Attributes:
        sigma0_cm: noise sd on a white target at normal incidence in the dark, cm (eq. 2).
        k_cm_per_klux: growth of that sd per 1000 lux, cm (eq. 2, linear in L).
        alpha_r: reflectivity exponent of the ranging strength S_r (eq. 1 has 1).
        m_r: cos(theta) exponent of S_r (eq. 1 has 1).
        s0: strength floor: below S_r ~ s0 the noise stops growing (eq. 3 has 0).
        p: exponent of the 1 / S_r noise growth (eq. 3 has 1).
        alpha_d: reflectivity exponent of the detection strength S_d.
        m_d: cos(theta) exponent of S_d.
        threshold_10klux: detection threshold on S_d at 10 klux (eq. 3's 0.05 is fixed).
        q: growth exponent of the threshold with L (threshold = c (L/10 klux)^q).
        tau: log-sd of the per-reading return amplitude, exp(tau xi).
    """

    sigma0_cm: float
    k_cm_per_klux: float
    alpha_r: float
    m_r: float
    s0: float
    p: float
    alpha_d: float
    m_d: float
    threshold_10klux: float
    q: float
    tau: float
    name: str = "calibrated"

    def error_sd_m(self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray) -> FloatArray:
        """Noise sd per cell, metres: (sigma0 + k L) ((1 + s0) / (S_r + s0))^p."""
        cos_t = np.clip(np.cos(np.radians(theta_deg)), 0.0, 1.0)
        s_r = np.asarray(r) ** self.alpha_r * cos_t**self.m_r
        sd_cm = (self.sigma0_cm + self.k_cm_per_klux * np.asarray(lux) / 1000.0) * (
            (1.0 + self.s0) / (s_r + self.s0)
        ) ** self.p
        return sd_cm / CM_PER_M

    def _threshold_z(self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray) -> FloatArray:
        """(ln threshold - ln S_d) / tau: a reading drops when its xi falls below this."""
        lux_a = np.asarray(lux, dtype=float)
        cos_t = np.clip(np.cos(np.radians(theta_deg)), 1e-12, 1.0)
        log_sd = self.alpha_d * np.log(np.asarray(r)) + self.m_d * np.log(cos_t)
        with np.errstate(divide="ignore"):
            log_thr = np.log(self.threshold_10klux) + self.q * np.log(lux_a / LUX_REF_THRESHOLD)
        return np.where(lux_a > 0, (log_thr - log_sd) / self.tau, -np.inf)

    def detect_probability(
        self, lux: FloatArray, r: FloatArray, theta_deg: FloatArray
    ) -> FloatArray:
        """P(S_d exp(tau xi) >= threshold(L)) per cell."""
        return 1.0 - norm_cdf(self._threshold_z(lux, r, theta_deg))

    def sample_detected(
        self,
        lux: FloatArray,
        r: FloatArray,
        theta_deg: FloatArray,
        readings: int,
        rng: np.random.Generator,
    ) -> NDArray[np.bool_]:
        """Draw xi per reading and compare it with the cell's threshold."""
        u = self._threshold_z(lux, r, theta_deg)
        xi = rng.standard_normal((u.shape[0], readings))
        return xi >= u[:, None]


CALIBRATED_DEFAULT = CalibratedProfile(
    sigma0_cm=0.0901294,
    k_cm_per_klux=0.00526342,
    alpha_r=8.00655,
    m_r=8.29993,
    s0=1e-06,
    p=0.28019,
    alpha_d=0.499402,
    m_d=0.771154,
    threshold_10klux=0.0836069,
    q=0.368608,
    tau=1.0041,
)
"""Fitted by ``lunad sweep --fit`` (sim/fit.py); paste its output here to change it."""

PAPER_METRES = PaperProfile()
PAPER_CENTIMETRES = PaperProfile(sigma_unit_m=SIGMA_UNIT_CM, name="paper-cm")


def norm_cdf(x: ArrayLike) -> FloatArray:
    """Standard normal CDF, numpy only (erfc via Abramowitz-Stegun 7.1.26, |err| < 1.5e-7)."""
    z = np.asarray(x, dtype=float) / math.sqrt(2.0)
    a = np.abs(z)
    t = 1.0 / (1.0 + 0.3275911 * np.where(np.isfinite(a), a, 0.0))
    poly = t * (
        0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    )
    erfc_a = np.where(np.isfinite(a), poly * np.exp(-(np.where(np.isfinite(a), a, 0.0) ** 2)), 0.0)
    return np.where(z >= 0, 1.0 - 0.5 * erfc_a, 0.5 * erfc_a)


_PHI0 = 1.0 / math.sqrt(2.0 * math.pi)


def _norm_pdf(x: FloatArray) -> FloatArray:
    with np.errstate(over="ignore"):
        return np.exp(-0.5 * np.square(x)) / math.sqrt(2.0 * math.pi)


def expected_cells(
    profile: Profile, lux: ArrayLike, r: ArrayLike, theta_deg: ArrayLike
) -> CellStats:
    """Exact per-reading expectation of the cell statistics (readings = 1).

    For e ~ N(0, s) inside the range gate [a, b] = [0.2 - D, 8.0 - D] m,
    P(gate) = Phi(b/s) - Phi(a/s) and E[|e|; gate] = s (2 phi(0) - phi(a/s) - phi(b/s));
    the strength test is independent of e, so both scale by its pass probability.
    """
    lux_a, r_a, t_a = (np.asarray(v, dtype=float) for v in np.broadcast_arrays(lux, r, theta_deg))
    sd = profile.error_sd_m(lux_a, r_a, t_a)
    det = profile.detect_probability(lux_a, r_a, t_a)
    lo, hi = RANGE_MIN_M - D_TRUE_M, RANGE_MAX_M - D_TRUE_M
    finite = np.isfinite(sd) & (sd > 0)
    s = np.where(finite, sd, 1.0)
    p_gate = np.where(finite, norm_cdf(hi / s) - norm_cdf(lo / s), 0.0)
    e_abs = np.where(finite, s * (2.0 * _PHI0 - _norm_pdf(lo / s) - _norm_pdf(hi / s)), 0.0)
    return CellStats(abs_error_sum_cm=det * e_abs * CM_PER_M, valid=det * p_gate, readings=1)


def simulate_cells(
    profile: Profile,
    lux: ArrayLike,
    r: ArrayLike,
    theta_deg: ArrayLike,
    readings: int = READINGS_PER_SCENARIO,
    rng: np.random.Generator | None = None,
) -> CellStats:
    """Draw ``readings`` readings per cell and return their statistics.

    Cells are processed in chunks of about two million readings; in each chunk the
    range noise is drawn first, then the strength test, so a seed fixes every number.

    Raises:
        ValueError: if ``readings`` < 1.
    """
    if readings < 1:
        raise ValueError(f"readings must be >= 1, got {readings}")
    gen = rng if rng is not None else np.random.default_rng()
    lux_a, r_a, t_a = (
        np.ravel(np.asarray(v, dtype=float)) for v in np.broadcast_arrays(lux, r, theta_deg)
    )
    shape = np.broadcast_shapes(np.shape(lux), np.shape(r), np.shape(theta_deg))
    sd = profile.error_sd_m(lux_a, r_a, t_a)
    err_sum = np.zeros(lux_a.size)
    valid = np.zeros(lux_a.size)
    step = max(1, _CHUNK_ELEMENTS // readings)
    lo, hi = RANGE_MIN_M - D_TRUE_M, RANGE_MAX_M - D_TRUE_M
    for start in range(0, lux_a.size, step):
        sl = slice(start, start + step)
        z = gen.standard_normal((sd[sl].size, readings))
        with np.errstate(invalid="ignore", over="ignore"):
            e_m = sd[sl, None] * z
            ok = (e_m >= lo) & (e_m <= hi)
        ok &= profile.sample_detected(lux_a[sl], r_a[sl], t_a[sl], readings, gen)
        valid[sl] = ok.sum(axis=1)
        err_sum[sl] = np.where(ok, np.abs(e_m), 0.0).sum(axis=1) * CM_PER_M
    return CellStats(
        abs_error_sum_cm=err_sum.reshape(shape), valid=valid.reshape(shape), readings=readings
    )
