"""Pure computation on readings: gates, dropout policy, adaptive filter, lux estimate."""

from lunad.filters.config import AMP_REF_DEFAULT, FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status, Zone
from lunad.filters.kalman import ACCEPTED, OUTLIER, RESTARTED, Tracker
from lunad.filters.lux import LuxEstimator
from lunad.filters.policy import DropoutPolicy
from lunad.filters.range_filter import RangeFilter
from lunad.filters.reference import ReferenceFilter
from lunad.filters.zone import ZoneClassifier

__all__ = [
    "ACCEPTED",
    "AMP_REF_DEFAULT",
    "OUTLIER",
    "RESTARTED",
    "DropoutPolicy",
    "Estimate",
    "FilterConfig",
    "LuxEstimator",
    "RangeFilter",
    "Reason",
    "ReferenceFilter",
    "Status",
    "Tracker",
    "Zone",
    "ZoneClassifier",
]
