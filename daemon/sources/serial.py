"""UART source through pyserial.

Opened with ``serial.serial_for_url(..., exclusive=True)``: a path, ``loop://``,
``spy:///dev/ttyAMA0`` (hex dump of the traffic) or ``socket://host:port`` work with
no extra code, and a second process cannot steal bytes from an open port. pyserial
reports a pulled USB adapter as ``SerialException`` on a read after ``poll`` said
ready (serialposix.py); that, and any OSError, is ``SourceLostError`` here.

Opening says why it failed in terms of what to do: a port another process holds is a
``PortBusyError`` naming that process and how to stop it (found in ``/proc/locks``,
where pyserial's ``flock`` shows, readable without root); a missing Raspberry Pi UART
(``/dev/serial0``, ``/dev/ttyAMA*``, ``/dev/ttyS0``) gets the hint to enable it, as
docs/raspberry-pi.md section 2 describes.

A path is often a name for a node rather than the node: ``/dev/serial0``, a udev
``/dev/tfluna-front`` or a ``/dev/serial/by-id/...`` link. When such a name moves to
another node while the port stays open (a udev rule re-pointed, two adapters swapping
names), the old node need not hang up: it just goes silent, and the daemon would wait
on it for ever. So a silent port checks that its path still names it: on a read that
timed out with nothing, at most once a second (``PATH_CHECK_S``), never on the path a
frame takes. When the path now names another node, or nothing, the source logs one
INFO line with both targets, closes the port and raises ``SourceLostError``: the
daemon then reopens from the path as after an unplug, which also configures the
sensor behind it (it may be another one) and clears health's firmware and serial.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import select
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from time import monotonic_ns
from typing import TYPE_CHECKING

import serial

from lunad.daemon.errors import SourceLostError, SourceOpenError
from lunad.daemon.sources.base import Source

READ_MAX_BYTES = 4096
"""Most bytes one read takes (455 frames): a record of a recording holds one read, and
a recording's reader takes at most two reads' worth after its last good record as a
record a power cut tore (``MAX_TORN_BYTES``, recording.py); what is left waits in the
kernel or the socket for the next read."""
PATH_CHECK_S = 1.0
"""A silent port checks at most this often that its path still names it (two ``stat``
calls): a sensor that stops answering is told from a moved name within about this,
and a port that times out many reads a second pays for one check."""
PATH_GONE_ERRNOS = frozenset({errno.ENOENT, errno.ENOTDIR, errno.ELOOP})
"""``stat`` errnos that mean the path names no node now (a dangling or looping link);
any other failure (EACCES) says nothing about the port and keeps it."""

log = logging.getLogger("lunad.serial")

if TYPE_CHECKING:
    from lunad.daemon.config import SourceSection

BUSY_ERRNOS = frozenset({errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY})
"""Errnos of a port someone else holds: pyserial's ``flock(LOCK_EX | LOCK_NB)`` on an
exclusively opened port fails with EWOULDBLOCK (serialposix.py), and ``open`` of a tty
another program put in TIOCEXCL mode with EBUSY (tty_ioctl(4))."""

PI_UART = re.compile(r"/dev/(serial0|ttyAMA\d+|ttyS0)")
"""Device paths of a Raspberry Pi's own UARTs: absent until the UART is enabled
(docs/raspberry-pi.md, "Which port is /dev/serial0?")."""

PI_UART_HINT = (
    "UART not enabled? on a Raspberry Pi: raspi-config, Interface Options, Serial Port:"
    " login shell no, hardware yes (sets enable_uart=1; on a Pi 5 dtparam=uart0=on),"
    " then reboot"
)
"""What docs/raspberry-pi.md section 2 does, in one line; the console must be off too,
or a login shell shares the port with the sensor."""
PI5_SERIAL0_HINT = "on a Pi 5 /dev/serial0 is the debug connector: use /dev/ttyAMA0"

STOP_THE_DAEMON = "sudo systemctl stop lunad@NAME"
"""The usual holder of a sensor's port is its daemon; NAME is its config's name."""

COMMAND_SHOWN_CHARS = 80
"""A holder's command line is cut to this many characters to keep the error one line."""


class PortBusyError(SourceOpenError):
    """The port is held by another process, named in the message with how to stop it.

    A ``SourceOpenError``, so the daemon retries it like an absent port (the holder may
    let go); commands that cannot wait for that (``record``, ``calibrate``) catch it
    first and stop with a non-zero exit.

    Attributes:
        device: the port as configured.
        holder: the process that holds it, when ``/proc/locks`` shows it.
    """

    def __init__(self, device: str, holder: PortHolder | None) -> None:
        self.device = device
        self.holder = holder
        if holder is None:
            who = "another process"
            fix = f"`sudo fuser -v {device}` names it; if it is lunad: {STOP_THE_DAEMON}"
        elif holder.unit is not None:
            who = f"{holder.unit} (pid {holder.pid})"
            systemctl = "systemctl --user" if holder.user_unit else "sudo systemctl"
            fix = f"stop it first: {systemctl} stop {holder.unit.removesuffix('.service')}"
        else:
            who = f"pid {holder.pid} ({holder.command})" if holder.command else f"pid {holder.pid}"
            fix = "stop that process first"
        super().__init__(f"cannot open {device}: the port is in use by {who}; {fix}")


@dataclass(frozen=True, slots=True)
class PortHolder:
    """A process holding a port's lock.

    Attributes:
        pid: its process id, as this process's pid namespace sees it.
        unit: the systemd service it runs in (``lunad@front.service``), or None.
        user_unit: True when ``unit`` belongs to a user's service manager.
        command: its command line, cut to ``COMMAND_SHOWN_CHARS``; empty if unreadable.
    """

    pid: int
    unit: str | None
    user_unit: bool
    command: str


def port_holder(device: str, proc: Path = Path("/proc")) -> PortHolder | None:
    """The process holding a lock on ``device``, from ``/proc/locks``; None when unknown.

    ``/proc/locks`` lists each lock with its owner's pid and the locked file as
    ``MAJOR:MINOR:INODE`` (hex, hex, decimal: the filesystem's device and the inode),
    and needs no privilege, unlike reading other users' ``/proc/PID/fd``. A lock whose
    owner lives in another pid namespace shows pid 0 and gives None.

    Args:
        device: a path (a URL such as ``socket://`` has no lock and gives None).
        proc: the proc filesystem's root; tests pass a directory laid out like it.
    """
    try:
        st = os.stat(device)
        locks = (proc / "locks").read_text()
    except (OSError, ValueError):
        return None
    wanted = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    for line in locks.splitlines():
        fields = line.split()
        if len(fields) < 6 or fields[1] == "->":  # "->": a waiter, not the holder
            continue
        try:
            major, minor, inode = fields[5].split(":")
            pid = int(fields[4])
            if (int(major, 16), int(minor, 16), int(inode)) != wanted or pid <= 0:
                continue
        except ValueError:
            continue
        unit, user_unit = _service_of(proc / str(pid) / "cgroup")
        return PortHolder(pid, unit, user_unit, _command_of(proc / str(pid) / "cmdline"))
    return None


def _service_of(cgroup_file: Path) -> tuple[str | None, bool]:
    """The systemd service whose own cgroup a process is in, and whether it is a user
    one: the last component of its unified (``0::``) or ``name=systemd`` cgroup path,
    when that ends in ``.service``. A process in a terminal sits in a ``.scope``."""
    try:
        text = cgroup_file.read_text()
    except OSError:
        return None, False
    for line in text.splitlines():
        parts = line.split(":", 2)  # HIERARCHY:CONTROLLERS:PATH (cgroups(7))
        if len(parts) == 3 and parts[1] in ("", "name=systemd"):
            path = parts[2]
            unit = path.rstrip("/").rpartition("/")[2]
            if unit.endswith(".service"):
                return unit, "/user@" in path
    return None, False


def _command_of(cmdline_file: Path) -> str:
    """A process's command line, the interpreter's path shortened to its name."""
    try:
        argv = [a.decode(errors="replace") for a in cmdline_file.read_bytes().split(b"\0") if a]
    except OSError:
        return ""
    if argv:
        argv[0] = os.path.basename(argv[0])
    text = " ".join(" ".join(argv).split())  # one line, whatever the arguments hold
    return text if len(text) <= COMMAND_SHOWN_CHARS else text[: COMMAND_SHOWN_CHARS - 1] + "…"


def _open_problem(device: str, exc: OSError) -> str:
    """Why ``device`` did not open, for the log and health, with a likely cause.

    pyserial words an OS error as ``[Errno 2] could not open port X: [Errno 2] No such
    file or directory: 'X'``; the errno's own text says the same once.
    """
    why = os.strerror(exc.errno) if exc.errno else str(exc)
    if exc.errno == errno.ENOENT and PI_UART.fullmatch(device):
        hints = [PI_UART_HINT, "docs/raspberry-pi.md"]
        if device == "/dev/serial0":
            hints.insert(1, PI5_SERIAL0_HINT)
        return f"{why} ({'; '.join(hints)})"
    return why


class SerialSource(Source):
    """A TF-Luna on a serial port (8N1, M05 p.12).

    Args:
        device: a path or a pyserial URL.
        baud: the line's speed, Bd.

    A read that times out on a path (not a URL) checks, at most once a second, that
    the path still names the open node (``_check_path``): a silent port behind a name
    that moved is given up with ``SourceLostError``, so that it is reopened.

    Raises:
        PortBusyError: another process holds the port.
        SourceOpenError: it cannot be opened for another reason (absent, no permission,
            a bad URL); the message carries a hint where one is likely.
    """

    def __init__(self, device: str, baud: int = 115200) -> None:
        self.device = device
        self.baud = baud
        try:
            self._ser = serial.serial_for_url(
                device, baudrate=baud, timeout=0.5, exclusive=True, do_not_open=False
            )
        except (serial.SerialException, OSError) as exc:  # SerialException is an OSError
            if exc.errno in BUSY_ERRNOS:
                raise PortBusyError(device, port_holder(device)) from exc
            raise SourceOpenError(f"cannot open {device}: {_open_problem(device, exc)}") from exc
        except ValueError as exc:
            raise SourceOpenError(f"cannot open {device}: {exc}") from exc
        ser = self._ser
        # The port and pyserial's abort pipe, polled together; None for URL ports.
        self._poll: Callable[[float | None], list[tuple[int, int]]] | None = None
        if type(ser) is serial.Serial and ser.fd is not None and ser.pipe_abort_read_r is not None:
            self._fd: int = ser.fd
            self._abort: int = ser.pipe_abort_read_r
            poller = select.poll()
            poller.register(self._fd, select.POLLIN)
            poller.register(self._abort, select.POLLIN)
            self._poll = poller.poll
        # pyserial's socket:// counts a readable socket as 1 byte waiting (select), so
        # its reads would take 2 bytes each: 5 reads and 5 records a frame at 250 Hz.
        self._waiting_is_one = type(ser).__module__.endswith(".protocol_socket")
        # The node the path named at open, for ``_check_path``; None for URL ports.
        self._opened: os.stat_result | None = None
        self._opened_name = ""
        self._next_path_check = 0
        if self._poll is not None:
            try:
                self._opened = os.fstat(self._fd)
                self._opened_name = os.ttyname(self._fd)
            except OSError:
                self._opened_name = os.path.realpath(device)

    @classmethod
    def from_config(cls, cfg: SourceSection) -> SerialSource:
        """Open the port ``cfg`` names."""
        return cls(cfg.device, cfg.baud)

    @property
    def buffers(self) -> bool:
        """True: the kernel (or a socket) keeps what arrives until it is read."""
        return True

    def _read(self, timeout_s: float | None) -> bytes:
        """One ``poll`` and one ``read`` on a real port; pyserial's path for URLs.
        Whatever either raises is ``SourceLostError``.

        pyserial's ``read(1)`` then ``read(in_waiting)`` costs five system calls per
        frame; this is two, and still wakes on ``cancel()`` through pyserial's abort
        pipe. ``poll`` on the two descriptors, registered once, costs about 60 % of
        a ``select`` on them. Always poll, even with a zero timeout: pyserial sets
        VMIN = VTIME = 0, so an empty tty reads as b"" (not EAGAIN), and only after
        a ``poll`` said readable does b"" mean the device is gone. ``loop://``,
        ``socket://`` and ``spy://`` keep the generic path. Only a ``poll`` that timed
        out may look at the path (``_check_path``): bytes cost nothing more.
        """
        poll = self._poll
        try:
            if poll is None:
                return self._read_generic(timeout_s)
            fd = self._fd
            ready = poll(None if timeout_s is None else timeout_s * 1000.0)
            if not ready:
                if self._opened is not None and monotonic_ns() >= self._next_path_check:
                    self._check_path()  # silent: is the path still this port?
                return b""
            if len(ready) > 1 or ready[0][0] != fd:
                os.read(self._abort, 1000)  # cancel() woke us
                if len(ready) == 1:
                    return b""  # nothing to read; when both are ready, data first
            data = os.read(fd, READ_MAX_BYTES)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            # TypeError/AttributeError: pyserial's read on a port closed under it;
            # SerialException: also a ``socket://`` port whose server went away.
            raise SourceLostError(f"{self.device}: {exc}") from exc
        if not data:
            raise SourceLostError(f"{self.device}: readable but returned no data (unplugged?)")
        return data

    def _check_path(self) -> None:
        """Close the port and raise ``SourceLostError`` when the configured path no
        longer names the open node: it resolves to another one, or to nothing.

        Called by ``_read`` only after a ``poll`` that timed out with nothing, and at
        most every ``PATH_CHECK_S``: a streaming port is never checked, since its
        bytes show it works. The open node is compared by identity (``fstat`` of the
        descriptor against ``stat`` of the path: device and inode), so a link that is
        rewritten to the same target is no change. Closing here frees the old node at
        once; the caller reopens from the path (the daemon after 0.1 s, as after an
        unplug), and ``close`` again is harmless.

        Raises:
            SourceLostError: the path now names another node or none; the message
                names the old and the new target.
        """
        opened = self._opened
        if opened is None:
            return
        self._next_path_check = monotonic_ns() + int(PATH_CHECK_S * 1e9)
        try:
            now = os.stat(self.device)
        except OSError as exc:
            if exc.errno not in PATH_GONE_ERRNOS:
                return
            target = None
        else:
            if os.path.samestat(now, opened):
                return
            target = os.path.realpath(self.device)
        old = self._opened_name
        if target is None:
            why = f"{self.device} no longer exists; {old}, open through it, is silent"
        else:
            why = f"{self.device} now resolves to {target}, not {old}, which is open and silent"
        log.info("%s: closing %s to open %s again", why, old, self.device)
        self.close()
        raise SourceLostError(why)

    def _read_generic(self, timeout_s: float | None) -> bytes:
        """A byte within ``timeout_s``, then what waits after it, at most
        ``READ_MAX_BYTES`` in all: ``in_waiting`` says how much, except on a
        ``socket://`` port, where a read that does not wait (timeout 0: one ``recv``)
        takes what came."""
        ser = self._ser
        if ser.timeout != timeout_s:
            ser.timeout = timeout_s
        data = ser.read(1)
        if data:
            if self._waiting_is_one:
                ser.timeout = 0
                data += ser.read(READ_MAX_BYTES - 1)
            else:
                waiting = ser.in_waiting
                if waiting:
                    data += ser.read(min(waiting, READ_MAX_BYTES - 1))
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
        """Close the port; safe to call twice."""
        self._poll = None
        self._opened = None
        try:
            self._ser.close()
        except (OSError, serial.SerialException):
            pass

    def __str__(self) -> str:
        return f"serial {self.device} {self.baud} Bd"
