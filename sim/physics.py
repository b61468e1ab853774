"""Per-reading sensor physics for the virtual TF-Luna.

How this works: the paper (seed 000, section III, eqs 1-3) models one reading as

    S = R cos(theta)                 (1)  relative signal strength
    sigma = sigma0 + k L             (2)  noise, growing with ambient light L (lux)
    D_meas = D_true + noise / S      (3)  noise ~ N(0, sigma)

and drops a reading when S < 0.05 or D_meas is outside [0.2, 8.0] m. The virtual
sensor turns S into the ``amp`` field with ``amp = S * AMP_REF`` and applies the real
sensor's rules (docs/tfluna.md section 4): amp below the amp threshold (100 by default,
ID 0x22) reports no distance, distances are quantised to 1 cm. A model is told the
threshold only so that it draws no noise for a reading the sensor will not report;
``VirtualSensor.data_frame`` puts the dummy distance on the wire.

The realistic profile (:class:`RealisticSensor`) is what the daemon meets in the
field, for scenarios and ``lunad eval``:

    amp   = AMP_REF R cos(theta) (2 m / d)^2 (1 + 3 % N(0, 1))   falls with d^2
    S     = amp / AMP_REF                          what the sensor lets us observe
    sigma = f (sigma0 + k L) / S                   paper eq. 2-3 structure, f = noise_scale
    D     = round_cm(d + N(0, sigma) [+ spike])    1 cm output steps (DS p.2)

with the sensor's own rules (docs/tfluna.md section 4): amp < 100 reports distance 0
(M05 p.16); amp that would exceed 65535 reads 65535, saturated (M05 p.14); a strong
but unsaturated signal tops out at 30000 ("normally Amp should not be above 30000",
M05 p.14); ambient light beyond the 70 klux immunity (DS p.2) reads amp > 32768
(M05 p.14); distances are clamped to the default Dist_max of 900 cm (M05 p.16).
In the 20 cm blind zone the reading is drawn as usual; the daemon's range gate
drops it. Rare multipath spikes (two targets in the beam, M05 p.10) add a longer
path to one reading. sigma0 and k are fitted to the datasheet repeatability table
at L = 0 (M05 p.9 Table 2): see REALISTIC_SIGMA0_M.

This module never imports ``lunad.filters``: the truth generator must not share code
with the estimator it judges (docs/architecture.md).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

AMP_REF = 2000.0
"""Amp for S = 1 (white matte target, normal incidence, 2 m). With the paper's
threshold S_min = 0.05 this puts the dropout at amp 100, the sensor's own weak-signal
threshold (M05 p.16)."""

AMP_WEAK = 100  # default amp threshold: below it the sensor sends dummy_dist (M05 p.16)
AMP_MAX = 0xFFFF  # 16-bit field; 65535 means overexposure (M05 p.14)
PAPER_SIGMA0_M = 0.01  # eq. 2, sigma0, read in metres (docs/paper-model.md)
PAPER_K_M_PER_LUX = 0.0001  # eq. 2, k, metres per lux

REF_DISTANCE_M = 2.0  # where amp = AMP_REF * R cos(theta): S = 1 at 2 m (docs/filter.md)
AMP_SIGNAL_MAX = 30000  # "normally Amp should not be above 30000", M05 p.14
AMP_AMBIENT = 32768  # amp above this flags ambient overexposure, M05 p.14
AMBIENT_IMMUNITY_LUX = 70_000.0  # ambient light immunity, DS p.2
DIST_MAX_CM = 900  # default Dist_max, M05 p.16 (output clamps there, silence = 0)

REALISTIC_SIGMA0_M = 0.004
"""sigma0 of the realistic profile, metres. With S = amp / 2000 and 1 cm steps,
sigma0 / S gives 0.49 cm at amp 2000, 0.85 cm at 1000, 2.0 cm at 400 against the
datasheet's 0.5, 1 and 2 cm (M05 p.9 Table 2). The 1/S law of paper eq. 3 is steeper
than the table below amp 400 (4 and 8 cm at amp 200 and 100, table: 3 cm) and than
the repeatability-versus-distance table (M05 p.10 Table 3): a dark or far target is
noisier here than on the datasheet."""

REALISTIC_K_M_PER_LUX = 2.5e-7
"""k of the realistic profile, metres per lux: sigma at S = 1 grows 4.6x from dark
to 60 klux, the ratio of the paper's Table I mean errors above 50 klux (6.9 cm) and
below 5 klux (1.5 cm). The paper's own 1e-4 m/lux gives 5 m at 50 klux."""

AMP_NOISE_FRACTION = 0.03
"""Relative one-sigma jitter of the reported amp (our choice; the datasheet gives no
figure). It makes a target at a threshold cross it back and forth, as real ones do."""

SPIKE_PROBABILITY = 0.002  # multipath spikes per reading (our choice: "rare")
SPIKE_MIN_M = 0.3  # a spike adds a longer path of 0.3 ...
SPIKE_MAX_M = 2.0  # ... to 2 m (two targets in the beam, M05 p.10)


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
        sigma_m: the true one-sigma noise this reading was drawn with, metres, before
            the 1 cm quantisation; None when the sensor reported no distance. Only
            a simulator knows it: ``lunad eval``'s oracle filter uses it.
        spike: True when a multipath spike was added to this reading.
    """

    dist_cm: int
    amp: int
    sigma_m: float | None = None
    spike: bool = False


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

    def amp_of(self, truth: Truth) -> float:
        """Received signal before the sensor's limits: amp_ref R cos(theta) (eq. 1; the
        paper's S does not fall with distance)."""
        s = truth.reflectivity * math.cos(math.radians(truth.angle_deg))
        return self.amp_ref * s if s > 0.0 else 0.0

    def sample(self, truth: Truth, rng: random.Random, amp_threshold: int = AMP_WEAK) -> RawReading:
        """Draw one reading for ``truth`` using ``rng``.

        Args:
            amp_threshold: the sensor's amp threshold (ID 0x22). A reading whose strength
                S is below ``amp_threshold / amp_ref`` gets no distance (0, ``sigma_m``
                None) and draws no noise. S is tested before amp is rounded: the paper
                drops S < 0.05 (eq. 1), and S = 0.0498 rounds to amp 100.
        """
        s = truth.reflectivity * math.cos(math.radians(truth.angle_deg))
        amp = max(0, min(AMP_MAX, round(s * self.amp_ref)))
        if s <= 0.0 or s < amp_threshold / self.amp_ref:
            return RawReading(0, amp)
        sigma = self.sigma0_m + self.k_m_per_lux * truth.lux
        d = truth.distance_m + rng.gauss(0.0, sigma) / s
        return RawReading(max(0, min(0xFFFF, round(d * 100.0))), amp, sigma / s)


NOISE_SCALE_MAX = 1000.0
"""Largest ``noise_scale`` (our bound): 1000 times the noise is metres of it at any
range, no sensor at all; past about 1e307 a reading overflows to infinity."""


class RealisticSensor:
    """The realistic profile: amp from R, cos(theta) and d^2, sensor rules, spikes.

    Args:
        noise_scale: multiplies sigma0 and k (2.0 or 0.5 model a sensor that is
            not the one the filter was configured for).
        sigma0_m, k_m_per_lux: paper eq. 2 constants before scaling, metres and
            metres per lux.
        amp_ref: amp for S = 1 at REF_DISTANCE_M.
        spike_probability: chance per reading of a multipath spike.
        amp_noise: relative one-sigma jitter of the reported amp.
    """

    def __init__(
        self,
        noise_scale: float = 1.0,
        *,
        sigma0_m: float = REALISTIC_SIGMA0_M,
        k_m_per_lux: float = REALISTIC_K_M_PER_LUX,
        amp_ref: float = AMP_REF,
        spike_probability: float = SPIKE_PROBABILITY,
        amp_noise: float = AMP_NOISE_FRACTION,
    ) -> None:
        if not 0.0 < noise_scale <= NOISE_SCALE_MAX:
            raise ValueError(
                f"noise_scale must be above 0 and at most {NOISE_SCALE_MAX:g}, got {noise_scale!r}"
            )
        self.noise_scale = noise_scale
        self.sigma0_m = sigma0_m * noise_scale
        self.k_m_per_lux = k_m_per_lux * noise_scale
        self.amp_ref = amp_ref
        self.spike_probability = spike_probability
        self.amp_noise = amp_noise

    def amp_of(self, truth: Truth) -> float:
        """Received signal before the sensor's limits: AMP_REF R cos(theta) (2 m / d)^2."""
        cos = math.cos(math.radians(truth.angle_deg))
        if cos <= 0.0 or truth.reflectivity <= 0.0:
            return 0.0
        d = max(truth.distance_m, 0.01)
        g = REF_DISTANCE_M / d
        return self.amp_ref * truth.reflectivity * cos * g * g

    def sigma_of(self, truth: Truth, amp: int) -> float:
        """One-sigma noise of a reading with this ``amp`` under ``truth``'s light, metres."""
        s = amp / self.amp_ref
        return (self.sigma0_m + self.k_m_per_lux * truth.lux) / s

    def sample(self, truth: Truth, rng: random.Random, amp_threshold: int = AMP_WEAK) -> RawReading:
        """Draw one reading for ``truth`` using ``rng``.

        Args:
            amp_threshold: the sensor's amp threshold (ID 0x22). A reading with a lower
                amp (or amp 0) gets no distance (0, ``sigma_m`` None) and draws no noise.
        """
        amp_f = self.amp_of(truth)
        if self.amp_noise > 0.0:
            amp_f *= 1.0 + self.amp_noise * rng.gauss(0.0, 1.0)
        if amp_f >= AMP_MAX:
            amp = AMP_MAX
        else:
            amp = max(0, min(AMP_SIGNAL_MAX, round(amp_f)))
        if amp < amp_threshold or amp == 0:
            return RawReading(0, amp)
        sigma = self.sigma_of(truth, amp)
        d = truth.distance_m + rng.gauss(0.0, sigma)
        spike = rng.random() < self.spike_probability
        if spike:
            d += rng.uniform(SPIKE_MIN_M, SPIKE_MAX_M)
        if truth.lux > AMBIENT_IMMUNITY_LUX and amp != AMP_MAX:
            # The sensor's ambient flag: amp jumps above 32768 (M05 p.14); the
            # distance it sends then is undocumented, we keep the noisy one.
            amp = min(AMP_MAX - 1, AMP_AMBIENT + 1 + amp)
        dist_cm = max(0, min(DIST_MAX_CM, round(d * 100.0)))
        return RawReading(dist_cm, amp, sigma, spike)
