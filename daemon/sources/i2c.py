"""I2C source through smbus2: a TF-Luna in trigger mode, read as UART frames.

How this works. At open: probe the signature (0x3C..0x3F reads ``LUNA`` on A05
firmware), read the firmware version (0x0A..0x0C), set MODE = trigger (0x23 = 1;
Benewake "strongly recommends" triggering on a shared bus, M05 p.14) and note the
current TICK. Then, per sample, as a small state machine driven by ``_read``::

    TRIGGER  write TRIG_ONE_SHOT (0x24 = 1)                  -> READ after the settle
    READ     one 8-byte block read from 0x00: dist, amp, temp, tick (docs/tfluna.md section 3.3)
             tick moved on   -> one UART data frame out      -> TRIGGER at the next slot
             tick unchanged  -> stale: count it              -> TRIGGER again in 5 ms
             5 stale in a row (ESPHome's hung-sensor rule)   -> REBOOT
             tick went back  -> restarted? drop the sample   -> MODE, checked
    REBOOT   write SHUTDOWN_REBOOT (0x21 = 2)                -> MODE after 1 s
    MODE     write MODE = trigger, read TICK (a reboot restores MODE = continuous,
             as we never save it: no flash writes)           -> TRIGGER
             checked: read MODE first; continuous means the sensor restarted by
             itself (a brown-out): count it in ``restarts``

A sensor that restarts by itself comes back in continuous mode, where TRIG_ONE_SHOT is
ignored (docs/tfluna.md §3.2) and an untimed read can catch the registers mid-update (M05 p.14,
docs/tfluna.md section 3.3). It NACKs while it boots, so a failed TRIGGER or READ resumes at MODE,
checked; one that restarted between two reads shows as TICK going back (its counter
starts again at boot). Neither costs a transfer on a sample that goes well.

Waits (frame pacing on an absolute schedule, the settle, retries, the reboot) are
``Wakeup`` (self-pipe) waits bounded by the caller's timeout, so ``cancel`` wakes them and
a ``_read`` never blocks much longer than asked (one transfer, well under 1 ms at
100 kHz); an unfinished step is picked up by the next ``_read``. Any ``OSError`` from
a transfer (NACK errno 121, bus timeout, EIO) is counted in ``nacks`` and retried with
backoff (5 ms doubling to 200 ms), a failed TRIGGER or READ from MODE (above); after 2 s
without a good read the source raises ``SourceLostError`` and the daemon reopens it with
its own backoff.

Each sample leaves as a 9-byte UART data frame (``encode_frame``), the temperature
converted from 0.01 degC (I2C, M05 p.34) to the UART's raw/8 - 256 (M05 p.24), so the
daemon has one parser path and one record format (docs/architecture.md). ``write`` emulates the
UART command layer the daemon speaks at connect: GET_VERSION, SAMPLE_FREQ, OUTPUT_EN
and SAMPLE_TRIG get the replies a UART sensor would send; other IDs are ignored.
"""

from __future__ import annotations

import enum
import errno
import logging
import struct
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from lunad.daemon.errors import SourceLostError, SourceOpenError
from lunad.daemon.sources.base import Source
from lunad.daemon.wakeup import Wakeup
from lunad.protocol.commands import (
    FRAME_RATES_HZ,
    I2C_ADDRESS_MAX,
    I2C_ADDRESS_MIN,
    CommandId,
    Version,
    encode_reply,
    split_commands,
)
from lunad.protocol.frame import encode_frame, temp_raw_from_c
from lunad.protocol.registers import (
    I2C_ADDRESS_DEFAULT,
    I2C_REBOOT_SETTLE_S,
    REBOOT_VALUE,
    SAMPLE_BLOCK_LEN,
    SIGNATURE,
    SN_LEN,
    TRIGGER_VALUE,
    Mode,
    Register,
    decode_sample,
)

if TYPE_CHECKING:
    from lunad.daemon.config import SourceSection

log = logging.getLogger("lunad.i2c")

SIM_BUS = "sim"  # bus name of the simulated sensor (lunad.sim.fake_i2c), like loop://
DEFAULT_RATE_HZ = 100  # M05 p.9

TRIGGER_SETTLE_S = 0.003
"""Wait between the trigger write and the block read. The sensor measures at 500 Hz
internally (M05 p.15), so one measurement is 2 ms; 3 ms leaves a margin. ESPHome reads
at once and lets the stale-TICK retry absorb a slow sensor; waiting a little first
keeps ``stale_ticks`` meaning "did not update" rather than "not yet"."""

STALE_RETRY_S = 0.005  # after an unchanged TICK, trigger again this much later (ESPHome)
STALE_REBOOT_AFTER = 5  # consecutive unchanged TICKs that mean a hung sensor (ESPHome)
TICK_BACK_MIN = 0x8000  # a TICK step this large, modulo 2**16, is a step back
TICK_BACK_WITHIN_S = 30.0
"""Judge a TICK step back only this soon after the last TICK. Drivers treat TICK as
milliseconds (docs/tfluna.md §3.2), so it wraps every 65.5 s: within 32.8 s a step of half the
range cannot be a forward one, later it can (on-demand sampling, output paused). A wrong
guess costs one sample and a MODE check, not a fault: MODE still reads trigger."""
BACKOFF_FIRST_S = 0.005  # first retry after a failed transfer ...
BACKOFF_MAX_S = 0.2  # ... doubling up to this
LOST_AFTER_S = 2.0  # transfers failing this long: the sensor is gone (SourceLostError)
OPEN_PROBE_TRIES = 3
"""A sensor waking from ultra-low power NACKs the first read (docs/tfluna.md §3.5)."""
SIGNATURE_LEN = len(SIGNATURE)
VERSION_LEN = 3  # VERSION_REVISION, MINOR, MAJOR at 0x0A..0x0C
TICK_LEN = 2


class SMBusLike(Protocol):
    """The part of ``smbus2.SMBus`` this source uses (``lunad.sim.fake_i2c`` has it too)."""

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]: ...

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None: ...

    def close(self) -> None: ...


class _Step(enum.Enum):
    """What the next transfer of the sample state machine is."""

    MODE = "mode"
    TRIGGER = "trigger"
    READ = "read"
    REBOOT = "reboot"


def _default_factory(bus: int | str) -> SMBusLike:
    """``smbus2.SMBus`` for a bus number or path; the fake for ``sim``."""
    if bus == SIM_BUS:
        from lunad.sim.fake_i2c import FakeSMBus
        from lunad.sim.physics import RealisticSensor, Truth

        # the realistic sensor the pty sim plays, a light wall 2 m away indoors: the
        # paper's literal equations read as daylight, nearly every reading high_ambient
        scene = Truth(distance_m=2.0, reflectivity=0.8, angle_deg=0.0, lux=300.0)
        return FakeSMBus(model=RealisticSensor(), truth=scene)
    import smbus2

    bus_obj: SMBusLike = smbus2.SMBus(bus)
    return bus_obj


def _hint(exc: OSError) -> str:
    """A likely cause for an errno seen when opening, for the log and health."""
    if exc.errno == errno.EREMOTEIO:
        return " (NACK: sensor absent, in ultra-low power, or wired for UART?)"
    if exc.errno == errno.ENOENT:
        return " (I2C not enabled? on a Raspberry Pi: raspi-config, Interface Options, I2C)"
    if exc.errno == errno.EACCES:
        return " (no permission: add the user to group i2c)"
    if exc.errno in (errno.ETIMEDOUT, errno.EIO):
        return " (bus error: check SDA/SCL wiring and pull-ups)"
    return ""


class I2CSource(Source):
    """A TF-Luna in I2C mode (pin 5 to GND at power-up, M05 p.12), read in trigger mode.

    Args:
        bus: I2C bus number (``1`` or ``"1"`` for /dev/i2c-1), a device path, or
            ``"sim"`` for the simulated sensor.
        address: 7-bit slave address, 0x08..0x77 (default 0x10, M05 p.13).
        rate_hz: samples per second; 0 samples only on a SAMPLE_TRIG command.
        smbus_factory: makes the bus object from ``bus``; ``smbus2.SMBus`` (or the
            fake for ``sim``) when None. Tests pass a factory returning a fake.

    Attributes:
        samples: new samples returned as frames.
        stale_ticks: block reads whose TICK had not changed (no new sample).
        nacks: transfers that failed with ``OSError`` (NACK or bus error), open included.
        reboots: reboots issued to a hung sensor.
        restarts: restarts the sensor did by itself (brown-out), seen as MODE back to
            continuous; each time trigger mode was set again.
        version: firmware version read at open.
        signature: the 4 bytes at 0x3C (``b"LUNA"`` on A05 firmware).

    Raises:
        SourceOpenError: the bus cannot be opened or the sensor does not answer.
        ValueError: ``address`` or ``rate_hz`` is out of range (caller misuse).
    """

    def __init__(
        self,
        bus: str | int,
        address: int = I2C_ADDRESS_DEFAULT,
        rate_hz: int = DEFAULT_RATE_HZ,
        smbus_factory: Callable[[int | str], SMBusLike] | None = None,
    ) -> None:
        if not I2C_ADDRESS_MIN <= address <= I2C_ADDRESS_MAX:
            raise ValueError(f"I2C address must be in 0x08..0x77, got {address:#04x}")
        if rate_hz not in FRAME_RATES_HZ:
            raise ValueError(f"rate must be 0 (on demand) or 500/n Hz (1..250), got {rate_hz}")
        if isinstance(bus, str) and bus.isdigit():
            bus = int(bus)
        self.bus = bus
        self.address = address
        self.samples = 0
        self.stale_ticks = 0
        self.nacks = 0
        self._last_error: str | None = None
        self.reboots = 0
        self.restarts = 0
        self.version = Version(0, 0, 0)
        self.signature = b""
        self._rate_hz = rate_hz
        self._enabled = True
        self._triggers_pending = 0
        self._replies = bytearray()
        self._commands = bytearray()
        self._cancel = Wakeup()
        self._step = _Step.TRIGGER
        self._due_ns = 0  # earliest time of the next transfer (settle, retry, reboot)
        self._next_sample_ns = time.monotonic_ns()  # the pacing schedule
        self._retrying = False  # the current sample is a retry: ignore the schedule
        self._last_tick: int | None = None
        self._last_tick_ns = 0  # when _last_tick was read
        self._check_mode = False  # the MODE step reads MODE first: did the sensor restart?
        self._stale_run = 0
        self._failing_since_ns: int | None = None
        self._backoff_s = BACKOFF_FIRST_S
        factory = smbus_factory or _default_factory
        try:
            self._bus: SMBusLike | None = factory(bus)
        except OSError as exc:
            self._cancel.close()  # the daemon retries every 2 s: a pipe a try would add up
            raise SourceOpenError(f"cannot open {self}: {exc}{_hint(exc)}") from exc
        try:
            self._start()
        except BaseException:
            self.close()
            raise

    @classmethod
    def from_config(cls, cfg: SourceSection) -> I2CSource:
        """Open the sensor ``cfg`` names; ``cfg.rate_hz`` is the sensor's frame rate."""
        return cls(cfg.bus, cfg.address, getattr(cfg, "rate_hz", DEFAULT_RATE_HZ))

    def __str__(self) -> str:
        return f"i2c bus {self.bus} address {self.address:#04x}"

    @property
    def rate_hz(self) -> int:
        """Current sampling rate, Hz (0: only on SAMPLE_TRIG)."""
        return self._rate_hz

    # -- open -----------------------------------------------------------------------

    def _start(self) -> None:
        """Probe, read the version, select trigger mode; OSError -> SourceOpenError."""
        sig: list[int] = []
        for attempt in range(OPEN_PROBE_TRIES):
            try:
                sig = self._block(Register.SIGNATURE, SIGNATURE_LEN)
                break
            except OSError as exc:
                self.nacks += 1
                self._last_error = f"{exc}{_hint(exc)}"
                if attempt == OPEN_PROBE_TRIES - 1:
                    raise SourceOpenError(f"cannot open {self}: {exc}{_hint(exc)}") from exc
                time.sleep(BACKOFF_FIRST_S * 2**attempt)
        self.signature = bytes(sig)
        try:
            rev, minor, major = self._block(Register.VERSION_REVISION, VERSION_LEN)
            self.version = Version(major=major, minor=minor, revision=rev)
            self._set_trigger_mode()
        except OSError as exc:
            self.nacks += 1
            raise SourceOpenError(f"cannot set up {self}: {exc}{_hint(exc)}") from exc
        if self.signature == SIGNATURE:
            log.info("%s: TF-Luna signature LUNA, firmware %s", self, self.version)
        elif not any(self.signature):
            log.info("%s: no signature (firmware %s predates A05); carrying on", self, self.version)
        else:
            log.warning(
                "%s: signature %s is not LUNA; is this a TF-Luna? carrying on",
                self,
                self.signature.hex(" "),
            )

    # -- the sample state machine -----------------------------------------------------

    def _read(self, timeout_s: float | None) -> bytes:
        if self._bus is None:
            raise SourceLostError(f"{self}: closed")
        if self._replies:
            out = bytes(self._replies)
            self._replies.clear()
            return out
        deadline = None if timeout_s is None else time.monotonic_ns() + int(timeout_s * 1e9)
        while True:
            now = time.monotonic_ns()
            due = self._action_due_ns()
            if due is not None and due <= now:
                frame = self._act(now)
                if frame:
                    return frame
                continue
            if deadline is not None and now >= deadline:
                return b""
            wake = due if deadline is None else deadline if due is None else min(due, deadline)
            wait_s = None if wake is None else (wake - now) / 1e9
            if self._cancel.wait(wait_s):
                return b""

    def _action_due_ns(self) -> int | None:
        """When the next transfer should happen, or None when no sample is wanted."""
        if self._step is not _Step.TRIGGER or self._retrying:
            return self._due_ns
        if self._triggers_pending:
            return self._due_ns
        if self._enabled and self._rate_hz:
            return max(self._due_ns, self._next_sample_ns)
        return None

    def _act(self, now: int) -> bytes:
        """Do the next transfer; return a frame when it completed a new sample."""
        step = self._step
        try:
            if step is _Step.TRIGGER:
                self._write(Register.TRIG_ONE_SHOT, TRIGGER_VALUE)
                self._step = _Step.READ
                self._due_ns = now + int(TRIGGER_SETTLE_S * 1e9)
                return b""
            if step is _Step.READ:
                return self._read_sample(now)
            if step is _Step.REBOOT:
                self._write(Register.SHUTDOWN_REBOOT, REBOOT_VALUE)
                self.reboots += 1
                self._step = _Step.MODE
                self._due_ns = now + int(I2C_REBOOT_SETTLE_S * 1e9)
                return b""
            if self._check_mode:
                self._note_restart()
            self._set_trigger_mode()
            self._step = _Step.TRIGGER
            self._due_ns = now
            return b""
        except OSError as exc:
            self._failed(now, exc)
            return b""

    def _read_sample(self, now: int) -> bytes:
        s = decode_sample(self._block(Register.DIST_LOW, SAMPLE_BLOCK_LEN))
        self._failing_since_ns = None
        self._backoff_s = BACKOFF_FIRST_S
        self._step = _Step.TRIGGER
        if s.tick == self._last_tick:
            self.stale_ticks += 1
            self._stale_run += 1
            self._retrying = True
            if self._stale_run >= STALE_REBOOT_AFTER:
                self._last_error = (
                    f"TICK stuck at {s.tick} for {self._stale_run} reads: sensor hung, rebooted it"
                )
                log.warning("%s: %s", self, self._last_error)
                self._step = _Step.REBOOT
                self._stale_run = 0
                self._due_ns = now
            else:
                self._due_ns = now + int(STALE_RETRY_S * 1e9)
            return b""
        if (
            self._last_tick is not None
            and (s.tick - self._last_tick) & 0xFFFF >= TICK_BACK_MIN
            and now - self._last_tick_ns < TICK_BACK_WITHIN_S * 1e9
        ):
            log.debug("%s: TICK went back from %d to %d", self, self._last_tick, s.tick)
            self._step = _Step.MODE
            self._check_mode = True
            self._retrying = True
            self._stale_run = 0
            self._due_ns = now
            return b""
        self._last_tick = s.tick
        self._last_tick_ns = now
        self._stale_run = 0
        self._retrying = False
        self.samples += 1
        if self._triggers_pending:
            self._triggers_pending -= 1
        elif self._rate_hz:
            period_ns = 1_000_000_000 // self._rate_hz
            self._next_sample_ns = max(self._next_sample_ns + period_ns, now)
        # TEMP is 0.01 degC; read as signed so that a sub-zero chip is not 655 degC.
        centi = s.temp_centi_c - 0x10000 if s.temp_centi_c >= 0x8000 else s.temp_centi_c
        return encode_frame(s.dist_cm, s.amp, temp_raw_from_c(centi / 100.0))

    @property
    def recovered_faults(self) -> tuple[int, str | None]:
        """Failed transfers retried (``nacks``) plus ``reboots`` and ``restarts``, and
        the last fault."""
        return self.nacks + self.reboots + self.restarts, self._last_error

    def _failed(self, now: int, exc: OSError) -> None:
        """Count a failed transfer and retry: a failed trigger or read resumes at MODE,
        checked, since a sensor that restarted by itself NACKs while it boots."""
        self.nacks += 1
        self._last_error = f"{exc}{_hint(exc)}"
        if self._failing_since_ns is None:
            self._failing_since_ns = now
        elif now - self._failing_since_ns >= LOST_AFTER_S * 1e9:
            raise SourceLostError(
                f"{self}: no answer for {LOST_AFTER_S:.0f} s ({self.nacks} failed transfers): "
                f"{exc}{_hint(exc)}"
            ) from exc
        log.debug("%s: transfer failed (%s); retrying in %.3f s", self, exc, self._backoff_s)
        if self._step is _Step.READ or self._step is _Step.TRIGGER:
            self._step = _Step.MODE
            self._check_mode = True
        self._retrying = True
        self._due_ns = now + int(self._backoff_s * 1e9)
        self._backoff_s = min(self._backoff_s * 2, BACKOFF_MAX_S)

    def _note_restart(self) -> None:
        """Read MODE back; continuous means the sensor restarted by itself, as we set
        trigger mode and never save it. Counted, logged and put on health."""
        (mode,) = self._block(Register.MODE, 1)
        self._check_mode = False
        if mode == Mode.TRIGGER:
            return
        self.restarts += 1
        self._last_error = (
            f"sensor restarted by itself (MODE read {mode}, not trigger {Mode.TRIGGER:d}; "
            "a power dip?): trigger mode set again"
        )
        log.warning("%s: %s", self, self._last_error)

    def _set_trigger_mode(self) -> None:
        """MODE = trigger, and take the current TICK as the one to move on from."""
        self._write(Register.MODE, Mode.TRIGGER)
        lo, hi = self._block(Register.TICK_LOW, TICK_LEN)
        self._last_tick = lo | hi << 8
        self._last_tick_ns = time.monotonic_ns()

    def _block(self, register: int, length: int) -> list[int]:
        bus = self._bus
        if bus is None:
            raise SourceLostError(f"{self}: closed")
        return bus.read_i2c_block_data(self.address, register, length)

    def _write(self, register: int, value: int) -> None:
        bus = self._bus
        if bus is None:
            raise SourceLostError(f"{self}: closed")
        bus.write_byte_data(self.address, register, value)

    # -- UART command emulation -------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Take UART command frames and answer as a UART TF-Luna would (docs/tfluna.md section 2.2).

        GET_VERSION answers from the version registers, READ_MANU_BIN from the serial
        number registers; SAMPLE_FREQ sets the pacing
        (0: sample only on SAMPLE_TRIG) and echoes the rate in force; OUTPUT_EN
        pauses or resumes sampling and echoes; SAMPLE_TRIG takes one sample on the
        next read. Replies come out of the next ``read`` ahead of any sample.
        """
        self._commands += data
        for cmd_id, payload in split_commands(self._commands):
            self._command(cmd_id, payload)

    def _command(self, cmd_id: int, payload: bytes) -> None:
        try:
            if cmd_id == CommandId.GET_VERSION:
                v = self.version
                self._replies += encode_reply(cmd_id, bytes((v.revision, v.minor, v.major)))
            elif cmd_id == CommandId.SAMPLE_FREQ:
                (hz,) = struct.unpack("<H", payload)
                if hz in FRAME_RATES_HZ and hz != self._rate_hz:
                    self._rate_hz = hz
                    self._next_sample_ns = time.monotonic_ns()
                self._replies += encode_reply(cmd_id, struct.pack("<H", self._rate_hz))
            elif cmd_id == CommandId.OUTPUT_EN:
                enabled = bool(payload[0])
                if enabled and not self._enabled:
                    self._next_sample_ns = time.monotonic_ns()
                self._enabled = enabled
                self._replies += encode_reply(cmd_id, bytes((int(enabled),)))
            elif cmd_id == CommandId.SAMPLE_TRIG:
                self._triggers_pending += 1
            elif cmd_id == CommandId.READ_MANU_BIN:  # the serial number registers 0x10..0x1D
                sn = bytes(self._block(Register.SN, SN_LEN))
                self._replies += encode_reply(cmd_id, sn)
            else:
                log.debug("%s: ignoring UART command %#04x (no I2C equivalent)", self, cmd_id)
        except (struct.error, IndexError):
            log.debug("%s: malformed UART command %#04x %s", self, cmd_id, payload.hex(" "))
        except OSError as exc:  # a NACK reading registers: health's field stays null
            self.nacks += 1
            log.debug("%s: no answer to UART command %#04x: %s", self, cmd_id, exc)

    # -- lifecycle --------------------------------------------------------------------

    def cancel(self) -> None:
        """Wake a ``read`` waiting for the next sample; it returns no data."""
        self._cancel.set()

    def close(self) -> None:
        """Release the bus; safe to call twice. The sensor stays in trigger mode."""
        self._cancel.close()
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.close()
            except OSError:
                pass
