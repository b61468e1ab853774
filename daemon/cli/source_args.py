"""Command-line flags that choose and set up a source, shared by every sub-command
that talks to a sensor (python-can's ``add_bus_arguments`` pattern)."""

from __future__ import annotations

import argparse

from lunad.daemon.errors import ConfigError


def add_source_args(p: argparse.ArgumentParser) -> None:
    """The flags that choose and set up a source; shared by serve, record and calibrate."""
    p.add_argument("--config", metavar="FILE", help="TOML config file")
    p.add_argument("--device", help="serial device path or pyserial URL (default /dev/serial0)")
    p.add_argument("--baud", help="baud rate (default 115200)")
    p.add_argument("--bus", help="read over I2C from /dev/i2c-BUS instead ('sim': simulated)")
    p.add_argument("--address", help="I2C address (default 0x10)")
    p.add_argument("--rate", metavar="HZ", help="frame rate to set at start (default 100)")
    p.add_argument(
        "--output-format",
        choices=("cm", "mm"),
        help="distance unit to set at start and read frames in (default cm; UART only)",
    )
    p.add_argument(
        "--no-configure",
        action="store_true",
        help="do not query the version or set rate and output at start",
    )
    p.add_argument("--log-level", choices=("debug", "info", "warning", "error"))


def source_overrides(args: argparse.Namespace) -> dict[str, object]:
    """Config overrides (dotted field -> value) from ``add_source_args`` flags.

    Raises:
        ConfigError: flags name two sources (``--device`` with ``--bus``, ``--replay``
            with either): which one the user meant is not ours to guess.
    """
    given = [
        flag
        for flag, value in (
            ("--replay", getattr(args, "replay", None)),
            ("--bus", args.bus),
            ("--device", args.device),
        )
        if value is not None
    ]
    if len(given) > 1:
        raise ConfigError(f"{' and '.join(given)} name different sources; give one of them")
    kind = {"--replay": "replay", "--bus": "i2c", "--device": "serial"}[given[0]] if given else None
    return {
        "source.kind": kind,
        "source.device": args.device,
        "source.baud": args.baud,
        "source.bus": args.bus,
        "source.address": args.address,
        "sensor.frame_rate_hz": args.rate,
        "sensor.configure": False if args.no_configure else None,
        "sensor.output_format": args.output_format,
        "log_level": args.log_level,
    }
