"""The service that runs on the robot: the serve loop (``serve.Daemon``), config,
publisher, health, systemd notify and the frame clock. Its rooms: ``sources/`` (where
bytes come from, record and replay), ``cli/`` (the ``lunad`` command, one module per
sub-command) and ``tools/`` (bench and soak). Nothing is re-exported here: ``lunad
--help`` and the bench's floor import this package and must not pay for pydantic or pyzmq.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
