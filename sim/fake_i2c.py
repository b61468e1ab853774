"""A TF-Luna on a fake I2C bus: the smbus2 calls the I2C source makes, byte for byte.

How this works: ``FakeSMBus`` stands where ``smbus2.SMBus`` would, as pyserial's
``loop://`` stands for a port. Behind it is a 256-byte register file laid out per
``lunad.protocol.registers`` (M05 Appendix III p.34-35, docs/tfluna.md section 3.2): signature
``LUNA`` at 0x3C, firmware version at 0x0A..0x0C, serial number at 0x10, MODE, ENABLE,
FPS and the limits at their factory values. Reads and writes auto-increment the
register pointer (M05 p.13). Writing 1 to TRIG_ONE_SHOT in trigger mode draws one
reading from a sensor model and stores distance (cm), amp, temperature (0.01 degC)
and a TICK that advances by one (16-bit wrap) at 0x00..0x07. In continuous mode the
sensor refreshes those registers by itself at FPS; here that happens lazily, on the
first sample-register read after a frame period has passed. Writing 2 to
SHUTDOWN_REBOOT restores the saved settings (MODE continuous unless someone saved
trigger mode) and clears a stall; writing 1 to SAVE saves them.

Faults, for tests: ``stall(n)`` (the next n triggers do not update the sample: a hung
sensor, cured by a reboot), ``nack(n)`` (the next n transfers raise ``OSError`` errno
121, as smbus2 does for a NACK), ``absent`` (every transfer NACKs),
``reboot_busy_s`` (the sensor NACKs for that long after a reboot; real ones are "not
accessible during few seconds", docs/tfluna.md section 3.4) and ``brown_out()`` (the same restart,
unasked, as after a supply dip). Counters and logs of every call let a test assert what
went over the bus.

Not modelled: ultra-low power (stored, never entered), the data-ready pin, a new
slave address (stored, never applied), torn reads in continuous mode.
"""

from __future__ import annotations

import errno
import os
import random
import struct
import time
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Protocol

from lunad.protocol.registers import (
    I2C_ADDRESS_DEFAULT,
    REBOOT_VALUE,
    RESTORE_VALUE,
    SAMPLE_BLOCK_LEN,
    SAVE_VALUE,
    SIGNATURE,
    SN_LEN,
    TRIGGER_VALUE,
    Enable,
    Mode,
    Register,
    RegisterSample,
    encode_sample,
)
from lunad.sim.physics import PaperSensor, RawReading, Truth
from lunad.sim.virtual_sensor import FIRMWARE, SERIAL_NUMBER

SMBUS_BLOCK_MAX = 32  # smbus2 refuses longer block transfers (I2C_SMBUS_BLOCK_MAX)
REGISTER_FILE_LEN = 256  # 8-bit register address
DEFAULT_TEMP_C = 40.0  # same chip temperature as the pty device
FACTORY_FPS_HZ = 100  # FPS_LOW/HIGH init 0x64 0x00, M05 p.35
FACTORY_AMP_THR = 100  # AMP_THR init 0x64 0x00, M05 p.35
FACTORY_MAX_DIST = 0x0320
"""MAX_DIST init 0x20 0x03 (800), M05 p.35 (unit disputed, docs/tfluna.md §8)."""

_SETTINGS = range(Register.ULTRA_LOW_POWER, Register.MAX_DIST_HIGH + 1)
"""Registers a save keeps and a reboot restores (the R/W configuration block)."""

_WRITABLE = frozenset(
    {
        Register.ULTRA_LOW_POWER,
        Register.SLAVE_ADDR,
        Register.MODE,
        Register.ENABLE,
        Register.FPS_LOW,
        Register.FPS_HIGH,
        Register.LOW_POWER,
        Register.AMP_THR_LOW,
        Register.AMP_THR_HIGH,
        Register.DUMMY_DIST_LOW,
        Register.DUMMY_DIST_HIGH,
        Register.MIN_DIST_LOW,
        Register.MIN_DIST_HIGH,
        Register.MAX_DIST_LOW,
        Register.MAX_DIST_HIGH,
    }
)
"""Registers that store what is written (M05 p.34-35 "W/R"); writes elsewhere are
ignored, except the command registers SAVE, SHUTDOWN_REBOOT, TRIG_ONE_SHOT and
RESTORE_FACTORY_DEFAULTS, which act."""


class SensorModel(Protocol):
    """Anything that draws one reading for a truth (see ``lunad.sim.physics``)."""

    def sample(self, truth: Truth, rng: random.Random) -> RawReading: ...


def _nack() -> OSError:
    """What smbus2 raises when the slave does not acknowledge (the kernel's EREMOTEIO)."""
    return OSError(errno.EREMOTEIO, os.strerror(errno.EREMOTEIO))


class FakeSMBus:
    """A TF-Luna in I2C mode behind the ``smbus2.SMBus`` calls lunad uses.

    Args:
        bus: ignored; accepted so that ``FakeSMBus(1)`` reads like ``SMBus(1)``.
        address: the sensor's 7-bit address; other addresses NACK.
        truth: the world the sensor sees: fixed, or a function of seconds since the
            bus was made. Default: a white target at 2 m, indoors.
        model: draws readings; the paper's equations 1-3 by default.
        seed: seed of the reading noise.
        temp_c: chip temperature stored in TEMP, degrees Celsius.
        firmware: (major, minor, revision) stored at 0x0C, 0x0B, 0x0A.
        signature: store ``LUNA`` at 0x3C (A05 firmware); False leaves zeros (A03).
        tick: the TICK value before the first sample.
        clock: monotonic seconds; drives continuous mode and ``reboot_busy_s``.

    Attributes (counters and logs, for tests):
        transfers: every call that went on the bus, NACKed or not.
        nacks_sent: transfers that raised ``OSError``.
        block_reads: (register, length) of every acknowledged block read.
        writes: (register, value) of every acknowledged byte written, in order.
        triggers: acknowledged writes of 1 to TRIG_ONE_SHOT.
        history: every sample the sensor produced, oldest first.
        reboots: reboots done through SHUTDOWN_REBOOT.
    """

    def __init__(
        self,
        bus: int | str | None = None,
        address: int = I2C_ADDRESS_DEFAULT,
        truth: Truth | Callable[[float], Truth] | None = None,
        model: SensorModel | None = None,
        seed: int = 0,
        temp_c: float = DEFAULT_TEMP_C,
        firmware: tuple[int, int, int] = FIRMWARE,
        signature: bool = True,
        tick: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        fixed = truth if isinstance(truth, Truth) else Truth()
        self._truth: Callable[[float], Truth] = truth if callable(truth) else (lambda _t: fixed)
        self.address = address
        self.model: SensorModel = model or PaperSensor()
        self.rng = random.Random(seed)
        self.temp_c = temp_c
        self.absent = False
        self.reboot_busy_s = 0.0
        self.transfers = 0
        self.nacks_sent = 0
        self.block_reads: list[tuple[int, int]] = []
        self.writes: list[tuple[int, int]] = []
        self.triggers = 0
        self.history: list[RegisterSample] = []
        self.reboots = 0
        self.closed = False
        self._clock = clock
        self._t0 = clock()
        self._stall = 0
        self._nack = 0
        self._busy_until = 0.0
        self._last_update = self._t0
        self.regs = bytearray(REGISTER_FILE_LEN)
        major, minor, revision = firmware
        self.regs[Register.VERSION_REVISION] = revision
        self.regs[Register.VERSION_MINOR] = minor
        self.regs[Register.VERSION_MAJOR] = major
        self.regs[Register.SN : Register.SN + SN_LEN] = SERIAL_NUMBER[:SN_LEN].ljust(SN_LEN)
        if signature:
            self.regs[Register.SIGNATURE : Register.SIGNATURE + len(SIGNATURE)] = SIGNATURE
        self._put16(Register.TICK_LOW, tick)
        self._restore_factory()
        self._saved = bytes(self.regs[_SETTINGS.start : _SETTINGS.stop])

    # -- fault knobs --------------------------------------------------------------

    def stall(self, n: int) -> None:
        """Hang the sensor: the next ``n`` triggers leave sample and TICK unchanged.

        A reboot (SHUTDOWN_REBOOT = 2) clears what is left of the stall.
        """
        self._stall = n

    def brown_out(self) -> None:
        """Restart the sensor by itself, as a supply dip does, not through the bus.

        As after SHUTDOWN_REBOOT: the saved settings come back (MODE continuous unless
        trigger mode was saved), the sample registers clear and the sensor NACKs for
        ``reboot_busy_s``. Not counted in ``reboots``, which counts the reboots asked for.
        """
        self._restart()

    def nack(self, n: int) -> None:
        """Make the next ``n`` transfers fail with ``OSError`` errno 121 (NACK)."""
        self._nack = n

    @property
    def mode(self) -> Mode:
        """The MODE register as the sensor holds it now."""
        return Mode(self.regs[Register.MODE])

    # -- smbus2.SMBus calls ---------------------------------------------------------

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        """Read ``length`` bytes from ``register`` on, in one transaction."""
        if length > SMBUS_BLOCK_MAX:
            raise ValueError(f"Desired block length over {SMBUS_BLOCK_MAX} bytes")
        self._transfer(i2c_addr)
        self.block_reads.append((register, length))
        if register <= Register.TICK_HIGH:
            self._continuous_refresh()
        return [self.regs[(register + i) % REGISTER_FILE_LEN] for i in range(length)]

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """Read one register."""
        self._transfer(i2c_addr)
        if register <= Register.TICK_HIGH:
            self._continuous_refresh()
        return self.regs[register % REGISTER_FILE_LEN]

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        """Write one register (command registers act at once)."""
        self._transfer(i2c_addr)
        self._write(register, value)

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: Sequence[int], force: bool | None = None
    ) -> None:
        """Write ``data`` from ``register`` on, in one transaction (auto-increment)."""
        if len(data) > SMBUS_BLOCK_MAX:
            raise ValueError(f"Data length cannot exceed {SMBUS_BLOCK_MAX} bytes")
        self._transfer(i2c_addr)
        for i, value in enumerate(data):
            self._write((register + i) % REGISTER_FILE_LEN, value)

    def close(self) -> None:
        """Release the bus; safe to call twice."""
        self.closed = True

    def __enter__(self) -> FakeSMBus:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- the sensor -----------------------------------------------------------------

    def _transfer(self, i2c_addr: int) -> None:
        if self.closed:
            raise OSError(errno.EBADF, "I2C bus is closed")
        self.transfers += 1
        if (
            self.absent
            or i2c_addr != self.address
            or self._nack > 0
            or self._clock() < self._busy_until
        ):
            self._nack = max(0, self._nack - 1)
            self.nacks_sent += 1
            raise _nack()

    def _write(self, register: int, value: int) -> None:
        if not 0 <= value <= 0xFF:
            raise ValueError(f"register value must be a byte, got {value}")
        self.writes.append((register, value))
        if register == Register.TRIG_ONE_SHOT:
            if value == TRIGGER_VALUE:
                self.triggers += 1
                if self.mode is Mode.TRIGGER:
                    self._measure()
        elif register == Register.SHUTDOWN_REBOOT:
            if value == REBOOT_VALUE:
                self._reboot()
        elif register == Register.SAVE:
            if value == SAVE_VALUE:
                self._saved = bytes(self.regs[_SETTINGS.start : _SETTINGS.stop])
        elif register == Register.RESTORE_FACTORY_DEFAULTS:
            if value == RESTORE_VALUE:
                self._restore_factory()
        elif register in _WRITABLE:
            self.regs[register] = value

    def _measure(self) -> None:
        """One measurement into 0x00..0x07, unless the sensor is stalled or off."""
        if self._stall > 0:
            self._stall -= 1
            return
        if self.regs[Register.ENABLE] != Enable.ON:
            return
        now = self._clock()
        self._last_update = now
        reading = self.model.sample(self._truth(now - self._t0), self.rng)
        dist_cm = reading.dist_cm
        if reading.amp < self._get16(Register.AMP_THR_LOW):
            dist_cm = self._get16(Register.DUMMY_DIST_LOW)
        tick = (self._get16(Register.TICK_LOW) + 1) & 0xFFFF
        temp = round(self.temp_c * 100) & 0xFFFF  # two's complement below 0 degC (assumed)
        sample = RegisterSample(
            dist_cm=max(0, min(0xFFFF, dist_cm)),
            amp=max(0, min(0xFFFF, reading.amp)),
            temp_centi_c=temp,
            tick=tick,
        )
        self.regs[0:SAMPLE_BLOCK_LEN] = encode_sample(sample)
        self.history.append(sample)

    def _continuous_refresh(self) -> None:
        """Continuous mode: a new sample once per frame period (FPS register, Hz)."""
        if self.mode is not Mode.CONTINUOUS:
            return
        fps = self._get16(Register.FPS_LOW) or FACTORY_FPS_HZ
        if self._clock() - self._last_update >= 1.0 / fps:
            self._measure()

    def _reboot(self) -> None:
        self.reboots += 1
        self._restart()

    def _restart(self) -> None:
        self._stall = 0
        self.regs[_SETTINGS.start : _SETTINGS.stop] = self._saved
        self.regs[0:SAMPLE_BLOCK_LEN] = bytes(SAMPLE_BLOCK_LEN)
        self._last_update = self._clock()
        self._busy_until = self._last_update + self.reboot_busy_s

    def _restore_factory(self) -> None:
        r = self.regs
        r[_SETTINGS.start : _SETTINGS.stop] = bytes(len(_SETTINGS))
        r[Register.SLAVE_ADDR] = I2C_ADDRESS_DEFAULT
        r[Register.MODE] = Mode.CONTINUOUS
        r[Register.ENABLE] = Enable.ON
        self._put16(Register.FPS_LOW, FACTORY_FPS_HZ)
        self._put16(Register.AMP_THR_LOW, FACTORY_AMP_THR)
        self._put16(Register.MAX_DIST_LOW, FACTORY_MAX_DIST)

    def _get16(self, low: int) -> int:
        return int(struct.unpack_from("<H", self.regs, low)[0])

    def _put16(self, low: int, value: int) -> None:
        struct.pack_into("<H", self.regs, low, value & 0xFFFF)
