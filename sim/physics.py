"""Per-reading sensor physics for the virtual TF-Luna.

How this works: the paper (seed 000, section III, eqs 1-3) models one reading as

    S = R cos(theta)                 (1)  relative signal strength
    sigma = sigma0 + k L             (2)  noise, growing with ambient light L (lux)
    D_meas = D_true + noise / S      (3)  noise ~ N(0, sigma)

and drops a reading when S < 0.05 or D_meas is outside [0.2, 8.0] m. The virtual
sensor turns S into the ``amp`` field with ``amp = S * AMP_REF`` and applies the real
sensor's rules (TFLUNA.md section 4): amp below 100 reports distance 0, distances are
quantised to 1 cm.

This module never imports ``lunad.filters``: the truth generator must not share code
with the estimator it judges (DESIGN.md).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

AMP_REF = 2000.0
"""Amp for S = 1 (white matte target, normal incidence, 2 m). With the paper's
threshold S_min = 0.05 this puts the dropout at amp 100, the sensor's own weak-signal
threshold (M05 p.16)."""

AMP_WEAK = 100  # below this the sensor reports dummy distance 0 (M05 p.16)
AMP_MAX = 0xFFFF  # 16-bit field; 65535 means overexposure (M05 p.14)
PAPER_SIGMA0_M = 0.01  # eq. 2, sigma0, read in metres (docs/paper-model.md)
PAPER_K_M_PER_LUX = 0.0001  # eq. 2, k, metres per lux


@dataclass(frozen=True, slots=True)
class Truth:
    """What the world looks like to the sensor at one instant.

    Attributes:
        distance_m: true distance to the target, metres.
        reflectivity: target reflectivity R, 0..1.
        angle_deg: incidence angle theta between beam and surface normal, degrees.
        lux: ambient illuminance L, lux.
    """

    distance_m: float = 2.0
    reflectivity: float = 0.9
    angle_deg: float = 0.0
    lux: float = 0.0


@dataclass(frozen=True, slots=True)
class RawReading:
    """One reading as the sensor would put it on the wire.

    Attributes:
        dist_cm: reported distance, centimetres (0 when the sensor reports none).
        amp: reported signal strength.
    """

    dist_cm: int
    amp: int


class PaperSensor:
    """Equations 1-3 of the paper, one reading at a time, with the sensor's wire rules."""

    def __init__(
        self,
        sigma0_m: float = PAPER_SIGMA0_M,
        k_m_per_lux: float = PAPER_K_M_PER_LUX,
        amp_ref: float = AMP_REF,
    ) -> None:
        self.sigma0_m = sigma0_m
        self.k_m_per_lux = k_m_per_lux
        self.amp_ref = amp_ref

    def sample(self, truth: Truth, rng: random.Random) -> RawReading:
        """Draw one reading for ``truth`` using ``rng``."""
        s = truth.reflectivity * math.cos(math.radians(truth.angle_deg))
        amp = max(0, min(AMP_MAX, round(s * self.amp_ref)))
        if amp < AMP_WEAK or s <= 0.0:
            return RawReading(0, amp)
        sigma = self.sigma0_m + self.k_m_per_lux * truth.lux
        d = truth.distance_m + rng.gauss(0.0, sigma) / s
        return RawReading(max(0, min(0xFFFF, round(d * 100.0))), amp)
