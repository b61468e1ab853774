"""I/O and lifecycle: config, sources, publisher, health, the CLI."""

__version__ = "0.1.0"

__all__ = ["__version__"]
