"""The filter's per-reading output: what the daemon publishes about one frame."""

from __future__ import annotations

from enum import StrEnum
from typing import NamedTuple


class Status(StrEnum):
    """How far robot code can trust ``range_m`` (docs/messages.md)."""

    OK = "ok"
    DEGRADED = "degraded"
    DROPOUT = "dropout"


class Reason(StrEnum):
    """Why a reading is not ``ok`` (docs/messages.md says what each means to a robot)."""

    WEAK_SIGNAL = "weak_signal"
    SATURATED = "saturated"
    TOO_CLOSE = "too_close"
    TOO_FAR = "too_far"
    NO_DISTANCE = "no_distance"
    OUTLIER = "outlier"
    HIGH_AMBIENT = "high_ambient"
    UNRELIABLE_ZONE = "unreliable_zone"
    STALE = "stale"


class Zone(StrEnum):
    """Operating zone after the paper's stable region (lux < 10 klux, R > 0.5, angle < 45 deg)."""

    STABLE = "stable"
    MARGINAL = "marginal"
    UNRELIABLE = "unreliable"


class Estimate(NamedTuple):
    """The cleaned reading for one frame (immutable; a ``NamedTuple``, see ``Frame``).

    Attributes:
        range_m: filtered distance in metres, or None when there is no trustworthy estimate.
        sigma_m: one-sigma uncertainty of ``range_m`` in metres, or None with it.
        lux_est: ambient light estimate in lux, or None before there is one.
        strength: S = amp / amp_ref (dimensionless).
        status: ok, degraded or dropout (then ``range_m`` is None).
        reasons: why not ok, in a stable order; empty when ok.
        zone: stable, marginal or unreliable.
    """

    range_m: float | None
    sigma_m: float | None
    lux_est: float | None
    strength: float
    status: Status
    reasons: tuple[Reason, ...]
    zone: Zone
