"""The virtual TF-Luna through the real serial path: pyserial on a real pty."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import serial

from lunad.protocol import CommandReply, Frame, FrameParser, OutputFormat, commands
from lunad.protocol.commands import Version, decode_reply
from lunad.sim.physics import PaperSensor, Truth
from lunad.sim.pty_device import PtyDevice


def read_for(ser: serial.Serial, seconds: float, parser: FrameParser) -> list[Frame | CommandReply]:
    out: list[Frame | CommandReply] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        out += parser.feed(ser.read(max(1, ser.in_waiting)), time.monotonic_ns())
    return out


def read_until(
    ser: serial.Serial,
    parser: FrameParser,
    done: Callable[[list[Frame | CommandReply]], bool],
    timeout_s: float = 10.0,
) -> list[Frame | CommandReply]:
    """Read until ``done(items)`` holds; fail after ``timeout_s`` (a shared machine may
    stall the device thread, so no test counts what arrives in a fixed window)."""
    out: list[Frame | CommandReply] = []
    deadline = time.monotonic() + timeout_s
    while not done(out):
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met within {timeout_s} s; got {len(out)} items")
        out += parser.feed(ser.read(max(1, ser.in_waiting)), time.monotonic_ns())
    return out


def frames(items: list[Frame | CommandReply]) -> list[Frame]:
    return [x for x in items if isinstance(x, Frame)]


def replies(items: list[Frame | CommandReply]) -> dict[int, object]:
    return {x.cmd_id: decode_reply(x) for x in items if isinstance(x, CommandReply)}


@pytest.fixture
def port(device: Callable[..., PtyDevice]) -> tuple[PtyDevice, serial.Serial]:
    dev = device(rate_hz=250)
    ser = serial.serial_for_url(dev.path, 115200, timeout=0.05, exclusive=True)
    yield dev, ser
    ser.close()


def test_link_points_at_a_raw_pty(port: tuple[PtyDevice, serial.Serial]) -> None:
    dev, _ = port
    assert os.path.islink(dev.path)
    assert os.readlink(dev.path) == dev.slave_name and dev.slave_name.startswith("/dev/pts/")


def test_streams_at_rate_with_valid_checksums(port: tuple[PtyDevice, serial.Serial]) -> None:
    _, ser = port
    p = FrameParser()
    read_until(ser, p, lambda items: len(frames(items)) >= 1)
    t0 = time.monotonic()
    got = frames(read_until(ser, p, lambda items: len(frames(items)) >= 250))
    took = time.monotonic() - t0
    assert took > 0.9, f"250 frames in {took:.2f} s: faster than 250 Hz"  # paced, not a flood
    assert p.stats.checksum_errors == 0 and p.stats.bytes_discarded == 0
    assert all(f.amp == 1800 and 150 <= f.dist <= 250 for f in got)  # R 0.9 at 2 m


def test_answers_commands(port: tuple[PtyDevice, serial.Serial]) -> None:
    _, ser = port
    p = FrameParser()
    ser.write(commands.get_version() + commands.set_output_format(OutputFormat.MM))
    r = replies(read_until(ser, p, lambda it: len(replies(it)) == 2))
    assert r[0x01] == Version(3, 0, 9) and r[0x05] is OutputFormat.MM
    mm = frames(read_until(ser, p, lambda it: len(frames(it)) >= 2))[-1]
    assert mm.fmt is OutputFormat.MM and 1500 <= mm.dist <= 2500
    ser.write(commands.set_output_enabled(False))
    read_until(ser, p, lambda it: 0x07 in replies(it))
    assert frames(read_for(ser, 0.3, p)) == []
    ser.write(commands.save_settings() + commands.restore_defaults() + commands.soft_reset())
    r = replies(read_until(ser, p, lambda it: len(replies(it)) == 3))
    assert r[0x11] is True and r[0x10] is True and r[0x02] is True


def test_trigger_mode(port: tuple[PtyDevice, serial.Serial]) -> None:
    _, ser = port
    p = FrameParser()
    ser.write(commands.set_frame_rate(0))
    assert replies(read_until(ser, p, lambda it: 0x03 in replies(it)))[0x03] == 0
    read_for(ser, 0.1, p)  # a frame already on its way when the command landed
    assert frames(read_for(ser, 0.3, p)) == []
    ser.write(commands.trigger() * 3)
    assert len(frames(read_until(ser, p, lambda it: len(frames(it)) >= 3))) == 3
    assert frames(read_for(ser, 0.3, p)) == []  # one frame a trigger, no more


def test_faults_garbage_and_corruption(port: tuple[PtyDevice, serial.Serial]) -> None:
    dev, ser = port
    p = FrameParser()
    ser.write(commands.set_output_enabled(False))
    read_until(ser, p, lambda it: 0x07 in replies(it))
    read_for(ser, 0.1, p)
    before = p.stats.frames
    sent_before = dev.frames_sent
    ser.write(commands.set_output_enabled(True))
    dev.corrupt_next(5)
    dev.inject_garbage(bytes(range(0, 0x59)) * 3)
    got = read_until(ser, p, lambda it: len(frames(it)) >= 50)
    assert p.stats.checksum_errors == 5
    assert p.stats.bytes_discarded >= 3 * 0x59 + 5 * 9 - 5
    assert len(frames(got)) >= 50
    # every good frame the device wrote arrives (pause, then drain)
    dev.pause(30)
    sent = dev.frames_sent - sent_before
    read_until(ser, p, lambda _: p.stats.frames - before >= sent)
    read_for(ser, 0.2, p)
    assert p.stats.frames - before == dev.frames_sent - sent_before


def test_pause_makes_it_silent(port: tuple[PtyDevice, serial.Serial]) -> None:
    dev, ser = port
    p = FrameParser()
    dev.pause(1.0)
    read_for(ser, 0.05, p)
    assert frames(read_for(ser, 0.3, p)) == []
    read_until(ser, p, lambda it: len(frames(it)) > 0)


def test_unplug_and_replug_same_link(device: Callable[..., PtyDevice]) -> None:
    dev = device(rate_hz=100)
    first = dev.slave_name
    ser = serial.serial_for_url(dev.path, 115200, timeout=0.1)
    try:
        dev.unplug()
        assert not os.path.lexists(dev.path)
        with pytest.raises(serial.SerialException):
            for _ in range(20):
                ser.read(100)
    finally:
        ser.close()
    dev.replug()
    assert os.readlink(dev.path) == dev.slave_name
    with serial.serial_for_url(dev.path, 115200, timeout=0.1) as ser2:
        assert frames(read_until(ser2, FrameParser(), lambda it: len(frames(it)) > 0))
    assert first  # the old slave name was real


def test_paper_model_physics() -> None:
    """Eqs 1-3: S = R cos(theta) sets amp; noise/S spreads the distance; weak reads 0."""
    import random

    rng = random.Random(1)
    m = PaperSensor()
    near = [m.sample(Truth(2.0, 0.9, 0.0, 0.0), rng) for _ in range(2000)]
    assert {r.amp for r in near} == {1800}
    mean = sum(r.dist_cm for r in near) / len(near)
    sd = (sum((r.dist_cm - mean) ** 2 for r in near) / len(near)) ** 0.5
    assert 199 <= mean <= 201 and 0.9 < sd < 1.4  # sigma 0.01 m / S 0.9 = 1.1 cm
    weak = m.sample(Truth(2.0, 0.1, 70.0, 0.0), rng)  # S = 0.034 < 0.05: amp 68
    assert weak.dist_cm == 0 and weak.amp == 68


def test_close_is_idempotent(tmp_path: Path) -> None:
    dev = PtyDevice(link=tmp_path / "x").start()
    dev.close()
    dev.close()
    assert not os.path.lexists(tmp_path / "x")
