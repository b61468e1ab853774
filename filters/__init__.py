"""Pure computation on readings: gates, dropout policy, adaptive filter, lux estimate."""

from lunad.filters.config import AMP_REF_DEFAULT, FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status, Zone
from lunad.filters.range_filter import RangeFilter

__all__ = [
    "AMP_REF_DEFAULT",
    "Estimate",
    "FilterConfig",
    "RangeFilter",
    "Reason",
    "Status",
    "Zone",
]
