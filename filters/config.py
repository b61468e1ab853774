"""Filter settings: plain values, validated at the daemon's config boundary."""

from __future__ import annotations

from dataclasses import dataclass

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


@dataclass(frozen=True, slots=True)
class FilterConfig:
    """Everything the filter needs to know about the sensor and the policy.

    Attributes:
        amp_ref: amp that corresponds to S = 1 (see AMP_REF_DEFAULT).
        s_min: dropout threshold on S.
        amp_min: readings with a lower amp are weak (the sensor's own rule).
        min_range_m, max_range_m: range gate, metres.
        stale_after_s: seconds without a valid reading before readings are `stale`.
    """

    amp_ref: float = AMP_REF_DEFAULT
    s_min: float = S_MIN_PAPER
    amp_min: int = AMP_MIN
    min_range_m: float = MIN_RANGE_M
    max_range_m: float = MAX_RANGE_M
    stale_after_s: float = 0.5
