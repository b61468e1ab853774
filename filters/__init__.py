"""Pure computation on readings: gates, noise measurement, adaptive filter, zone."""

from lunad.filters.config import AMP_REF_DEFAULT, FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status, Zone
from lunad.filters.range_filter import RangeFilter
from lunad.filters.zone import ZoneClassifier, ZoneLimits

__all__ = [
    "AMP_REF_DEFAULT",
    "Estimate",
    "FilterConfig",
    "RangeFilter",
    "Reason",
    "Status",
    "Zone",
    "ZoneClassifier",
    "ZoneLimits",
]
