"""The TF-Luna's command behaviour, without I/O: settings in, reply bytes out.

How this works: ``handle`` takes one host command (ID and payload) and returns the
bytes the sensor would send back, with valid checksums (docs/tfluna.md section 2.2-2.3): an echo
for settings, a status byte for reset/save/restore, a data frame for a trigger.
Settings change at once and survive a soft reset only after a save (M05 p.13).
Unknown IDs get no answer (the manual does not document one; docs/tfluna.md section 2.2).

Inbound checksums: the sensor accepts any checksum byte until the host turns checking
on with ID 0x08 (docs/tfluna.md section 2.1, M05 p.13). After that a command with a wrong checksum
is not carried out. What the sensor sends back for it is undocumented (docs/tfluna.md section 2.2
notes and section 9), so, as for an unknown ID, the virtual sensor sends nothing.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, replace

from lunad.protocol import commands
from lunad.protocol.commands import CommandId
from lunad.protocol.frame import OutputFormat, checksum, encode_frame

DEFAULT_RATE_HZ = 100  # M05 p.9
FIRMWARE = (3, 0, 9)  # major, minor, revision: a real unit's version (docs/tfluna.md section 2.3)
SERIAL_NUMBER = b"LUNADSIM000001"  # 14 ASCII bytes like "U0900018010001"


@dataclass(frozen=True, slots=True)
class Settings:
    """What a command can change. Defaults are the factory settings (M05 App. II)."""

    rate_hz: int = DEFAULT_RATE_HZ
    output_enabled: bool = True
    fmt: OutputFormat = OutputFormat.CM
    baud: int = 115200
    checksum_enabled: bool = False
    i2c_address: int = 0x10
    amp_threshold: int = 100
    dummy_dist_cm: int = 0
    min_dist_cm: int = 0
    max_dist_cm: int = 900
    silence: bool = False


class VirtualSensor:
    """Settings and command handling of one virtual TF-Luna."""

    def __init__(self, settings: Settings | None = None) -> None:
        self.saved = settings or Settings()
        self.settings = self.saved
        self.trigger_pending = 0
        self.resets = 0
        self.bad_checksums = 0
        """Commands ignored for a wrong checksum while checking was on."""

    def handle_frame(self, frame: bytes) -> bytes:
        """Apply one whole command frame (``5A Len ID payload CS``); return the reply.

        With checksum checking on (ID 0x08) a frame whose checksum is wrong is
        ignored and gets no reply (module docstring); otherwise as ``handle``.
        """
        if self.settings.checksum_enabled and checksum(frame[:-1]) != frame[-1]:
            self.bad_checksums += 1
            return b""
        return self.handle(frame[2], frame[3:-1])

    def handle(self, cmd_id: int, payload: bytes) -> bytes:
        """Apply one command; return the reply bytes (possibly empty).

        A trigger returns no bytes here: it raises ``trigger_pending`` and the device
        sends a fresh data frame, as the sensor measures on demand.
        """
        s = self.settings
        reply = commands.encode_reply
        try:
            if cmd_id == CommandId.GET_VERSION:
                major, minor, rev = FIRMWARE
                return reply(cmd_id, bytes((rev, minor, major)))
            if cmd_id == CommandId.SOFT_RESET:
                self.settings = self.saved
                self.resets += 1
                return reply(cmd_id, b"\x00")
            if cmd_id == CommandId.SAMPLE_FREQ:
                (hz,) = struct.unpack("<H", payload)
                if hz in commands.FRAME_RATES_HZ:
                    self.settings = replace(s, rate_hz=hz)
                return reply(cmd_id, struct.pack("<H", self.settings.rate_hz))
            if cmd_id == CommandId.SAMPLE_TRIG:
                self.trigger_pending += 1
                return b""
            if cmd_id == CommandId.OUTPUT_FORMAT:
                if payload[0] in (OutputFormat.CM, OutputFormat.MM):
                    self.settings = replace(s, fmt=OutputFormat(payload[0]))
                return reply(cmd_id, bytes((self.settings.fmt,)))
            if cmd_id == CommandId.BAUD_RATE:
                (baud,) = struct.unpack("<I", payload)
                self.settings = replace(s, baud=baud)
                return reply(cmd_id, payload)
            if cmd_id == CommandId.OUTPUT_EN:
                self.settings = replace(s, output_enabled=bool(payload[0]))
                return reply(cmd_id, bytes((int(self.settings.output_enabled),)))
            if cmd_id == CommandId.FRAME_CHECKSUM_EN:
                self.settings = replace(s, checksum_enabled=bool(payload[0]))
                return reply(cmd_id, payload[:1])
            if cmd_id == CommandId.I2C_SLAVE_ADDR:
                self.settings = replace(s, i2c_address=payload[0])
                return reply(cmd_id, payload[:1])
            if cmd_id == CommandId.AMP_THRESHOLD:
                thr, dummy = struct.unpack("<BH", payload)
                self.settings = replace(s, amp_threshold=thr * 10, dummy_dist_cm=dummy)
                return reply(cmd_id, payload)
            if cmd_id == CommandId.DIST_LIMIT:
                lo, hi, silence = struct.unpack("<HHB", payload)
                self.settings = replace(s, min_dist_cm=lo, max_dist_cm=hi, silence=bool(silence))
                return reply(cmd_id, payload)
            if cmd_id == CommandId.SAVE_SETTINGS:
                self.saved = s
                return reply(cmd_id, b"\x00")
            if cmd_id == CommandId.RESTORE_DEFAULT:
                self.settings = self.saved = Settings()
                return reply(cmd_id, b"\x00")
            if cmd_id == CommandId.READ_MANU_BIN:
                return reply(cmd_id, SERIAL_NUMBER)
        except (struct.error, IndexError):
            return b""
        return b""

    def data_frame(self, dist_cm: int | None, amp: int, temp_raw: int) -> bytes | None:
        """The frame the sensor sends for a measurement, or None when it sends nothing.

        The one place the amp threshold applies (ID 0x22; default 100): below it, or
        with no distance measured (``dist_cm`` None), the frame carries the dummy
        distance (M05 p.16, p.30; docs/tfluna.md section 4). A threshold lowered below 100
        therefore reports distances for weaker signals, as the sensor does. Then the
        distance limits (clamp, or silence, M05 p.32) and the output format (cm or mm).

        Args:
            dist_cm: measured distance, centimetres, or None for no distance.
            amp: signal strength, as sent.
            temp_raw: temperature field, as sent.
        """
        s = self.settings
        if dist_cm is None or amp < s.amp_threshold:
            dist_cm = s.dummy_dist_cm
        elif not s.min_dist_cm <= dist_cm <= s.max_dist_cm:
            if s.silence:
                return None
            dist_cm = min(max(dist_cm, s.min_dist_cm), s.max_dist_cm)
        dist = dist_cm * 10 if s.fmt is OutputFormat.MM else dist_cm
        return encode_frame(min(dist, 0xFFFF), amp, temp_raw)
