"""Virtual TF-Luna: sensor physics, scenarios, a pty device, the paper sweep."""

from lunad.sim.physics import AMP_REF, PaperSensor, RawReading, Truth

__all__ = ["AMP_REF", "PaperSensor", "RawReading", "Truth"]
