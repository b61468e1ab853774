"""Command frames: byte-exact encodings (docs/tfluna.md section 2.3) and encode/decode round trips
through the virtual sensor and the parser, like h11's ConnectionPair."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from lunad.protocol import CommandReply, FrameParser, OutputFormat, commands
from lunad.protocol.commands import AmpThreshold, DistanceLimits, Version, decode_reply
from lunad.sim.virtual_sensor import VirtualSensor

EXACT = [
    (commands.get_version(), "5A 04 01 5F"),
    (commands.soft_reset(), "5A 04 02 60"),
    (commands.set_frame_rate(100), "5A 06 03 64 00 C7"),
    (commands.set_frame_rate(0), "5A 06 03 00 00 63"),
    (commands.trigger(), "5A 04 04 62"),
    (commands.set_output_format(OutputFormat.CM), "5A 05 05 01 65"),
    (commands.set_output_format(OutputFormat.MM), "5A 05 05 06 6A"),
    (commands.set_baud_rate(115200), "5A 08 06 00 C2 01 00 2B"),
    (commands.set_output_enabled(True), "5A 05 07 01 67"),
    (commands.set_output_enabled(False), "5A 05 07 00 66"),
    (commands.restore_defaults(), "5A 04 10 6E"),
    (commands.save_settings(), "5A 04 11 6F"),
    (commands.get_full_version(), "5A 04 14 72"),
    (commands.set_amp_threshold(300, 500), "5A 07 22 1E F4 01 96"),  # M05 p.30 example, CS computed
    (commands.set_frame_rate(1000 // 4), "5A 06 03 FA 00 5D"),
]


@pytest.mark.parametrize(("encoded", "expected"), EXACT)
def test_byte_exact(encoded: bytes, expected: str) -> None:
    assert encoded == bytes.fromhex(expected)


def test_status_reply_checksums_are_computed_not_copied() -> None:
    """The manuals print 5A 05 02 00 60 etc.; arithmetic gives one more (docs/tfluna.md §2.3)."""
    assert commands.encode_reply(0x02, b"\x00") == bytes.fromhex("5A 05 02 00 61")
    assert commands.encode_reply(0x10, b"\x00") == bytes.fromhex("5A 05 10 00 6F")
    assert commands.encode_reply(0x11, b"\x00") == bytes.fromhex("5A 05 11 00 70")
    assert commands.encode_reply(0x01, bytes((9, 0, 3))) == bytes.fromhex("5A 07 01 09 00 03 6E")


@pytest.mark.parametrize(
    "bad",
    [
        lambda: commands.set_frame_rate(1000),
        lambda: commands.set_frame_rate(99),
        lambda: commands.set_baud_rate(12345),
        lambda: commands.set_i2c_address(0x78),
        lambda: commands.set_amp_threshold(105),
        lambda: commands.set_distance_limits(500, 100),
    ],
)
def test_misuse_raises_value_error(bad: Callable[[], object]) -> None:
    with pytest.raises(ValueError):
        bad()


def round_trip(cmd: bytes, sensor: VirtualSensor | None = None) -> object:
    """Send ``cmd`` to a virtual sensor and decode what comes back through the parser."""
    sensor = sensor or VirtualSensor()
    buf = bytearray(cmd)
    ((cid, payload),) = commands.split_commands(buf)
    out = FrameParser().feed(sensor.handle(cid, payload), 0)
    assert len(out) == 1 and isinstance(out[0], CommandReply)
    assert out[0].cmd_id == cid
    return decode_reply(out[0])


def test_round_trips() -> None:
    s = VirtualSensor()
    assert round_trip(commands.get_version(), s) == Version(3, 0, 9)
    assert round_trip(commands.set_frame_rate(250), s) == 250
    assert s.settings.rate_hz == 250
    assert round_trip(commands.set_frame_rate(0), s) == 0
    assert round_trip(commands.set_output_format(OutputFormat.MM), s) is OutputFormat.MM
    assert round_trip(commands.set_baud_rate(460800), s) == 460800
    assert round_trip(commands.set_output_enabled(False), s) is False
    assert round_trip(commands.set_checksum_enabled(True), s) is True
    assert round_trip(commands.set_i2c_address(0x22), s) == 0x22
    assert round_trip(commands.set_amp_threshold(200, 1200), s) == AmpThreshold(200, 1200)
    assert round_trip(commands.set_distance_limits(20, 800, True), s) == DistanceLimits(
        20, 800, True
    )
    assert round_trip(commands.read_serial_number(), s) == "LUNADSIM000001"


def test_save_restore_reset_semantics() -> None:
    s = VirtualSensor()
    round_trip(commands.set_frame_rate(250), s)
    assert round_trip(commands.soft_reset(), s) is True
    assert s.settings.rate_hz == 100  # not saved: lost on reset (M05 p.13)
    round_trip(commands.set_frame_rate(250), s)
    assert round_trip(commands.save_settings(), s) is True
    round_trip(commands.soft_reset(), s)
    assert s.settings.rate_hz == 250
    assert round_trip(commands.restore_defaults(), s) is True
    assert s.settings.rate_hz == 100


def test_decode_reply_keeps_odd_payloads_visible() -> None:
    assert decode_reply(CommandReply(0x03, b"\x01", 0)) == b"\x01"


def test_split_commands_keeps_incomplete_and_skips_junk() -> None:
    buf = bytearray(b"\x00\x01" + commands.get_version() + commands.set_frame_rate(100)[:3])
    assert commands.split_commands(buf) == [(0x01, b"")]
    assert bytes(buf) == commands.set_frame_rate(100)[:3]
