"""argparse types the sub-commands share: a bad value is a usage error (exit 2) that
names the flag, before anything starts, instead of a run that does something else
(``--duration nan`` watching for ever, ``--count 0`` stopping at once)."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable


def positive_float(text: str) -> float:
    """A finite number above 0 (seconds, a noise factor)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def int_at_least(minimum: int, what: str | None = None) -> Callable[[str], int]:
    """An integer of at least ``minimum``, called ``what`` in errors."""
    said = what or f"an integer >= {minimum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {said}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {said}, got {value}")
        return value

    return parse


def sensor_name(text: str) -> str:
    """A sensor name as the daemon's topics carry it (``SENSOR_NAME_PATTERN``, which
    lives with the message models, imported here only when a name is given)."""
    from lunad.protocol.messages import SENSOR_NAME_PATTERN

    if re.fullmatch(SENSOR_NAME_PATTERN, text) is None:
        raise argparse.ArgumentTypeError(
            f"expected 1-64 letters, digits, '_', '.' or '-' (the daemon's [sensor] name), "
            f"got {text!r}"
        )
    return text
