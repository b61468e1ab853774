"""The virtual TF-Luna through the real serial path: pyserial on a real pty."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

from lunad.protocol import CommandReply, Frame, FrameParser, OutputFormat, commands
from lunad.protocol.commands import Version, decode_reply
from lunad.sim.physics import PaperSensor, RealisticSensor, Truth
from lunad.sim.pty_device import DeviceError, PtyDevice


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
def port(device: Callable[..., PtyDevice]) -> Iterator[tuple[PtyDevice, serial.Serial]]:
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


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_link_refuses_what_is_not_a_symlink(tmp_path: Path, kind: str) -> None:
    """``lunad sim --link notes.txt`` used to replace the user's file and delete it at exit."""
    path = tmp_path / "notes.txt"
    if kind == "file":
        path.write_text("my notes\n")
    else:
        path.mkdir()
    before = open_fds()
    with pytest.raises(FileExistsError, match="not a symlink"):
        PtyDevice(link=path).start()
    assert open_fds() == before  # pty pair and wake pipe closed again
    assert path.is_dir() if kind == "folder" else path.read_text() == "my notes\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_failed_start_closes_every_fd() -> None:
    """Each failed start used to leak the pty pair and the wake pipe (4 fds)."""
    before = open_fds()
    for _ in range(3):
        with pytest.raises(FileNotFoundError), PtyDevice(link="/proc/no-such-pid/tfluna"):
            pass
    assert open_fds() == before


def test_a_dead_device_thread_is_raised_on_close(tmp_path: Path) -> None:
    """A NaN truth killed the device thread, and the sensor then went mute unnoticed."""
    died: list[BaseException] = []
    ended = threading.Event()

    def on_error(exc: BaseException) -> None:
        died.append(exc)
        ended.set()

    dev = PtyDevice(Truth(float("nan")), rate_hz=250, link=tmp_path / "x", on_error=on_error)
    dev.start()
    assert ended.wait(10.0), "the device thread did not fail on a NaN distance"
    with pytest.raises(DeviceError, match="ValueError") as info:
        dev.close()
    assert info.value.__cause__ is died[0] is dev.error
    dev.close()  # reported once; closing again is quiet
    assert not os.path.lexists(tmp_path / "x")


def with_bad_checksum(cmd: bytes) -> bytes:
    return cmd[:-1] + bytes(((cmd[-1] + 1) & 0xFF,))


def test_checksum_checking_ignores_bad_commands(device: Callable[..., PtyDevice]) -> None:
    """After ID 0x08 a wrong checksum is not obeyed, and gets no reply (docs/tfluna.md §2.1, 9)."""
    dev = device(rate_hz=0)
    p = FrameParser()
    with serial.serial_for_url(dev.path, 115200, timeout=0.05, exclusive=True) as ser:
        ser.write(with_bad_checksum(commands.get_version()))  # by default any CS is accepted
        read_until(ser, p, lambda it: 0x01 in replies(it))
        ser.write(commands.set_checksum_enabled(True))
        read_until(ser, p, lambda it: 0x08 in replies(it))
        ignored = [
            commands.set_output_format(OutputFormat.MM),
            commands.trigger(),
            commands.set_checksum_enabled(False),
        ]
        ser.write(b"".join(with_bad_checksum(c) for c in ignored) + commands.get_version())
        got = read_until(ser, p, lambda it: 0x01 in replies(it))
        ser.write(commands.trigger())
        got += read_until(ser, p, lambda it: len(frames(it)) >= 1)
        ser.write(commands.get_version())  # any frame of the bad trigger came before this
        got += read_until(ser, p, lambda it: 0x01 in replies(it))
    assert set(replies(got)) == {0x01}
    (frame,) = frames(got)
    assert frame.fmt is OutputFormat.CM and 150 <= frame.dist <= 250
    assert dev.sensor.settings.checksum_enabled and dev.sensor.bad_checksums == 3


@pytest.mark.parametrize(
    "model",
    [PaperSensor(), RealisticSensor(spike_probability=0.0, amp_noise=0.0)],
    ids=["paper", "realistic"],
)
def test_amp_threshold_command_moves_the_weak_signal_cut(
    device: Callable[..., PtyDevice], model: PaperSensor | RealisticSensor
) -> None:
    """ID 0x22: amp below the threshold reports Dummy_Dist, at or above it a distance
    (M05 p.30, docs/tfluna.md section 4); lowered below 100 it used to change nothing."""
    dev = device(rate_hz=0, truth=Truth(2.0, 0.04, 0.0, 0.0), model=model)  # amp 80
    p = FrameParser()
    got: list[Frame] = []

    def triggered() -> Frame:
        ser.write(commands.trigger())
        got.extend(frames(read_until(ser, p, lambda it: len(frames(it)) >= 1)))
        return got[-1]

    with serial.serial_for_url(dev.path, 115200, timeout=0.05, exclusive=True) as ser:
        assert triggered()[:2] == (0, 80)  # the default threshold, 100
        ser.write(commands.set_amp_threshold(50))
        read_until(ser, p, lambda it: 0x22 in replies(it))
        lowered = triggered()
        ser.write(commands.set_amp_threshold(300, 500))
        read_until(ser, p, lambda it: 0x22 in replies(it))
        raised = triggered()
    assert lowered.amp == 80 and 100 <= lowered.dist <= 300
    assert raised[:2] == (500, 80)


def test_a_scenario_played_on_the_pty_mixes_both_surfaces_at_each_edge(
    device: Callable[..., PtyDevice],
) -> None:
    """``lunad sim`` and ``lunad demo`` give the device the scenario's edges
    (``sim.edges.edge_view``): the readings just after each jump between a dark object
    at 1 m and a white wall at 5 m lie between the two, while ``truth_out`` logs only
    the surface at the beam's centre."""
    import io

    from lunad.sim.edges import edge_view
    from lunad.sim.scenario import load_scenario

    scenario = load_scenario("alternating")
    model = RealisticSensor(spike_probability=0.0)  # only the edges fall between
    length = scenario.duration_s
    log = io.StringIO()
    dev = device(
        truth=lambda t: scenario.truth_at(t % length),
        model=model,
        view=edge_view(scenario.step_times_s, scenario.truth_at, model.amp_of, length),
        rate_hz=250,
        truth_out=log,
    )
    with serial.serial_for_url(dev.path, 115200, timeout=0.05, exclusive=True) as ser:
        parser = FrameParser()
        got = frames(read_until(ser, parser, lambda items: len(frames(items)) >= 600))
    dev.close()
    between = [f.distance_m for f in got if f.distance_m is not None and 1.3 < f.distance_m < 4.5]
    assert len(between) >= 3, "each jump (every 0.5 s) gives readings of neither surface"
    logged = {round(float(row.split(",")[1]), 2) for row in log.getvalue().splitlines()}
    assert logged <= {1.0, 5.0}
