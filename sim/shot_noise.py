"""A second sensor physics, the "shot-noise world", so that an evaluation can say no.

Why it exists. lunad's filter inverts a noise law (paper eqs 1-3: sigma = (sigma0 + k L)
/ S with S read from amp). :class:`~lunad.sim.physics.RealisticSensor` draws its readings
from the same law, so a filter that matches it can only look good there. This module
draws readings from a law of a different shape, with its own constants and its own amp
scale, so that ``lunad eval`` can ask whether lunad still holds up when its assumptions
are wrong, as they will be on real hardware. It shares only the sensor's wire rules
(validity thresholds, amp limits, Dist_max: docs/tfluna.md section 4) with the realistic
profile, by importing them; it never imports ``lunad.filters`` (docs/architecture.md).

The law. A phase time-of-flight sensor counts photons; the phase error of a count is
photon shot noise, whose one-sigma is the square root of everything counted (the
returned signal plus the ambient light that reaches the detector) over the signal:

    S     = R cos(theta) (d_ref / d)^2              d_ref = 1.5 m, S in this world's units
    amp   = 1500 S (1 + 5 % N(0, 1))                 a jittered report of S
    shot  = 5 mm sqrt(S + 0.336 L / 1000) / S        L: ambient light, lux
    sigma = f sqrt(shot^2 + (2 mm)^2)               2 mm electronics floor, f = noise_scale
    D     = round_cm(d + N(0, sigma) [+ spike])      0.1 % multipath spikes, 0.2-1.5 m longer

So in the dark sigma falls as 1/sqrt(S) (the paper: 1/S), and ambient light enters
under the square root (the paper's eq. 2: linearly, sigma0 + k L). The noise follows
the *true* signal; the reported amp is only a jittered witness of it, so a filter that
reads S from amp is a little wrong on every reading, as on a real sensor.

How the constants were chosen, each independently of ``lunad.filters`` and of the
realistic profile's fit:

- 5 mm at S = 1 in the dark: the datasheet's ~0.5 cm repeatability at strong returns
  (amp >= 2000, M05 p.9 Table 2; docs/tfluna.md section 5). Here amp 2000 is S = 1.33,
  sigma 4.8 mm with the floor.
- 0.336 per klux: at S = 1 the shot noise grows 4.6x from dark to 60 klux, the ratio of the
  paper's Table I mean errors above 50 klux and below 5 klux (6.9 and 1.5 cm). This is
  the one datum both worlds are anchored to; their shapes differ everywhere else.
- d_ref 1.5 m and 1500 amp per unit of S: our choice, so that amp means something
  else here than in the realistic profile (2000 at 2 m). A white board (R 0.9) reads
  amp 1350 at 1.5 m, 300 at 3.2 m and drops out (amp < 100) beyond 5.5 m, well short
  of the datasheet's 8 m at 90 % (M05 p.9): a pessimistic world.
- 2 mm floor: our choice, the phase-measurement jitter of the electronics that no
  signal averages away; it keeps a very strong return from reading noise-free.
- 5 % amp jitter and 0.1 % spikes of 0.2-1.5 m: our choice, other numbers than the
  realistic profile's 3 % and 0.2 % of 0.3-2 m.

Against the datasheet's repeatability table (M05 p.9 Table 2) this world is quieter for
weak returns: amp 1000, 400, 200, 100 give 0.64, 0.99, 1.4, 1.9 cm in the dark against
1, 2, 3, 3 cm. Sun beyond 70 klux raises amp above 32768, as on the realistic profile.
"""

from __future__ import annotations

import math
import random

from lunad.sim.physics import (
    AMBIENT_IMMUNITY_LUX,
    AMP_AMBIENT,
    AMP_MAX,
    AMP_SIGNAL_MAX,
    AMP_WEAK,
    DIST_MAX_CM,
    RawReading,
    Truth,
)

SHOT_REF_DISTANCE_M = 1.5  # distance at which S = R cos(theta) (our choice, see module doc)
SHOT_AMP_PER_S = 1500.0  # reported amp per unit of S (our choice, see module doc)
SHOT_SIGMA_AT_S1_M = 0.005
"""One-sigma shot noise at S = 1 in the dark, metres: the datasheet's 0.5 cm at strong
returns (M05 p.9 Table 2)."""

SHOT_AMBIENT_S_PER_LUX = 0.336e-3
"""Ambient light counted by the detector, in units of S per lux: sqrt(1 + 0.336 * 60) =
4.6, the paper's Table I ratio of mean errors above 50 klux to below 5 klux."""

SHOT_FLOOR_M = 0.002  # electronics jitter, added in quadrature (our choice, module doc)
SHOT_AMP_JITTER = 0.05  # relative one-sigma jitter of the reported amp (our choice)
SHOT_SPIKE_PROBABILITY = 0.001  # multipath spikes per reading (our choice)
SHOT_SPIKE_MIN_M = 0.2  # a spike adds a longer path of 0.2 ...
SHOT_SPIKE_MAX_M = 1.5  # ... to 1.5 m (two targets in the beam, M05 p.10)
_MIN_DISTANCE_M = 0.01  # keeps (d_ref / d)^2 finite at d = 0


class ShotNoiseSensor:
    """The shot-noise world: the realistic profile's interface, another noise law.

    Args:
        noise_scale: multiplies the whole one-sigma (a sensor noisier or quieter than
            this world's nominal one).
        ref_distance_m: d_ref, where S = R cos(theta), metres.
        amp_per_s: reported amp per unit of S.
        sigma_at_s1_m: shot noise at S = 1 in the dark, metres.
        ambient_s_per_lux: ambient light in units of S per lux.
        floor_m: electronics floor, metres, in quadrature.
        amp_noise: relative one-sigma jitter of the reported amp.
        spike_probability: chance per reading of a multipath spike.

    Raises:
        ValueError: for a noise_scale that is not positive.
    """

    def __init__(
        self,
        noise_scale: float = 1.0,
        *,
        ref_distance_m: float = SHOT_REF_DISTANCE_M,
        amp_per_s: float = SHOT_AMP_PER_S,
        sigma_at_s1_m: float = SHOT_SIGMA_AT_S1_M,
        ambient_s_per_lux: float = SHOT_AMBIENT_S_PER_LUX,
        floor_m: float = SHOT_FLOOR_M,
        amp_noise: float = SHOT_AMP_JITTER,
        spike_probability: float = SHOT_SPIKE_PROBABILITY,
    ) -> None:
        if not noise_scale > 0.0:
            raise ValueError(f"noise_scale must be positive, got {noise_scale!r}")
        self.noise_scale = noise_scale
        self.ref_distance_m = ref_distance_m
        self.amp_per_s = amp_per_s
        self.sigma_at_s1_m = sigma_at_s1_m
        self.ambient_s_per_lux = ambient_s_per_lux
        self.floor_m = floor_m
        self.amp_noise = amp_noise
        self.spike_probability = spike_probability

    def signal_of(self, truth: Truth) -> float:
        """True signal S = R cos(theta) (d_ref / d)^2, in this world's units (0: none)."""
        cos = math.cos(math.radians(truth.angle_deg))
        if cos <= 0.0 or truth.reflectivity <= 0.0:
            return 0.0
        g = self.ref_distance_m / max(truth.distance_m, _MIN_DISTANCE_M)
        return truth.reflectivity * cos * g * g

    def amp_of(self, truth: Truth) -> float:
        """Amp the true signal would read before jitter and the sensor's limits."""
        return self.amp_per_s * self.signal_of(truth)

    def sigma_of(self, truth: Truth, amp: int | None = None) -> float:
        """One-sigma noise of a reading under ``truth``, metres, before quantisation.

        Args:
            truth: the world at this instant; the noise follows its true signal and light.
            amp: accepted for the interface of ``RealisticSensor.sigma_of`` and not used:
                in this world the reported amp is only a jittered report of the signal
                that sets the noise.

        Returns:
            ``noise_scale * sqrt(shot^2 + floor^2)``; infinity when there is no signal.
        """
        s = self.signal_of(truth)
        if s <= 0.0:
            return math.inf
        counted = s + self.ambient_s_per_lux * max(truth.lux, 0.0)
        shot = self.sigma_at_s1_m * math.sqrt(counted) / s
        return self.noise_scale * math.hypot(shot, self.floor_m)

    def sample(self, truth: Truth, rng: random.Random, amp_threshold: int = AMP_WEAK) -> RawReading:
        """Draw one reading for ``truth`` using ``rng``.

        Args:
            truth: the world at this instant.
            rng: the only source of randomness, so a seeded run repeats exactly.
            amp_threshold: the sensor's amp threshold (ID 0x22). A reading with a lower
                amp (or amp 0) gets no distance (0, ``sigma_m`` None) and draws no noise.

        Returns:
            The reading as the sensor would send it, with the true one-sigma noise it was
            drawn with (before the 1 cm quantisation) in ``sigma_m``.
        """
        amp_f = self.amp_of(truth)
        if self.amp_noise > 0.0 and amp_f > 0.0:
            amp_f *= max(0.0, 1.0 + self.amp_noise * rng.gauss(0.0, 1.0))
        if amp_f >= AMP_MAX:
            amp = AMP_MAX  # overexposure, M05 p.14
        else:
            amp = max(0, min(AMP_SIGNAL_MAX, round(amp_f)))
        if amp < amp_threshold or amp == 0:
            return RawReading(0, amp)
        sigma = self.sigma_of(truth)
        d = truth.distance_m + rng.gauss(0.0, sigma)
        spike = rng.random() < self.spike_probability
        if spike:
            d += rng.uniform(SHOT_SPIKE_MIN_M, SHOT_SPIKE_MAX_M)
        if truth.lux > AMBIENT_IMMUNITY_LUX and amp != AMP_MAX:
            # The sensor's ambient flag: amp jumps above 32768 (M05 p.14), as on the
            # realistic profile; the distance sent then is undocumented, we keep the noisy one.
            amp = min(AMP_MAX - 1, AMP_AMBIENT + 1 + amp)
        dist_cm = max(0, min(DIST_MAX_CM, round(d * 100.0)))
        return RawReading(dist_cm, amp, sigma, spike)
