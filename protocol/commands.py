"""TF-Luna UART command frames: ``5A Len ID payload CS`` (docs/tfluna.md section 2).

``Len`` is the total frame length including head and checksum, ``CS`` the low 8 bits
of the sum of every byte before it, payloads are little-endian (M05 p.12-13, M01 p.14).
Checksums are computed here, never copied: the manuals' tables have typos (docs/tfluna.md
section 2.3). Encoders raise ``ValueError`` for values the sensor does not accept
(caller misuse); decoding what the sensor sent never raises, see ``decode_reply``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from lunad.protocol.frame import OutputFormat, checksum

COMMAND_HEADER = b"\x5a"  # command and reply frames, M05 p.12
COMMAND_HEADER_BYTE = 0x5A


class CommandId(IntEnum):
    """Command IDs of A05 firmware (M05 App. II p.26-33, docs/tfluna.md section 2.2)."""

    GET_VERSION = 0x01
    SOFT_RESET = 0x02
    SAMPLE_FREQ = 0x03
    SAMPLE_TRIG = 0x04
    OUTPUT_FORMAT = 0x05
    BAUD_RATE = 0x06
    OUTPUT_EN = 0x07
    FRAME_CHECKSUM_EN = 0x08
    I2C_SLAVE_ADDR = 0x0B
    RESTORE_DEFAULT = 0x10
    SAVE_SETTINGS = 0x11
    READ_MANU_BIN = 0x12
    GET_FULL_VERSION = 0x14
    AMP_THRESHOLD = 0x22
    DIST_LIMIT = 0x3A


REPLY_LENGTHS: dict[int, int] = {
    CommandId.GET_VERSION: 7,
    CommandId.SOFT_RESET: 5,
    CommandId.SAMPLE_FREQ: 6,
    CommandId.OUTPUT_FORMAT: 5,
    CommandId.BAUD_RATE: 8,
    CommandId.OUTPUT_EN: 5,
    CommandId.FRAME_CHECKSUM_EN: 5,
    CommandId.I2C_SLAVE_ADDR: 5,
    CommandId.RESTORE_DEFAULT: 5,
    CommandId.SAVE_SETTINGS: 5,
    CommandId.READ_MANU_BIN: 18,
    CommandId.GET_FULL_VERSION: 30,
    CommandId.AMP_THRESHOLD: 7,
    CommandId.DIST_LIMIT: 9,
}
"""Total length of each reply the sensor sends (docs/tfluna.md section 2.2; 0x12 and 0x14 computed
from their layouts). The parser accepts a ``5A`` frame only with a known (ID, Len)
pair, so a stray 0x5A in garbage costs at most 30 bytes of look-ahead."""

MAX_REPLY_LEN = max(REPLY_LENGTHS.values())

FRAME_RATES_HZ: frozenset[int] = frozenset({0} | {500 // n for n in range(2, 501)})
"""Frame rates the sensor accepts: 500/n Hz for n in 2..500, and 0 for trigger mode
(M05 p.9, p.15)."""

BAUD_RATES: tuple[int, ...] = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
"""Documented baud rates (M05 p.27-28)."""

I2C_ADDRESS_MIN, I2C_ADDRESS_MAX = 0x08, 0x77  # M05 p.13, p.34


@dataclass(frozen=True, slots=True)
class CommandReply:
    """A ``5A`` reply the sensor sent, checksum verified.

    Attributes:
        cmd_id: the command ID it answers.
        payload: the bytes between ID and checksum.
        t_mono_ns: monotonic time its last byte was read.
    """

    cmd_id: int
    payload: bytes
    t_mono_ns: int


@dataclass(frozen=True, slots=True)
class Version:
    """Firmware version from a GET_VERSION reply (bytes 3,4,5 = revision, minor, major)."""

    major: int
    minor: int
    revision: int

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}.{self.revision}"


@dataclass(frozen=True, slots=True)
class AmpThreshold:
    """Amp threshold (amp units) and the dummy distance (cm) reported below it."""

    amp: int
    dummy_dist_cm: int


@dataclass(frozen=True, slots=True)
class DistanceLimits:
    """Output distance limits in centimetres; with ``silence`` nothing is sent outside."""

    min_cm: int
    max_cm: int
    silence: bool


ReplyValue = Version | bool | int | str | OutputFormat | AmpThreshold | DistanceLimits | bytes


def encode_command(cmd_id: int, payload: bytes = b"") -> bytes:
    """Frame ``payload`` as command ``cmd_id`` with length and a computed checksum."""
    length = 4 + len(payload)
    if length > 255:
        raise ValueError(f"payload too long for one command frame: {len(payload)} bytes")
    body = bytes((COMMAND_HEADER_BYTE, length, cmd_id)) + payload
    return body + bytes((checksum(body),))


def get_version() -> bytes:
    """``5A 04 01 5F``: ask for the firmware version."""
    return encode_command(CommandId.GET_VERSION)


def soft_reset() -> bytes:
    """``5A 04 02 60``: restart the sensor."""
    return encode_command(CommandId.SOFT_RESET)


def set_frame_rate(hz: int) -> bytes:
    """Set the output rate in Hz; 0 selects trigger mode (M05 p.15).

    Raises:
        ValueError: ``hz`` is not 0 and not 500/n for an integer n in 2..500.
    """
    if hz not in FRAME_RATES_HZ:
        raise ValueError(f"frame rate must be 0 (trigger) or 500/n Hz (1..250), got {hz}")
    return encode_command(CommandId.SAMPLE_FREQ, struct.pack("<H", hz))


def trigger() -> bytes:
    """``5A 04 04 62``: measure once (trigger mode); the sensor answers with a data frame."""
    return encode_command(CommandId.SAMPLE_TRIG)


def set_output_format(fmt: OutputFormat) -> bytes:
    """Select the data frame format; lunad parses cm (0x01) and mm (0x06)."""
    return encode_command(CommandId.OUTPUT_FORMAT, bytes((OutputFormat(fmt),)))


def set_baud_rate(baud: int) -> bytes:
    """Change the UART baud rate (takes effect at once; save to keep it).

    Raises:
        ValueError: ``baud`` is not one of ``BAUD_RATES``.
    """
    if baud not in BAUD_RATES:
        raise ValueError(f"baud rate must be one of {BAUD_RATES}, got {baud}")
    return encode_command(CommandId.BAUD_RATE, struct.pack("<I", baud))


def set_output_enabled(enabled: bool) -> bytes:
    """Turn the data frame output on or off."""
    return encode_command(CommandId.OUTPUT_EN, bytes((int(enabled),)))


def set_checksum_enabled(enabled: bool) -> bytes:
    """Make the sensor check inbound command checksums (off by default, M05 p.13)."""
    return encode_command(CommandId.FRAME_CHECKSUM_EN, bytes((int(enabled),)))


def set_i2c_address(address: int) -> bytes:
    """Set the 7-bit I2C slave address.

    Raises:
        ValueError: ``address`` is outside 0x08..0x77.
    """
    if not I2C_ADDRESS_MIN <= address <= I2C_ADDRESS_MAX:
        raise ValueError(f"I2C address must be in 0x08..0x77, got {address:#04x}")
    return encode_command(CommandId.I2C_SLAVE_ADDR, bytes((address,)))


def set_amp_threshold(amp: int, dummy_dist_cm: int = 0) -> bytes:
    """Report ``dummy_dist_cm`` whenever amp is below ``amp`` (M05 p.30).

    The wire field is amp / 10 in one byte, so ``amp`` must be a multiple of 10
    in 0..2550.

    Raises:
        ValueError: ``amp`` or ``dummy_dist_cm`` is out of range.
    """
    if amp % 10 or not 0 <= amp <= 2550:
        raise ValueError(f"amp threshold must be a multiple of 10 in 0..2550, got {amp}")
    if not 0 <= dummy_dist_cm <= 0xFFFF:
        raise ValueError(f"dummy distance must be in 0..65535 cm, got {dummy_dist_cm}")
    return encode_command(CommandId.AMP_THRESHOLD, struct.pack("<BH", amp // 10, dummy_dist_cm))


def set_distance_limits(min_cm: int, max_cm: int, silence: bool = False) -> bytes:
    """Limit output distances to [min_cm, max_cm] (M05 p.32).

    Raises:
        ValueError: the limits are not 0 <= min_cm <= max_cm <= 65535.
    """
    if not 0 <= min_cm <= max_cm <= 0xFFFF:
        raise ValueError(f"need 0 <= min_cm <= max_cm <= 65535, got {min_cm}, {max_cm}")
    payload = struct.pack("<HHB", min_cm, max_cm, int(silence))
    return encode_command(CommandId.DIST_LIMIT, payload)


def save_settings() -> bytes:
    """``5A 04 11 6F``: persist the current settings (lost on power cycle otherwise)."""
    return encode_command(CommandId.SAVE_SETTINGS)


def restore_defaults() -> bytes:
    """``5A 04 10 6E``: restore factory settings."""
    return encode_command(CommandId.RESTORE_DEFAULT)


def read_serial_number() -> bytes:
    """``5A 04 12 70``: ask for the 14-character production code."""
    return encode_command(CommandId.READ_MANU_BIN)


def get_full_version() -> bytes:
    """``5A 04 14 72``: ask for the 30-byte ASCII full version."""
    return encode_command(CommandId.GET_FULL_VERSION)


def startup(rate_hz: int, fmt: OutputFormat = OutputFormat.CM) -> bytes:
    """What a host sends at connect: firmware version query, the output format its
    parser reads (a sensor saved in mm, read as cm, would give 2 m as 20), frame rate,
    output on, serial number."""
    return (
        get_version()
        + set_output_format(fmt)
        + set_frame_rate(rate_hz)
        + set_output_enabled(True)
        + read_serial_number()
    )


def decode_reply(reply: CommandReply) -> ReplyValue:
    """The value a reply carries, typed by its command.

    Status replies (reset, save, restore) give True on success. A reply whose
    payload does not have the expected size comes back as its raw payload bytes,
    so that a firmware oddity is visible rather than fatal.
    """
    p = reply.payload
    cid = reply.cmd_id
    try:
        if cid == CommandId.GET_VERSION:
            return Version(major=p[2], minor=p[1], revision=p[0])
        if cid in (CommandId.SOFT_RESET, CommandId.SAVE_SETTINGS, CommandId.RESTORE_DEFAULT):
            return p[0] == 0 and len(p) == 1
        if cid == CommandId.SAMPLE_FREQ:
            return int(struct.unpack("<H", p)[0])
        if cid == CommandId.OUTPUT_FORMAT:
            try:
                return OutputFormat(p[0])
            except ValueError:
                return int(p[0])
        if cid == CommandId.BAUD_RATE:
            return int(struct.unpack("<I", p)[0])
        if cid in (CommandId.OUTPUT_EN, CommandId.FRAME_CHECKSUM_EN):
            return bool(p[0])
        if cid == CommandId.I2C_SLAVE_ADDR:
            return int(p[0])
        if cid == CommandId.AMP_THRESHOLD:
            thr, dummy = struct.unpack("<BH", p)
            return AmpThreshold(amp=thr * 10, dummy_dist_cm=dummy)
        if cid == CommandId.DIST_LIMIT:
            lo, hi, silence = struct.unpack("<HHB", p)
            return DistanceLimits(min_cm=lo, max_cm=hi, silence=bool(silence))
        if cid in (CommandId.READ_MANU_BIN, CommandId.GET_FULL_VERSION):
            return p.decode("ascii", errors="replace")
    except (IndexError, struct.error):
        pass
    return bytes(p)


def encode_reply(cmd_id: int, payload: bytes) -> bytes:
    """A reply frame as the sensor sends it (the virtual sensor uses this)."""
    return encode_command(cmd_id, payload)


MIN_COMMAND_LEN = 4  # 5A Len ID CS: the shortest command (M05 p.13)


def take_command_frames(buf: bytearray) -> list[bytes]:
    """Take every complete ``5A`` command out of ``buf`` (host to sensor direction),
    each whole from header to checksum byte.

    Bytes before a header are dropped; an incomplete command stays in ``buf``.
    """
    out: list[bytes] = []
    while True:
        start = buf.find(COMMAND_HEADER)
        if start < 0:
            buf.clear()
            return out
        if start:
            del buf[:start]
        if len(buf) < 2:
            return out
        length = buf[1]
        if length < MIN_COMMAND_LEN:
            del buf[:1]
            continue
        if len(buf) < length:
            return out
        out.append(bytes(buf[:length]))
        del buf[:length]


def split_commands(buf: bytearray) -> list[tuple[int, bytes]]:
    """``take_command_frames`` as ``(cmd_id, payload)`` pairs, in order.

    Checksums are not checked, as the sensor does not check them by default
    (M05 p.13); the virtual sensor, which must once ID 0x08 turns checking on,
    takes the whole frames.
    """
    return [(frame[2], frame[3:-1]) for frame in take_command_frames(buf)]
