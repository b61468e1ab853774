"""TF-Luna UART data frames: the 9-byte ``59 59 Dist Amp Temp CS`` frame.

Layout (TF-Luna manual M05 p.24, docs/tfluna.md section 1.2), little-endian::

    byte  0    1    2      3      4     5     6      7      8
          0x59 0x59 Dist_L Dist_H Amp_L Amp_H Temp_L Temp_H CS

``CS`` is the low 8 bits of the sum of bytes 0..7 (M05 p.13). Distance is in
centimetres in format 0x01 and millimetres in format 0x06; temperature is
``raw / 8 - 256`` degrees Celsius (M05 p.14).
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import NamedTuple

DATA_HEADER = b"\x59\x59"  # UART data frame header, M05 p.24 (docs/tfluna.md section 1.2)
DATA_HEADER_BYTE = 0x59
DATA_FRAME_LEN = 9  # M05 p.24

AMP_MIN_VALID = 100  # Dist unreliable below this amp; sensor outputs dummy 0 (M05 p.14, p.16)
AMP_AMBIENT_OVEREXPOSED = 32768  # amp above this: ambient overexposure, e.g. sun (M05 p.14)
AMP_SATURATED = 0xFFFF  # amp 65535: overexposure (M05 p.14, p.24)
DIST_INVALID_A01 = 0xFFFF  # early A01 firmware reports -1 for a weak signal (M01 p.11)

TEMP_OPERATING_C = (-10.0, 60.0)  # ambient operating range, DS p.2, M05 p.8 (docs/tfluna.md §5)
TEMP_PLAUSIBLE_MIN_C = -40.0
TEMP_PLAUSIBLE_MAX_C = 100.0
"""Chip temperatures a real frame can carry. The field is the chip's own temperature,
which runs warm above ambient (M01 p.18 Q2), so the window is the operating range
widened by 30 degC below (a sensor started cold outside its spec, before it warms
itself) and 40 degC above (self-heating at 60 degC ambient in the sun). A window that
garbage forms over a real frame carries a random temperature field; 1121 of the 65536
raw values fall inside, so the check rejects 98 % of such false frames by itself."""
TEMP_RAW_MIN = round((TEMP_PLAUSIBLE_MIN_C + 256.0) * 8.0)  # 1728; raw/8 - 256 (M05 p.14)
TEMP_RAW_MAX = round((TEMP_PLAUSIBLE_MAX_C + 256.0) * 8.0)  # 2848

_FRAME = struct.Struct("<2sHHHB")


class OutputFormat(IntEnum):
    """UART output formats with a 9-byte data frame (ID 0x05, M05 p.24)."""

    CM = 0x01
    MM = 0x06


_CM = OutputFormat.CM
"""Looked up once: an enum member read through its class costs ~0.2 us in Python 3.11."""


class Frame(NamedTuple):
    """One data frame as the sensor sent it.

    Immutable; a ``NamedTuple`` rather than a frozen dataclass because one is made per
    frame on the hot path and a frozen dataclass costs about twice as much to build.

    Attributes:
        dist: raw distance field, in the unit of ``fmt`` (centimetres or millimetres).
        amp: signal strength the sensor reported (dimensionless, 0..65535).
        temp_raw: raw temperature field; see ``temp_c``.
        t_mono_ns: ``time.monotonic_ns()`` when the frame's last byte was read.
        fmt: the output format the frame was parsed in.
    """

    dist: int
    amp: int
    temp_raw: int
    t_mono_ns: int
    fmt: OutputFormat = OutputFormat.CM

    @property
    def temp_c(self) -> float:
        """Chip temperature in degrees Celsius (UART scaling, M05 p.14)."""
        return self.temp_raw / 8.0 - 256.0

    @property
    def distance_m(self) -> float | None:
        """Reported distance in metres, or None when the sensor reported none.

        The sensor reports no distance as dummy 0 (A03+ firmware) or 0xFFFF
        (A01 firmware); both read as None here.
        """
        dist = self.dist
        if dist == 0 or dist == DIST_INVALID_A01:
            return None
        return dist / 100.0 if self.fmt is _CM else dist / 1000.0


def checksum(data: bytes | bytearray | memoryview) -> int:
    """Low 8 bits of the byte sum (data frames and command frames, M05 p.13)."""
    return sum(data) & 0xFF


def encode_frame(dist: int, amp: int, temp_raw: int) -> bytes:
    """Encode a 9-byte data frame with a correct checksum.

    Raises:
        ValueError: a field does not fit in an unsigned 16-bit integer.
    """
    for name, value in (("dist", dist), ("amp", amp), ("temp_raw", temp_raw)):
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"{name} must be in 0..65535, got {value}")
    body = _FRAME.pack(DATA_HEADER, dist, amp, temp_raw, 0)[:8]
    return body + bytes((checksum(body),))


def temp_raw_from_c(temp_c: float) -> int:
    """Inverse of ``Frame.temp_c``: the raw field for a temperature in Celsius."""
    return max(0, min(0xFFFF, round((temp_c + 256.0) * 8.0)))
