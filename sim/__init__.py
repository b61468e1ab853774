"""Virtual TF-Luna: sensor physics (two worlds), readings at edges, scenarios, a pty
device, the paper sweep, and the independent oracle ``lunad eval`` judges the filter
against."""

from lunad.sim.edges import EDGE_OLD_SHARES, mixed_truth
from lunad.sim.oracle import OracleKalman, run_oracle, tuned_oracle
from lunad.sim.physics import AMP_REF, PaperSensor, RawReading, RealisticSensor, Truth
from lunad.sim.shot_noise import ShotNoiseSensor

__all__ = [
    "AMP_REF",
    "EDGE_OLD_SHARES",
    "OracleKalman",
    "PaperSensor",
    "RawReading",
    "RealisticSensor",
    "ShotNoiseSensor",
    "Truth",
    "mixed_truth",
    "run_oracle",
    "tuned_oracle",
]
