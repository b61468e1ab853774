"""UART source through pyserial.

Opened with ``serial.serial_for_url(..., exclusive=True)``: a path, ``loop://``,
``spy:///dev/ttyAMA0`` (hex dump of the traffic) or ``socket://host:port`` work with
no extra code, and a second process cannot steal bytes from an open port. pyserial
reports a pulled USB adapter as ``SerialException`` on a read after ``poll`` said
ready (serialposix.py); that, and any OSError, is ``SourceLostError`` here.
"""

from __future__ import annotations

import os
import select
import termios
from collections.abc import Callable
from typing import TYPE_CHECKING

import serial

from lunad.daemon.errors import SourceLostError, SourceOpenError
from lunad.daemon.source import Source

VMIN_MAX = 255  # termios VMIN is one byte (termios(3))

if TYPE_CHECKING:
    from lunad.daemon.config import SourceSection


class SerialSource(Source):
    """A TF-Luna on a serial port (8N1, M05 p.12)."""

    def __init__(self, device: str, baud: int = 115200) -> None:
        self.device = device
        self.baud = baud
        try:
            self._ser = serial.serial_for_url(
                device, baudrate=baud, timeout=0.5, exclusive=True, do_not_open=False
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SourceOpenError(f"cannot open {device}: {exc}") from exc
        ser = self._ser
        self._vmin = 0  # VMIN set by ``batch``; pyserial opens with 0
        # The port and pyserial's abort pipe, polled together; None for URL ports.
        self._poll: Callable[[float | None], list[tuple[int, int]]] | None = None
        if type(ser) is serial.Serial and ser.fd is not None and ser.pipe_abort_read_r is not None:
            self._fd: int = ser.fd
            self._abort: int = ser.pipe_abort_read_r
            poller = select.poll()
            poller.register(self._fd, select.POLLIN)
            poller.register(self._abort, select.POLLIN)
            self._poll = poller.poll

    @classmethod
    def from_config(cls, cfg: SourceSection) -> SerialSource:
        """Open the port ``cfg`` names."""
        return cls(cfg.device, cfg.baud)

    @property
    def buffers(self) -> bool:
        """True: the kernel (or a socket) keeps what arrives until it is read."""
        return True

    def batch(self, nbytes: int) -> int:
        """Hold reads until ``nbytes`` (at most 255) are waiting: the tty's VMIN.

        The kernel then keeps ``poll`` from reporting the port readable until VMIN
        bytes are queued (n_tty's ``input_available_p``), so the reader sleeps through
        the frames in between with no timer and no wake-up. A real port only; URL
        ports return 0 (their pyserial path has no VMIN). Checked on Linux with a
        pty: ``poll`` waits for VMIN bytes, and reports a hang-up at once as before.
        """
        if self._poll is None:
            return 0
        vmin = min(nbytes, VMIN_MAX) if nbytes > 1 else 0
        try:
            attrs = termios.tcgetattr(self._fd)
            attrs[6][termios.VMIN] = vmin
            attrs[6][termios.VTIME] = 0
            termios.tcsetattr(self._fd, termios.TCSANOW, attrs)
        except (termios.error, OSError):
            return 0
        self._vmin = vmin
        return vmin

    def _read(self, timeout_s: float | None) -> bytes:
        """One ``poll`` and one ``read`` on a real port; pyserial's path for URLs.
        Whatever either raises is ``SourceLostError``.

        pyserial's ``read(1)`` then ``read(in_waiting)`` costs five system calls per
        frame; this is two, and still wakes on ``cancel()`` through pyserial's abort
        pipe. ``poll`` on the two descriptors, registered once, costs about 60 % of
        a ``select`` on them. Always poll, even with a zero timeout: pyserial sets
        VMIN = VTIME = 0, so an empty tty reads as b"" (not EAGAIN), and only after
        a ``poll`` said readable does b"" mean the device is gone. ``loop://``,
        ``socket://`` and ``spy://`` keep the generic path.
        """
        poll = self._poll
        try:
            if poll is None:
                return self._read_generic(timeout_s)
            fd = self._fd
            ready = poll(None if timeout_s is None else timeout_s * 1000.0)
            if not ready:
                return b""
            if len(ready) > 1 or ready[0][0] != fd:
                os.read(self._abort, 1000)  # cancel() woke us
                if len(ready) == 1:
                    return b""  # nothing to read; when both are ready, data first
            data = os.read(fd, 4096)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            # TypeError/AttributeError: pyserial's read on a port closed under it;
            # SerialException: also a ``socket://`` port whose server went away.
            raise SourceLostError(f"{self.device}: {exc}") from exc
        if not data:
            raise SourceLostError(f"{self.device}: readable but returned no data (unplugged?)")
        return data

    def _read_generic(self, timeout_s: float | None) -> bytes:
        ser = self._ser
        if ser.timeout != timeout_s:
            ser.timeout = timeout_s
        data = ser.read(1)
        if data:
            waiting = ser.in_waiting
            if waiting:
                data += ser.read(waiting)
        return bytes(data)

    def write(self, data: bytes) -> None:
        """Send command bytes; a failure means the device is gone."""
        try:
            self._ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise SourceLostError(f"{self.device}: write failed: {exc}") from exc

    def cancel(self) -> None:
        """Wake a blocked read (pyserial's ``cancel_read``)."""
        cancel = getattr(self._ser, "cancel_read", None)
        if cancel is not None and self._ser.is_open:
            try:
                cancel()
            except (OSError, serial.SerialException):
                pass

    def close(self) -> None:
        """Close the port (VMIN back to 0 for whoever opens it next); safe to call twice."""
        if self._poll is not None and self._vmin:
            self.batch(0)  # a port already gone fails quietly in there
        self._poll = None
        try:
            self._ser.close()
        except (OSError, serial.SerialException):
            pass

    def __str__(self) -> str:
        return f"serial {self.device} {self.baud} Bd"
