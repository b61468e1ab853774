"""Filter settings: plain values, validated at the daemon's config boundary.

Units are in the names: metres (``_m``), seconds (``_s``), lux. Every default cites
where it comes from; the ones we chose ourselves say so and say why.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

AMP_REF_DEFAULT = 2000.0
"""Amp for S = 1 until ``lunad calibrate`` measures it (white matte target, normal
incidence, 2 m). With S_min = 0.05 it puts the paper's dropout at amp 100, the
sensor's own weak-signal threshold (TF-Luna manual M05 p.16)."""

S_MIN_PAPER = 0.05  # dropout threshold on S, paper section III
MIN_RANGE_M = 0.2  # blind zone and the paper's range gate, M05 p.10; paper section III
MAX_RANGE_M = 8.0  # datasheet range at 90 % reflectivity, DS p.2; paper section III
AMP_MIN = 100  # weak-signal threshold, M05 p.16
AMP_AMBIENT = 32768  # amp above this means ambient overexposure, M05 p.14
AMP_SATURATED = 0xFFFF  # overexposure, M05 p.14

SIGMA0_DEFAULT_M = 0.004
"""sigma0 of paper eq. 2, metres, refitted to the datasheet repeatability table
(M05 p.9 Table 2, docs/tfluna.md section 5): sigma0 / S with S = amp / 2000 gives 0.4 cm
at amp 2000 (0.49 cm with the 1 cm quantisation, table: 0.5 cm), 0.8 cm at amp
1000 (table: 1 cm) and 2 cm at amp 400 (table: 2 cm). The paper's own 0.01 would
be 1 cm at S = 1, twice the datasheet."""

K_DEFAULT_M_PER_LUX = 2.5e-7
"""k of paper eq. 2, metres per lux. The paper's 1e-4 m/lux would make sigma 5 m at
50 klux, which contradicts its own Table I; we keep the structure and choose k so
that sigma at S = 1 grows about 4.6x from dark to 60 klux, the ratio of Table I's
mean errors for > 50 klux (6.9 cm) and < 5 klux (1.5 cm)."""

RESOLUTION_M = 0.01  # 1 cm output resolution, DS p.2; M05 p.9

LUX_STABLE_MAX = 10_000.0  # paper section V (docs/filter.md, zones): stable region lux < 10 klux
LUX_HIGH_AMBIENT = 20_000.0  # paper section IV.A and Table I: degradation above 20 klux
S_STABLE_MIN = 0.35  # paper's stable region R > 0.5 and angle < 45 deg: R cos(theta) > 0.354


VALUE_MIN = 1e-9
VALUE_MAX = 1e9
"""Every float setting lies in this range (or is 0 where 0 is allowed). Sane ones lie
well inside it (``k_m_per_lux`` about 1e-7, lux thresholds about 1e5); beyond it the
filter's arithmetic overflows (``k_m_per_lux = 1e-320`` made ``lux_est`` infinite), and
the published JSON would carry ``inf``, which no JSON parser accepts."""

COUNT_MAX = 100_000
"""Every count of readings (``step_confirm``, ``manoeuvre_frames``, ``noise_frames``,
``noise_slow_frames``) is at most this: 400 s at 250 Hz. Sane ones are tens to
hundreds; past it an average never settles in a run, and 1e20 readings is a typo."""


@dataclass(frozen=True, slots=True)
class FilterConfig:
    """Everything the filter needs to know about the sensor and the policy.

    Attributes:
        amp_ref: amp that corresponds to S = 1 (see AMP_REF_DEFAULT).
        s_min: dropout threshold on S (paper section III).
        amp_min: readings with a lower amp are weak (the sensor's own rule).
        min_range_m, max_range_m: range gate, metres.
        stale_after_s: seconds without an accepted reading before output is ``stale``
            (a dropout), and after which the next accepted reading restarts the track.
        sigma0_m: paper eq. 2 noise at zero ambient light and S = 1, metres.
        k_m_per_lux: paper eq. 2 growth of the noise with ambient light, metres per lux.
        resolution_m: output quantisation of the sensor, metres; its variance
            resolution^2 / 12 is added to every reading's variance.
        accel_psd: process noise of the constant-velocity model while the target
            holds its course, the spectral density of white acceleration, m^2/s^3:
            small, so that a still target is averaged like a mean (``lunad eval``).
        manoeuvre_accel_psd: the process noise while the manoeuvre test fires,
            m^2/s^3: a robot braking at 10 m/s^2, or a beam swept across a wall at
            90 deg/s, is followed within a few frames (10 missed fewest targets in
            ``lunad eval`` among 5, 10, 20 and 50).
        manoeuvre_sigmas: the manoeuvre test's threshold, in standard deviations of
            the innovations' fast running mean (3.5: at 3, the light jumps of
            ``cloud_flicker`` fired it on a still target four times in 10 s); the
            slow mean's is ``DRIFT_SIGMAS`` (range_filter.py).
        manoeuvre_frames: readings the innovations' fast running mean spans (the
            slow one, and their mean square, span five times as many); also how
            long the raised process noise is held after the test last fired. In
            frames, not seconds: a test's power depends on how many readings it
            has seen.
        init_speed_sigma_m_s: one-sigma prior on the target's speed when a track
            starts, metres per second: a robot's or a person's 3 m/s, so a track
            that restarts on a target already moving (a beam sweeping a wall after a
            weak stretch) learns its speed from the next readings instead of lagging
            behind a prior that says "still".
        gate_sigmas: innovation gate; a reading whose innovation exceeds this many
            predicted sigmas is an ``outlier``.
        step_confirm: this many consecutive outliers that agree with each other are
            a real step: the track restarts there.
        noise_frames: readings the fast noise average spans (noise.py): it follows
            a cloud or a lamp, and weights each reading (r = c^2 / S^2 + q). Above
            17 the noise is booted from the first readings after a start and no
            estimate is published until then (noise.py, ``NOISE_BOOT_SAMPLES``).
        noise_slow_frames: readings the slow noise average spans: the one
            ``lux_est``, the zone and ``high_ambient`` use.
        noise_jump_ratio: when the fast and slow averages part by more than this
            factor the light has changed and the slow one restarts from the fast.
        noise_clip_sigmas: second differences beyond this many of their own
            standard deviations are clipped before they count (steps, spikes).
        lux_observable_sigma_m: below this reading noise, metres, the 1 cm output
            steps hide the light and ``lux_est`` is null: half the step, where the
            steps' variance is within 2 % of the noise's wherever the target sits
            between two of them (noise.py).
        lux_init: ambient light assumed before the noise is measured, lux.
        sigma_floor_m: the published sigma never goes below this, metres: how far
            averaging 1 cm output steps that the noise dithers can be trusted.
        hysteresis: relative band around the amp, S and ambient-lux thresholds: a
            state is entered at the threshold and left only this fraction beyond it.
            10 % is about three sigma of the amp's own jitter.
        zone_hysteresis: the same for the zone thresholds (lux, S, sigma), which
            move more from frame to frame.
        range_hysteresis_m: band of the range gate, metres.
        range_feed_margin_m: readings up to this far beyond max_range_m still feed
            the filter (not published), so that the gate does not bias it, metres.
        lux_high_ambient: estimated lux above which output is ``degraded`` with
            reason ``high_ambient``.
        lux_stable_max, s_stable_min, sigma_stable_max_m: the ``stable`` zone needs
            all three (paper's stable region, section V).
        lux_unreliable, s_unreliable, sigma_unreliable_m: any one makes the zone
            ``unreliable``.
    """

    amp_ref: float = AMP_REF_DEFAULT
    s_min: float = S_MIN_PAPER
    amp_min: int = AMP_MIN
    min_range_m: float = MIN_RANGE_M
    max_range_m: float = MAX_RANGE_M
    stale_after_s: float = 0.5
    sigma0_m: float = SIGMA0_DEFAULT_M
    k_m_per_lux: float = K_DEFAULT_M_PER_LUX
    resolution_m: float = RESOLUTION_M
    accel_psd: float = 1e-4
    manoeuvre_accel_psd: float = 10.0
    manoeuvre_sigmas: float = 3.5
    manoeuvre_frames: int = 10
    init_speed_sigma_m_s: float = 3.0
    gate_sigmas: float = 4.0
    step_confirm: int = 2
    noise_frames: int = 25
    noise_slow_frames: int = 250
    noise_jump_ratio: float = 1.7
    noise_clip_sigmas: float = 2.0
    lux_observable_sigma_m: float = 0.005
    lux_init: float = 0.0
    sigma_floor_m: float = 0.001
    hysteresis: float = 0.1
    zone_hysteresis: float = 0.2
    range_hysteresis_m: float = 0.05
    range_feed_margin_m: float = 1.0
    lux_high_ambient: float = LUX_HIGH_AMBIENT
    lux_stable_max: float = LUX_STABLE_MAX
    s_stable_min: float = S_STABLE_MIN
    sigma_stable_max_m: float = 0.02
    lux_unreliable: float = 50_000.0
    s_unreliable: float = 0.1
    sigma_unreliable_m: float = 0.10

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            zero_ok = f.name in (
                "lux_init",
                "hysteresis",
                "zone_hysteresis",
                "range_hysteresis_m",
                "range_feed_margin_m",
                "accel_psd",
            )
            if not (value >= 0 if zero_ok else value > 0):
                must = "0 or more" if zero_ok else "positive"
                raise ValueError(f"FilterConfig.{f.name} must be {must}, got {value!r}")
            if isinstance(value, float) and not (
                VALUE_MIN <= value <= VALUE_MAX or (zero_ok and value == 0.0)
            ):
                raise ValueError(
                    f"FilterConfig.{f.name} must be {'0 or ' if zero_ok else ''}between"
                    f" {VALUE_MIN:g} and {VALUE_MAX:g}, got {value!r}"
                )
        if self.amp_min > AMP_AMBIENT:
            raise ValueError(
                f"FilterConfig.amp_min must be at most {AMP_AMBIENT} (an amp above it is"
                f" ambient overexposure, M05 p.14, never a reading), got {self.amp_min!r}"
            )
        for name in ("step_confirm", "manoeuvre_frames", "noise_frames", "noise_slow_frames"):
            if getattr(self, name) > COUNT_MAX:
                raise ValueError(
                    f"FilterConfig.{name} must be at most {COUNT_MAX} readings, got"
                    f" {getattr(self, name)!r}"
                )
        if self.min_range_m >= self.max_range_m:
            raise ValueError("FilterConfig.min_range_m must be below max_range_m")
        if self.step_confirm < 1:
            raise ValueError("FilterConfig.step_confirm must be at least 1")
        for name in ("manoeuvre_frames", "noise_frames", "noise_slow_frames"):
            if getattr(self, name) < 2:
                raise ValueError(f"FilterConfig.{name} must be at least 2 readings")
        if self.noise_slow_frames < self.noise_frames:
            raise ValueError(
                f"FilterConfig.noise_slow_frames ({self.noise_slow_frames}) must be at least "
                f"noise_frames ({self.noise_frames}): the slow noise average is the longer "
                "one (docs/filter.md section 3); raise it or lower noise_frames"
            )
        if self.noise_jump_ratio <= 1.0:
            raise ValueError(
                f"FilterConfig.noise_jump_ratio must be above 1, got {self.noise_jump_ratio!r}"
            )
        for name in ("hysteresis", "zone_hysteresis"):
            if getattr(self, name) >= 1.0:
                raise ValueError(
                    f"FilterConfig.{name} must be below 1 (a fraction: 0.1 is 10 %), got"
                    f" {getattr(self, name)!r}; at 1 or more a band is never left"
                )
        if 2.0 * self.range_hysteresis_m >= self.max_range_m - self.min_range_m:
            raise ValueError(
                "FilterConfig.range_hysteresis_m must be under half of max_range_m -"
                f" min_range_m, got {self.range_hysteresis_m!r}; out of range would"
                " never be left"
            )
