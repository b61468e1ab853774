"""The I2C source against the fake bus, through the real UART frame parser.

Every test goes through ``I2CSource`` and ``FakeSMBus`` (no mocks of smbus2): what the
source sends over the bus is asserted from the fake's logs, what it yields by parsing
it with ``FrameParser`` as the daemon does.
"""

from __future__ import annotations

import errno
import random
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from lunad.daemon.config import SourceSection, load_config
from lunad.daemon.errors import SourceLostError, SourceOpenError
from lunad.daemon.notify import Notifier
from lunad.daemon.publisher import Publisher
from lunad.daemon.serve import Daemon
from lunad.daemon.sources import i2c as i2c_source
from lunad.daemon.sources.i2c import I2CSource
from lunad.protocol import CommandReply, Frame, FrameParser, commands
from lunad.protocol.client import Subscriber
from lunad.protocol.commands import CommandId, Version, decode_reply
from lunad.protocol.messages import HealthMessage
from lunad.protocol.registers import Mode, Register
from lunad.sim.fake_i2c import FakeSMBus
from lunad.sim.physics import RawReading, Truth

SAMPLE_READ = (Register.DIST_LOW, 8)
TRIGGER = (Register.TRIG_ONE_SHOT, 1)
SET_TRIGGER_MODE = (Register.MODE, Mode.TRIGGER)
REBOOT = (Register.SHUTDOWN_REBOOT, 2)


@dataclass
class FixedModel:
    """A sensor model with a known reading, so frames can be checked to the bit."""

    dist_cm: int = 123
    amp: int = 1000

    def sample(self, truth: Truth, rng: random.Random) -> RawReading:
        return RawReading(self.dist_cm, self.amp)


Items = list[Frame | CommandReply]


def collect(src: I2CSource, parser: FrameParser, frames: int = 1, within_s: float = 2.0) -> Items:
    """Read with short bounded reads until ``frames`` data frames arrived or time is up."""
    out: Items = []
    deadline = time.monotonic() + within_s
    while sum(isinstance(x, Frame) for x in out) < frames and time.monotonic() < deadline:
        chunk = src.read(0.05)
        if chunk is not None:
            out += parser.feed(chunk.data, chunk.t_mono_ns)
    return out


def read_now(src: I2CSource) -> Items:
    """One read that waits for nothing: the queued command replies, if any."""
    chunk = src.read(0.0)
    return [] if chunk is None else FrameParser().feed(chunk.data, chunk.t_mono_ns)


def data_frames(items: Items) -> list[Frame]:
    return [x for x in items if isinstance(x, Frame)]


def replies(items: Items) -> dict[int, object]:
    return {x.cmd_id: decode_reply(x) for x in items if isinstance(x, CommandReply)}


@pytest.fixture
def fake() -> FakeSMBus:
    return FakeSMBus(model=FixedModel(), temp_c=40.0)


@pytest.fixture
def opener(fake: FakeSMBus) -> Iterator[Callable[..., I2CSource]]:
    """Opens ``I2CSource`` on bus "1" with the fake behind it; closes what it opened."""
    made: list[I2CSource] = []

    def open_(bus: FakeSMBus | None = None, **kw: Any) -> I2CSource:
        dev = bus or fake
        src = I2CSource("1", smbus_factory=lambda _bus: dev, **kw)
        made.append(src)
        return src

    yield open_
    for src in made:
        src.close()


# -- samples on the wire ---------------------------------------------------------------


def test_samples_become_valid_uart_frames(fake: FakeSMBus, opener: Callable[..., I2CSource]):
    src = opener()
    p = FrameParser()
    got = data_frames(collect(src, p, frames=5))
    assert len(got) == 5
    assert all((f.dist, f.amp, f.temp_raw) == (123, 1000, 0x0940) for f in got)  # 40.0 degC
    assert got[0].distance_m == 1.23 and got[0].temp_c == 40.0
    assert p.stats.checksum_errors == 0 and p.stats.bytes_discarded == 0 and p.stats.buffered == 0


def test_frames_carry_each_register_sample(opener: Callable[..., I2CSource]):
    dev = FakeSMBus(truth=Truth(distance_m=3.0, reflectivity=0.5, lux=20_000), seed=7)
    src = opener(dev)
    got = data_frames(collect(src, FrameParser(), frames=20))
    assert len(got) == 20
    assert len({f.dist for f in got}) > 1  # noisy readings, not one value repeated
    assert [(f.dist, f.amp) for f in got] == [(s.dist_cm, s.amp) for s in dev.history]


@pytest.mark.parametrize("temp_c", [36.37, 0.0, -5.25, 59.99])
def test_temperature_converted_from_centidegrees(opener: Callable[..., I2CSource], temp_c: float):
    src = opener(FakeSMBus(model=FixedModel(), temp_c=temp_c))
    (f,) = data_frames(collect(src, FrameParser(), frames=1))
    assert abs(f.temp_c - temp_c) <= 1 / 16  # UART raw is 1/8 degC steps (M05 p.24)


def test_one_trigger_and_one_block_read_per_sample(
    fake: FakeSMBus, opener: Callable[..., I2CSource]
):
    src = opener()
    opened_at = fake.transfers
    n_reads = len(fake.block_reads)
    got = data_frames(collect(src, FrameParser(), frames=10))
    assert len(got) == src.samples == 10 and src.stale_ticks == 0
    assert fake.block_reads[n_reads:] == [SAMPLE_READ] * 10
    assert fake.transfers - opened_at == 2 * 10  # trigger write + block read, nothing else
    assert fake.writes == [SET_TRIGGER_MODE] + [TRIGGER] * 10


def test_tick_wrap_is_a_new_sample(opener: Callable[..., I2CSource]):
    src = opener(FakeSMBus(model=FixedModel(), tick=0xFFFF))
    assert len(data_frames(collect(src, FrameParser(), frames=2))) == 2
    assert src.stale_ticks == 0


# -- open --------------------------------------------------------------------------------


def test_open_probes_reads_version_and_sets_trigger_mode(opener: Callable[..., I2CSource]):
    dev = FakeSMBus(model=FixedModel(), firmware=(3, 1, 7))
    assert dev.mode is Mode.CONTINUOUS
    src = opener(dev)
    assert dev.block_reads[:2] == [(Register.SIGNATURE, 4), (Register.VERSION_REVISION, 3)]
    assert dev.writes == [SET_TRIGGER_MODE]
    assert dev.mode is Mode.TRIGGER
    assert src.signature == b"LUNA" and src.version == Version(major=3, minor=1, revision=7)
    assert str(src) == "i2c bus 1 address 0x10"


def test_firmware_without_signature_still_works(opener: Callable[..., I2CSource]):
    src = opener(FakeSMBus(model=FixedModel(), signature=False))
    assert src.signature == bytes(4)
    assert len(data_frames(collect(src, FrameParser(), frames=1))) == 1


def test_absent_sensor_is_a_clear_open_error(fake: FakeSMBus):
    fake.absent = True
    with pytest.raises(SourceOpenError, match=r"i2c bus 1 address 0x10: .*Errno 121.*NACK"):
        I2CSource("1", smbus_factory=lambda _bus: fake)
    assert fake.closed


def test_wrong_address_is_an_open_error(fake: FakeSMBus):
    with pytest.raises(SourceOpenError, match="address 0x11"):
        I2CSource("1", address=0x11, smbus_factory=lambda _bus: fake)


def test_one_nack_at_open_is_retried(fake: FakeSMBus, opener: Callable[..., I2CSource]):
    fake.nack(1)  # e.g. a sensor waking from ultra-low power (docs/tfluna.md section 3.5)
    src = opener()
    assert src.nacks == 1 and fake.mode is Mode.TRIGGER


def test_missing_bus_device_is_an_open_error() -> None:
    with pytest.raises(SourceOpenError, match=r"cannot open i2c bus 99 address 0x10: .*Errno 2"):
        I2CSource("99")  # real smbus2, no /dev/i2c-99


def test_bus_factory_oserror_is_an_open_error() -> None:
    def no_permission(bus: int | str) -> FakeSMBus:
        raise PermissionError(errno.EACCES, "Permission denied", f"/dev/i2c-{bus}")

    with pytest.raises(SourceOpenError, match="group i2c"):
        I2CSource("1", smbus_factory=no_permission)


def test_failed_opens_leave_no_descriptors_behind() -> None:
    """The daemon retries an absent bus every 2 s: a pipe left open by each try ran a
    Pi out of descriptors in about 17 minutes (then os.pipe raised EMFILE)."""
    import os

    def absent(bus: int | str) -> FakeSMBus:
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", f"/dev/i2c-{bus}")

    before = len(os.listdir("/proc/self/fd"))
    for _ in range(50):
        with pytest.raises(SourceOpenError):
            I2CSource("1", smbus_factory=absent)
    assert len(os.listdir("/proc/self/fd")) == before


def test_bad_arguments_are_value_errors(fake: FakeSMBus):
    with pytest.raises(ValueError, match="address"):
        I2CSource("1", address=0x78, smbus_factory=lambda _bus: fake)
    with pytest.raises(ValueError, match="rate"):
        I2CSource("1", rate_hz=99, smbus_factory=lambda _bus: fake)


def test_sim_bus_and_from_config() -> None:
    section = SourceSection(kind="i2c", bus="sim", address=0x10, rate_hz=50)
    with I2CSource.from_config(section) as src:
        assert str(src) == "i2c bus sim address 0x10" and src.rate_hz == 50
        assert len(data_frames(collect(src, FrameParser(), frames=3))) == 3
    # A section with no rate_hz at all, on purpose: from_config falls back to the default.
    cfg = SimpleNamespace(kind="i2c", bus="sim", address=0x10)
    with I2CSource.from_config(cfg) as src:  # type: ignore[arg-type]
        assert src.rate_hz == 100


# -- faults --------------------------------------------------------------------------------


def test_stale_ticks_retried_without_reboot(fake: FakeSMBus, opener: Callable[..., I2CSource]):
    src = opener()
    fake.stall(3)
    (f,) = data_frames(collect(src, FrameParser(), frames=1))
    assert src.stale_ticks == 3 and src.samples == 1 and src.reboots == 0
    assert fake.triggers == 4 and fake.reboots == 0
    assert f.dist == fake.history[-1].dist_cm and len(fake.history) == 1


def test_first_read_after_open_must_move_the_tick(opener: Callable[..., I2CSource]):
    dev = FakeSMBus(model=FixedModel())
    dev.stall(1)  # the first trigger does nothing: the registers still hold the boot values
    src = opener(dev)
    assert len(data_frames(collect(src, FrameParser(), frames=1))) == 1
    assert src.stale_ticks == 1


def test_hung_sensor_rebooted_then_trigger_mode_set_again(
    fake: FakeSMBus, opener: Callable[..., I2CSource]
):
    src = opener()
    p = FrameParser()
    assert len(data_frames(collect(src, p, frames=1))) == 1
    fake.stall(1_000_000)  # hung until rebooted
    deadline = time.monotonic() + 2.0
    while src.reboots == 0 and time.monotonic() < deadline:
        assert src.read(0.02) is None
    assert src.reboots == 1 and fake.reboots == 1
    assert src.stale_ticks == i2c_source.STALE_REBOOT_AFTER
    assert fake.mode is Mode.CONTINUOUS  # a reboot restores the saved (continuous) mode

    # The reboot settle (1 s) must neither block the caller nor touch the bus.
    quiet_from = fake.transfers
    t0 = time.monotonic()
    assert src.read(0.05) is None
    assert time.monotonic() - t0 < 0.9 and fake.transfers == quiet_from  # not through the 1 s

    got = data_frames(collect(src, p, frames=1, within_s=3.0))
    assert len(got) == 1 and src.samples == 2
    after = fake.writes[fake.writes.index(REBOOT) + 1 :]
    assert after[:2] == [SET_TRIGGER_MODE, TRIGGER]
    assert fake.mode is Mode.TRIGGER


def test_sensor_restarting_by_itself_is_put_back_in_trigger_mode(
    opener: Callable[..., I2CSource],
):
    """A brown-out: the sensor NACKs while it boots and comes back in continuous mode (MODE
    is never saved), where triggers are ignored and reads can be torn (docs/tfluna.md §3.2-3.3).
    The source sets trigger mode before its next trigger and reads triggered samples."""
    now = [0.0]  # the fake's clock: it boots when the test says so
    dev = FakeSMBus(model=FixedModel(), clock=lambda: now[0])
    src = opener(dev)
    p = FrameParser()
    assert len(data_frames(collect(src, p, frames=3))) == 3
    dev.reboot_busy_s = 1.0
    dev.brown_out()
    assert dev.mode is Mode.CONTINUOUS
    deadline = time.monotonic() + 5.0
    while dev.nacks_sent < 3:
        assert src.read(0.05) is None
        assert time.monotonic() < deadline, "the source did not retry the booting sensor"
    writes, measured = len(dev.writes), len(dev.history)
    now[0] += dev.reboot_busy_s  # booted

    got = data_frames(collect(src, p, frames=5))
    assert len(got) == 5 and dev.mode is Mode.TRIGGER
    assert dev.writes[writes:] == [SET_TRIGGER_MODE] + [TRIGGER] * 5
    assert len(dev.history) - measured == 5  # each frame measured on a trigger, none continuous
    assert src.restarts == 1 and src.reboots == 0 and dev.reboots == 0
    assert src.nacks == dev.nacks_sent
    count, last = src.recovered_faults
    assert count == src.nacks + 1 and last is not None and "restarted by itself" in last


def test_sensor_restart_between_reads_seen_by_tick_going_back(opener: Callable[..., I2CSource]):
    """A restart no transfer saw (no NACK): TICK starts again at boot, so it goes back. The
    continuous-mode sample is dropped and trigger mode set again."""
    now = [0.0]
    dev = FakeSMBus(model=FixedModel(), clock=lambda: now[0], tick=1000)
    src = opener(dev)
    p = FrameParser()
    assert len(data_frames(collect(src, p, frames=3))) == 3
    dev.brown_out()  # answers at once (reboot_busy_s 0), TICK cleared, continuous mode
    now[0] += 0.02  # two continuous frame periods: the next sample read refreshes, TICK = 1
    writes, measured = len(dev.writes), len(dev.history)

    got = data_frames(collect(src, p, frames=5))
    assert len(got) == 5 and dev.mode is Mode.TRIGGER
    # the first trigger is ignored and its read (TICK 1003 -> 1) dropped
    assert dev.writes[writes:] == [TRIGGER, SET_TRIGGER_MODE] + [TRIGGER] * 5
    assert len(dev.history) - measured == 1 + 5
    assert src.restarts == 1 and src.nacks == 0 and src.reboots == 0


def test_nacks_counted_and_retried(fake: FakeSMBus, opener: Callable[..., I2CSource]):
    src = opener()
    fake.nack(3)
    (f,) = data_frames(collect(src, FrameParser(), frames=1))
    assert f.dist == 123
    assert src.nacks == 3 == fake.nacks_sent and src.samples == 1


def test_nack_on_the_block_read_retries_the_whole_sample(
    fake: FakeSMBus, opener: Callable[..., I2CSource]
):
    src = opener()
    deadline = time.monotonic() + 5.0
    while True:  # until a read stops between the trigger and its block read
        triggers = fake.triggers
        if src.read(0.0) is None and fake.triggers == triggers + 1:
            break  # the block read waits for the settle (a stall past it finishes the sample)
        assert time.monotonic() < deadline, "no read stopped after a trigger"
        time.sleep(0.001)
    fake.nack(1)
    assert len(data_frames(collect(src, FrameParser(), frames=1))) == 1
    assert src.nacks == 1 and fake.triggers == triggers + 2


def test_persistent_nack_is_source_lost_after_backoff(
    fake: FakeSMBus, opener: Callable[..., I2CSource]
):
    src = opener()
    assert len(data_frames(collect(src, FrameParser(), frames=1))) == 1
    fake.absent = True
    t0 = time.monotonic()
    deadline = t0 + 5.0
    with pytest.raises(SourceLostError, match=r"i2c bus 1 address 0x10: no answer .*Errno 121"):
        while time.monotonic() < deadline:
            src.read(0.25)
    assert time.monotonic() - t0 >= i2c_source.LOST_AFTER_S
    assert 5 <= src.nacks < 40  # backed off (5 ms doubling to 200 ms), not hammering the bus


def _health_notes_after(fake: FakeSMBus, tmp_path: Path, fault: Callable[[], None]) -> list[str]:
    """Serve the fake through a real ``Daemon`` and ZeroMQ; inject ``fault`` after the first
    reading; return every ``last_error`` health reported, once 20 more readings came."""
    endpoint = f"ipc://{tmp_path}/i2c.sock"
    cfg = load_config(
        None,
        {
            "source.kind": "i2c",
            "sensor.name": "bus",
            "sensor.frame_rate_hz": 100,
            "publish.endpoint": endpoint,
            "publish.health_interval_s": 0.1,
        },
    )

    def open_on_fake(section: SourceSection) -> I2CSource:
        return I2CSource(section.bus, section.address, smbus_factory=lambda _bus: fake)

    daemon = Daemon(cfg, source_opener=open_on_fake, notifier=Notifier(None))
    pub = Publisher(endpoint)
    loop = threading.Thread(target=daemon.run, args=(pub,))
    loop.start()
    notes: list[str] = []
    try:
        with Subscriber(endpoint, sensor="bus") as sub:
            deadline = time.monotonic() + 10
            ranges_after = 0
            injected = False
            while time.monotonic() < deadline and not (notes and ranges_after >= 20):
                m = sub.recv(timeout_s=0.2)
                if m is None:
                    continue
                if m.kind == "range" and not injected:
                    fault()
                    injected = True
                elif m.kind == "range":
                    ranges_after += 1
                elif isinstance(m, HealthMessage) and m.last_error:
                    notes.append(m.last_error)
            assert ranges_after >= 20, "the readings did not come back after the fault"
    finally:
        daemon.request_stop()
        loop.join(5)
        pub.close()
    assert not loop.is_alive()
    return notes


def test_daemon_reports_retried_nacks_on_health(fake: FakeSMBus, tmp_path: Path) -> None:
    """A NACK the source retries is counted and shown in health's last_error
    (docs/architecture.md, "What bad input gets")."""
    notes = _health_notes_after(fake, tmp_path, lambda: fake.nack(3))
    assert notes, "no health message reported the retried NACKs"
    assert notes[-1].startswith("i2c bus 1 address 0x10: recovered from 3 fault(s) since opening")
    assert "Errno 121" in notes[-1] and "NACK" in notes[-1]


def test_daemon_reports_a_rebooted_sensor_on_health(fake: FakeSMBus, tmp_path: Path) -> None:
    """A hung sensor (TICK stuck) that the source reboots shows in health's last_error."""
    notes = _health_notes_after(fake, tmp_path, lambda: fake.stall(1_000_000))
    assert notes, "no health message reported the reboot"
    assert notes[-1].startswith("i2c bus 1 address 0x10: recovered from 1 fault(s) since opening")
    assert notes[-1].endswith(
        f"for {i2c_source.STALE_REBOOT_AFTER} reads: sensor hung, rebooted it"
    )
    assert fake.reboots == 1


def test_daemon_reports_a_sensor_that_restarted_by_itself_on_health(
    fake: FakeSMBus, tmp_path: Path
) -> None:
    """A brown-out (NACKs, then continuous mode) the source recovers from shows in health."""

    def brown_out() -> None:
        fake.reboot_busy_s = 0.1
        fake.brown_out()

    notes = _health_notes_after(fake, tmp_path, brown_out)
    assert notes, "no health message reported the restart"
    assert notes[-1].startswith("i2c bus 1 address 0x10: recovered from ")
    assert notes[-1].endswith(
        "sensor restarted by itself (MODE read 0, not trigger 1; a power dip?): "
        "trigger mode set again"
    )
    assert fake.mode is Mode.TRIGGER


# -- UART command emulation -----------------------------------------------------------------


def test_version_reply_comes_from_the_registers(opener: Callable[..., I2CSource]):
    src = opener(FakeSMBus(model=FixedModel(), firmware=(3, 0, 9)))
    src.write(commands.get_version())
    chunk = src.read(0.0)
    assert chunk is not None and chunk.data == bytes.fromhex("5A 07 01 09 00 03 6E")
    (reply,) = FrameParser().feed(chunk.data, chunk.t_mono_ns)
    assert isinstance(reply, CommandReply)
    assert decode_reply(reply) == Version(major=3, minor=0, revision=9)


def test_daemon_connect_sequence(fake: FakeSMBus, opener: Callable[..., I2CSource]):
    src = opener()
    src.write(
        commands.get_version() + commands.set_frame_rate(50) + commands.set_output_enabled(True)
    )
    items = collect(src, FrameParser(), frames=2)
    assert isinstance(items[0], CommandReply)  # replies come before any sample
    assert replies(items) == {
        CommandId.GET_VERSION: Version(3, 0, 9),
        CommandId.SAMPLE_FREQ: 50,
        CommandId.OUTPUT_EN: True,
    }
    assert len(data_frames(items)) == 2 and src.rate_hz == 50


def test_commands_split_across_writes_and_unknown_ids(opener: Callable[..., I2CSource]):
    src = opener()
    cmd = commands.save_settings() + commands.get_version()
    src.write(cmd[:3])
    src.write(cmd[3:])
    assert list(replies(read_now(src))) == [CommandId.GET_VERSION]  # save: not emulated, no reply


def test_output_off_stops_sampling_and_on_resumes(
    fake: FakeSMBus, opener: Callable[..., I2CSource]
):
    src = opener()
    src.write(commands.set_output_enabled(False))
    assert replies(read_now(src)) == {CommandId.OUTPUT_EN: False}
    triggers = fake.triggers
    assert src.read(0.1) is None and fake.triggers == triggers
    src.write(commands.set_output_enabled(True))
    assert len(data_frames(collect(src, FrameParser(), frames=2))) == 2


def test_rate_zero_samples_only_on_trigger(fake: FakeSMBus, opener: Callable[..., I2CSource]):
    src = opener()
    src.write(commands.set_frame_rate(0))
    assert replies(read_now(src)) == {CommandId.SAMPLE_FREQ: 0}
    assert src.read(0.1) is None and fake.triggers == 0
    src.write(commands.trigger())
    assert len(data_frames(collect(src, FrameParser(), frames=1))) == 1
    assert src.read(0.1) is None and fake.triggers == 1 and src.samples == 1


def test_invalid_rate_keeps_the_current_one(opener: Callable[..., I2CSource]):
    src = opener()
    src.write(commands.encode_command(CommandId.SAMPLE_FREQ, (99).to_bytes(2, "little")))
    assert replies(read_now(src)) == {CommandId.SAMPLE_FREQ: 100}
    assert src.rate_hz == 100


# -- pacing, cancel, close --------------------------------------------------------------------


def test_paced_at_about_the_rate(opener: Callable[..., I2CSource]):
    src = opener(rate_hz=100)
    n = 0
    end = time.monotonic() + 0.5
    while (left := end - time.monotonic()) > 0:
        chunk = src.read(min(left, 0.25))
        n += chunk is not None
    assert 5 <= n <= 60  # 50 expected; unpaced would be hundreds (no lower speed bound:
    # the machine is shared, and pacing means not faster than the rate)


def test_read_returns_within_its_timeout_between_samples(opener: Callable[..., I2CSource]):
    src = opener(rate_hz=1)
    assert len(data_frames(collect(src, FrameParser(), frames=1))) == 1
    t0 = time.monotonic()
    assert src.read(0.05) is None
    assert time.monotonic() - t0 < 0.5


def test_cancel_wakes_a_waiting_read(opener: Callable[..., I2CSource]):
    src = opener(rate_hz=0)  # nothing to sample: the read waits out its whole timeout
    result: list[object] = []
    t = threading.Thread(target=lambda: result.append(src.read(10.0)))
    t0 = time.monotonic()
    t.start()
    time.sleep(0.05)  # let the read start waiting (a cancel before it would also end it)
    src.cancel()
    t.join(timeout=5.0)
    assert not t.is_alive() and result == [None]
    assert time.monotonic() - t0 < 5.0
    src.write(commands.trigger())
    assert src.read(1.0) is not None  # a consumed cancel does not end later reads


def test_close_is_idempotent_and_read_after_close_is_lost(
    fake: FakeSMBus, opener: Callable[..., I2CSource]
):
    src = opener()
    src.close()
    src.close()
    assert fake.closed
    with pytest.raises(SourceLostError):
        src.read(0.0)


# -- the fake itself ------------------------------------------------------------------------


def test_fake_register_map_and_nack() -> None:
    dev = FakeSMBus()
    assert bytes(dev.read_i2c_block_data(0x10, Register.SIGNATURE, 4)) == b"LUNA"
    assert dev.read_i2c_block_data(0x10, Register.FPS_LOW, 2) == [100, 0]
    assert dev.read_byte_data(0x10, Register.ENABLE) == 1
    with pytest.raises(OSError) as exc:
        dev.read_byte_data(0x11, 0)
    assert exc.value.errno == errno.EREMOTEIO
    with pytest.raises(ValueError):
        dev.read_i2c_block_data(0x10, 0, 33)


def test_fake_trigger_only_in_trigger_mode_and_save_survives_reboot() -> None:
    now = [0.0]
    dev = FakeSMBus(model=FixedModel(), clock=lambda: now[0])
    dev.write_byte_data(0x10, Register.TRIG_ONE_SHOT, 1)
    assert dev.history == []  # continuous mode ignores the trigger ...
    now[0] += 0.011
    assert dev.read_i2c_block_data(0x10, 0, 8)[6:] == [1, 0]  # ... and updates by itself
    dev.write_byte_data(0x10, Register.MODE, Mode.TRIGGER)
    dev.write_byte_data(0x10, Register.TRIG_ONE_SHOT, 1)
    assert dev.read_i2c_block_data(0x10, 0, 8) == [123, 0, 0xE8, 3, 0xA0, 0x0F, 2, 0]
    dev.write_i2c_block_data(0x10, Register.SAVE, [1, 2])  # save, then reboot
    assert dev.mode is Mode.TRIGGER and dev.reboots == 1
