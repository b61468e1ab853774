"""A virtual TF-Luna on a pseudo-terminal, behind a stable symlink.

How this works: ``openpty`` gives a master/slave pair; the slave is put in raw mode
and a symlink (``link``) points at it, so the daemon opens a path exactly as it would
open ``/dev/serial0``. One thread owns the master: it waits in ``select`` for host
commands or the next frame time (absolute schedule, no drift, no busy-wait), answers
commands through ``VirtualSensor`` and writes data frames drawn from a sensor model.

Fault injection for tests and soak runs: garbage bytes, corrupted checksums, a pause
(sensor silent) and unplug/replug (close the pty, make a new one behind the same
symlink). Bytes the host does not read pile up in a bounded out-buffer; past it, new
frames are dropped and counted, as a UART drops what nobody reads.

The link is only ever a symlink this device made: an existing file or folder at its
path is refused, never replaced or removed. If the device thread dies, ``close``
raises ``DeviceError`` with the cause, so a sensor that went mute is not mistaken
for a clean run.
"""

from __future__ import annotations

import contextlib
import errno
import os
import random
import select
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Protocol, TextIO

from lunad.protocol.commands import take_command_frames
from lunad.protocol.frame import temp_raw_from_c
from lunad.sim.physics import PaperSensor, RawReading, Truth
from lunad.sim.scenario import TRUTH_CSV_HEADER, truth_csv_row
from lunad.sim.virtual_sensor import Settings, VirtualSensor

TRUTH_OUT_HEADER = TRUTH_CSV_HEADER + ",good,dist_cm,amp"
"""Columns of ``truth_out``: the truth, whether the frame's checksum was left good,
and the reading the sensor reported (centimetres, amp)."""
OUT_BUFFER_MAX = 4096  # bytes held for a host that does not read (about 450 frames)
DEFAULT_TEMP_C = 40.0


class SensorModel(Protocol):
    """Anything that draws one reading for a truth (see ``lunad.sim.physics``).

    ``amp_threshold`` is the sensor's current one (ID 0x22), so that a model draws
    no noise for a reading below it; ``VirtualSensor.data_frame`` applies it.
    """

    def sample(self, truth: Truth, rng: random.Random, amp_threshold: int = ...) -> RawReading: ...


class DeviceError(RuntimeError):
    """The device thread died; ``__cause__`` is what killed it."""


def default_link() -> Path:
    """``$XDG_RUNTIME_DIR/lunad/tfluna-sim``, or a per-user folder in /tmp without it."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    base = Path(runtime) / "lunad" if runtime else Path(f"/tmp/lunad-{os.getuid()}")
    return base / "tfluna-sim"


class PtyDevice:
    """A virtual TF-Luna streaming on a pty.

    Args:
        truth: the world the sensor sees: fixed, or a function of seconds since start
            (a scenario's ``truth_at``). Default: a white target at 2 m, in the dark.
        model: draws readings; the paper's equations 1-3 by default.
        rate_hz: initial frame rate (0 = trigger mode).
        link: the stable symlink to the pty slave; ``default_link()`` if None.
        seed: seed of the reading noise and of random faults.
        temp_c: chip temperature reported, degrees Celsius.
        garbage_rate: chance per frame of a burst of 1-16 random bytes before it.
        corrupt_rate: chance per frame of a wrong checksum.
        truth_out: text file that gets one CSV row per frame (``TRUTH_OUT_HEADER``).
        output_enabled: start with the output on; off makes the sensor wait for the
            host's ``output on`` command, so every frame sent finds a reader.
        on_frame_sent: called from the device thread with (the frame's index among
            good frames sent, ``time.monotonic_ns()``) once its last byte is written;
            benchmarks measure latency from it.
        on_bytes_written: called from the device thread with (the bytes of one write
            to the pty, the end offsets within them of the good frames it completed,
            ``time.monotonic_ns()``); the soak's reference parser reads every byte.
        on_error: called from the device thread with the exception that is about to
            end it (``close`` raises it again as ``DeviceError``); lets a caller
            waiting on something else stop at once.
        view: what the beam sees at a time given the truth then (``sim.edges.edge_view``:
            both surfaces just after a jump); the model draws from it, ``truth_out``
            logs the truth. None: the truth itself.

    Use as a context manager: ``with PtyDevice(...) as dev: serve(dev.path)``.
    """

    def __init__(
        self,
        truth: Callable[[float], Truth] | Truth | None = None,
        model: SensorModel | None = None,
        rate_hz: int = 100,
        link: Path | str | None = None,
        seed: int = 0,
        temp_c: float = DEFAULT_TEMP_C,
        garbage_rate: float = 0.0,
        corrupt_rate: float = 0.0,
        truth_out: TextIO | None = None,
        output_enabled: bool = True,
        on_frame_sent: Callable[[int, int], None] | None = None,
        on_bytes_written: Callable[[bytes, list[int], int], None] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        view: Callable[[float, Truth], Truth] | None = None,
    ) -> None:
        fixed = truth if isinstance(truth, Truth) else Truth()
        self._truth: Callable[[float], Truth] = truth if callable(truth) else (lambda _t: fixed)
        self.model: SensorModel = model or PaperSensor()
        self._view = view
        self.link = Path(link) if link else default_link()
        self.sensor = VirtualSensor(Settings(rate_hz=rate_hz, output_enabled=output_enabled))
        self.rng = random.Random(seed)
        self.temp_raw = temp_raw_from_c(temp_c)
        self.garbage_rate = garbage_rate
        self.corrupt_rate = corrupt_rate
        self.truth_out = truth_out
        self.on_frame_sent = on_frame_sent
        self.on_bytes_written = on_bytes_written
        self.on_error = on_error
        self.error: BaseException | None = None
        """What killed the device thread, if something did."""
        self._error_raised = False
        self.frames_sent = 0
        self.frames_corrupted = 0
        self.frames_unread = 0
        self.garbage_bytes = 0
        self.commands_received = 0
        self.replugs = 0
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_name = ""
        self._out = bytearray()
        self._frame_ends: deque[int] = deque()
        self._inject = bytearray()
        self._corrupt_next = 0
        self._silent_until = 0.0
        self._wake_r, self._wake_w = os.pipe()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._t0 = 0.0

    @property
    def path(self) -> str:
        """The path a host opens: the stable symlink."""
        return str(self.link)

    @property
    def slave_name(self) -> str:
        """The pty slave the symlink points at now (changes on replug)."""
        return self._slave_name

    def start(self) -> PtyDevice:
        """Open the pty, make the symlink and start streaming.

        Raises:
            OSError: the pty or the link cannot be made (``FileExistsError`` when
                ``link`` names something that is not a symlink). Every descriptor
                is closed again before it propagates.
        """
        try:
            self._open_pty()
            self._t0 = time.monotonic()
            self._thread = threading.Thread(target=self._run, name="pty-device", daemon=True)
            self._thread.start()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop streaming, close the pty and remove the symlink; safe to call twice.

        Raises:
            DeviceError: the device thread had died (once; a second close does not).
        """
        self._stop = True
        self._wake()
        if self._thread is not None:
            if self._thread.is_alive():  # not if ``start`` was interrupted before it ran
                self._thread.join(timeout=2.0)
            self._thread = None
        with self._lock:
            self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._wake_r = self._wake_w = -1
        error = self.error
        if error is not None and not self._error_raised:
            self._error_raised = True
            raise DeviceError(
                f"the virtual sensor stopped: {type(error).__name__}: {error}"
            ) from error

    def __enter__(self) -> PtyDevice:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def inject_garbage(self, data: bytes | int) -> None:
        """Send ``data`` (or that many random bytes) before the next frame."""
        if isinstance(data, int):
            data = self.rng.randbytes(data)
        with self._lock:
            self._inject += data
            self.garbage_bytes += len(data)
        self._wake()

    def corrupt_next(self, n: int = 1) -> None:
        """Give the next ``n`` frames a wrong checksum."""
        with self._lock:
            self._corrupt_next += n

    def pause(self, seconds: float) -> None:
        """Go silent for ``seconds`` (no frames, commands still answered)."""
        self._silent_until = time.monotonic() + seconds

    def unplug(self) -> None:
        """Close the pty and remove the symlink, as a pulled USB adapter does."""
        with self._lock:
            self._close_pty()

    def replug(self) -> None:
        """Open a new pty behind the same symlink."""
        with self._lock:
            self._close_pty()
            self._open_pty()
            self.replugs += 1
        self._wake()

    # -- the device thread -------------------------------------------------

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:
            self.error = exc
            if self.on_error is not None:
                self.on_error(exc)

    def _loop(self) -> None:
        period = 0.0
        next_t = time.monotonic()
        inbuf = bytearray()
        while not self._stop:
            rate = self.sensor.settings.rate_hz
            new_period = 1.0 / rate if rate > 0 else 0.0
            if new_period != period:
                period = new_period
                next_t = time.monotonic() + period
            now = time.monotonic()
            timeout = max(0.0, next_t - now) if period else 1.0
            with self._lock:
                master = self._master
                want_write = bool(self._out or self._inject)
            rlist = [self._wake_r] + ([master] if master is not None else [])
            wlist = [master] if master is not None and want_write else []
            try:
                readable, _, _ = select.select(rlist, wlist, [], timeout)
            except (OSError, ValueError):
                continue
            if self._wake_r in readable:
                os.read(self._wake_r, 4096)
            with self._lock:
                if master is not None and master == self._master:
                    if master in readable:
                        self._read_commands(master, inbuf)
                    while self.sensor.trigger_pending:
                        self.sensor.trigger_pending -= 1
                        self._emit_frame()
                    if period and time.monotonic() >= next_t:
                        self._tick()
                    self._flush(master)
            if period and time.monotonic() >= next_t:
                next_t += period
                if time.monotonic() - next_t > 1.0:
                    next_t = time.monotonic() + period

    def _tick(self) -> None:
        if time.monotonic() < self._silent_until or not self.sensor.settings.output_enabled:
            return
        self._emit_frame()

    def _emit_frame(self) -> None:
        t = time.monotonic() - self._t0
        truth = self._truth(t)
        seen = truth if self._view is None else self._view(t, truth)
        reading = self.model.sample(seen, self.rng, self.sensor.settings.amp_threshold)
        dist_cm = reading.dist_cm or None  # RawReading: 0 means no distance
        frame = self.sensor.data_frame(dist_cm, reading.amp, self.temp_raw)
        if frame is None:
            return
        if self._corrupt_next or (self.corrupt_rate and self.rng.random() < self.corrupt_rate):
            self._corrupt_next = max(0, self._corrupt_next - 1)
            frame = frame[:8] + bytes(((frame[8] + 1 + self.rng.randrange(255)) & 0xFF,))
            self.frames_corrupted += 1
            good = False
        else:
            good = True
        if self.garbage_rate and self.rng.random() < self.garbage_rate:
            junk = self.rng.randbytes(self.rng.randint(1, 16))
            self._inject += junk
            self.garbage_bytes += len(junk)
        if len(self._out) + len(self._inject) + len(frame) > OUT_BUFFER_MAX:
            self.frames_unread += 1
            return
        self._out += self._inject
        self._inject.clear()
        self._out += frame
        if good:
            self._frame_ends.append(len(self._out))
        if self.truth_out is not None:
            self.truth_out.write(
                f"{truth_csv_row(t, truth)},{int(good)},{reading.dist_cm},{reading.amp}\n"
            )

    def _read_commands(self, master: int, inbuf: bytearray) -> None:
        try:
            data = os.read(master, 4096)
        except OSError:
            return
        inbuf += data
        for frame in take_command_frames(inbuf):
            self.commands_received += 1
            self._out += self.sensor.handle_frame(frame)

    def _flush(self, master: int) -> None:
        if self._inject and not self._out:
            self._out += self._inject
            self._inject.clear()
        if not self._out:
            return
        try:
            n = os.write(master, self._out)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno in (errno.EIO, errno.EBADF):
                return
            raise
        ends = self._frame_ends
        hook = self.on_frame_sent
        t_ns = time.monotonic_ns() if hook or self.on_bytes_written else 0
        if self.on_bytes_written is not None:
            self.on_bytes_written(bytes(self._out[:n]), [e for e in ends if e <= n], t_ns)
        del self._out[:n]
        while ends and ends[0] <= n:
            ends.popleft()
            if hook is not None:
                hook(self.frames_sent, t_ns)
            self.frames_sent += 1
        for k in range(len(ends)):
            ends[k] -= n

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._slave_name = os.ttyname(slave)
        if os.path.lexists(self.link) and not self.link.is_symlink():
            raise FileExistsError(
                errno.EEXIST, "exists and is not a symlink; refusing to replace it", str(self.link)
            )
        self.link.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(self._slave_name)
        os.replace(tmp, self.link)

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        self._out.clear()
        self._frame_ends.clear()
        if self.link.is_symlink() and os.readlink(self.link) == self._slave_name:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()

    def _wake(self) -> None:
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"\x00")
