"""TF-Luna I2C register map (A05 firmware, M05 Appendix III p.34-35; docs/tfluna.md section 3.2).

Registers are 8-bit and auto-increment, multi-byte values little-endian. In I2C mode
the distance is always centimetres and the temperature is 0.01 degC (unlike the UART
frame's raw/8 - 256). Read 0x00..0x07 in one block transaction so that distance, amp,
temperature and tick come from one sample (docs/tfluna.md section 3.3).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

I2C_ADDRESS_DEFAULT = 0x10  # 7-bit, M05 p.13
I2C_WRITE_SETTLE_S = 0.1  # wait after a write before reading back, M05 p.14
I2C_REBOOT_SETTLE_S = 1.0  # wait after a reboot, embedded-tfluna practice (docs/tfluna.md §3.4)
SIGNATURE = b"LUNA"  # registers 0x3C..0x3F on A05 firmware, M05 p.35
SAMPLE_BLOCK_LEN = 8  # DIST, AMP, TEMP, TICK: 0x00..0x07


class Register(IntEnum):
    """Register addresses (M05 p.34-35)."""

    DIST_LOW = 0x00
    DIST_HIGH = 0x01
    AMP_LOW = 0x02
    AMP_HIGH = 0x03
    TEMP_LOW = 0x04
    TEMP_HIGH = 0x05
    TICK_LOW = 0x06
    TICK_HIGH = 0x07
    ERROR_LOW = 0x08
    ERROR_HIGH = 0x09
    VERSION_REVISION = 0x0A
    VERSION_MINOR = 0x0B
    VERSION_MAJOR = 0x0C
    SN = 0x10  # 14 ASCII bytes, 0x10..0x1D
    ULTRA_LOW_POWER = 0x1F
    SAVE = 0x20
    SHUTDOWN_REBOOT = 0x21
    SLAVE_ADDR = 0x22
    MODE = 0x23
    TRIG_ONE_SHOT = 0x24
    ENABLE = 0x25
    FPS_LOW = 0x26
    FPS_HIGH = 0x27
    LOW_POWER = 0x28
    RESTORE_FACTORY_DEFAULTS = 0x29
    AMP_THR_LOW = 0x2A
    AMP_THR_HIGH = 0x2B
    DUMMY_DIST_LOW = 0x2C
    DUMMY_DIST_HIGH = 0x2D
    MIN_DIST_LOW = 0x2E
    MIN_DIST_HIGH = 0x2F
    MAX_DIST_LOW = 0x30
    MAX_DIST_HIGH = 0x31
    SIGNATURE = 0x3C  # 'L' 'U' 'N' 'A', 0x3C..0x3F


SN_LEN = 14
SAVE_VALUE = 0x01  # write to SAVE
REBOOT_VALUE = 0x02  # write to SHUTDOWN_REBOOT
TRIGGER_VALUE = 0x01  # write to TRIG_ONE_SHOT
RESTORE_VALUE = 0x01  # write to RESTORE_FACTORY_DEFAULTS


class Mode(IntEnum):
    """MODE register values (M05 p.35)."""

    CONTINUOUS = 0x00
    TRIGGER = 0x01


class Enable(IntEnum):
    """ENABLE register values, A05 polarity (1 = LiDAR on; M03 had it reversed,
    docs/tfluna.md §8)."""

    OFF = 0x00
    ON = 0x01


@dataclass(frozen=True, slots=True)
class RegisterSample:
    """One sample read from registers 0x00..0x07.

    Attributes:
        dist_cm: distance, centimetres.
        amp: signal strength.
        temp_centi_c: chip temperature, hundredths of a degree Celsius.
        tick: 16-bit sample counter; unchanged between two reads means no new sample.
    """

    dist_cm: int
    amp: int
    temp_centi_c: int
    tick: int

    @property
    def temp_c(self) -> float:
        """Chip temperature in degrees Celsius (I2C scaling, M05 p.34)."""
        return self.temp_centi_c / 100.0


def decode_sample(block: bytes | bytearray | list[int]) -> RegisterSample:
    """Decode the 8-byte block read from register 0x00.

    Raises:
        ValueError: the block is not 8 bytes long.
    """
    if len(block) != SAMPLE_BLOCK_LEN:
        raise ValueError(f"sample block must be {SAMPLE_BLOCK_LEN} bytes, got {len(block)}")
    dist, amp, temp, tick = struct.unpack("<HHHH", bytes(block))
    return RegisterSample(dist, amp, temp, tick)


def encode_sample(sample: RegisterSample) -> bytes:
    """The 8 register bytes for ``sample`` (the fake I2C sensor uses this)."""
    return struct.pack("<HHHH", sample.dist_cm, sample.amp, sample.temp_centi_c, sample.tick)
