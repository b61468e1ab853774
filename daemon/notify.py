"""systemd readiness, status and watchdog notifications, with the standard library only.

How this works: systemd (``Type=notify``) puts the path of a datagram socket in
``NOTIFY_SOCKET``; the service sends it newline-separated ``KEY=VALUE`` fields, one
datagram per notification (sd_notify(3)). A value starting with ``@`` names a socket in
the Linux abstract namespace, which on the wire starts with a NUL byte. With
``WatchdogSec=`` set, systemd also exports ``WATCHDOG_USEC`` (and ``WATCHDOG_PID``) and
restarts the service when no ``WATCHDOG=1`` arrives within that time; we ping at half of
it, as sd_watchdog_enabled(3) recommends.

The Notifier never pings on its own (no thread, no timer): the read loop calls
``watchdog()`` when its deadline passes, so a wedged loop stops the pings and systemd
restarts the daemon. A timer thread would keep a hung daemon alive forever.

Unlike bb4242/sdnotify, which swallows every exception, a failed send is logged at
warning (once, then at debug) and counted in ``errors``; it is never raised, because
a vanished notify socket must not take the sensor down with it.
"""

from __future__ import annotations

import errno
import logging
import os
import socket
import time
from collections.abc import Mapping

log = logging.getLogger(__name__)

WATCHDOG_FRACTION = 0.5  # ping at half the timeout (sd_watchdog_enabled(3))
_USEC_PER_S = 1_000_000


class Notifier:
    """Sends sd_notify(3) datagrams to ``address``, or does nothing when it is None.

    Args:
        address: the ``NOTIFY_SOCKET`` value: an absolute path or ``@abstract-name``;
            None disables every send.
        watchdog_interval_s: seconds between ``WATCHDOG=1`` pings (half the systemd
            timeout), or None when systemd runs no watchdog for this process.
    """

    def __init__(self, address: str | None, watchdog_interval_s: float | None = None) -> None:
        self.address = address
        self.errors = 0
        self._sock: socket.socket | None = None
        self._addr: str | bytes = ""
        if address is not None:
            # Abstract names may contain any byte after the leading NUL, so send bytes.
            self._addr = b"\0" + address[1:].encode() if address.startswith("@") else address
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.setblocking(False)
        self.watchdog_interval_s = watchdog_interval_s if self._sock is not None else None

    @classmethod
    def from_env(cls, environ: Mapping[str, str] = os.environ) -> Notifier:
        """A Notifier for what systemd exported; disabled outside systemd.

        Outside systemd (``NOTIFY_SOCKET`` unset, every run by hand) that is expected, so
        it is one debug line; a ``NOTIFY_SOCKET`` that is set but unusable is a warning,
        since then systemd waits for a READY=1 that never comes.

        ``WATCHDOG_USEC`` is honoured only when ``WATCHDOG_PID`` is unset or names this
        process: a child that inherited the variables must not ping for its parent.
        """
        address = environ.get("NOTIFY_SOCKET") or None
        if address is None:
            log.debug("NOTIFY_SOCKET is not set: not running under systemd, notifications off")
            return cls(None)
        if not address.startswith(("/", "@")):
            log.warning("NOTIFY_SOCKET=%r is not a path or @abstract name: ignored", address)
            return cls(None)
        interval_s: float | None = None
        usec_text = environ.get("WATCHDOG_USEC", "")
        pid_text = environ.get("WATCHDOG_PID", "")
        if usec_text and (not pid_text or pid_text == str(os.getpid())):
            try:
                usec = int(usec_text)
            except ValueError:
                log.warning("WATCHDOG_USEC=%r is not an integer: watchdog off", usec_text)
            else:
                if usec > 0:
                    interval_s = usec * WATCHDOG_FRACTION / _USEC_PER_S
        return cls(address, interval_s)

    @property
    def enabled(self) -> bool:
        """True when notifications go somewhere (NOTIFY_SOCKET was set and usable)."""
        return self._sock is not None

    def send(self, *fields: str) -> bool:
        """Send ``KEY=VALUE`` fields in one datagram without blocking.

        Returns:
            True when the datagram was handed to the kernel; False when disabled or the
            send failed (logged and counted in ``errors``, never raised).
        """
        if self._sock is None:
            return False
        try:
            self._sock.sendto("\n".join(fields).encode(), self._addr)
        except OSError as exc:
            self.errors += 1
            level = logging.WARNING if self.errors == 1 else logging.DEBUG
            reason = "queue full" if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK) else exc
            log.log(level, "systemd notify to %s failed (%s)", self.address, reason)
            return False
        return True

    def ready(self) -> bool:
        """The socket is bound and the source is open or being waited for."""
        return self.send("READY=1")

    def status(self, text: str) -> bool:
        """A one-line summary for ``systemctl status`` (newlines would end the field)."""
        return self.send("STATUS=" + " ".join(text.split()))

    def stopping(self) -> bool:
        """Shutdown has begun."""
        return self.send("STOPPING=1")

    def reloading(self) -> bool:
        """A reload (SIGHUP) has begun; send ``ready()`` when it is done.

        ``MONOTONIC_USEC`` (CLOCK_MONOTONIC, microseconds) lets systemd match this
        message to the reload request, as sd_notify(3) asks for ``Type=notify-reload``.
        """
        return self.send("RELOADING=1", f"MONOTONIC_USEC={time.monotonic_ns() // 1000}")

    def watchdog(self) -> bool:
        """Tell systemd the read loop is alive; call it from that loop only."""
        return self.send("WATCHDOG=1")

    def close(self) -> None:
        """Release the socket; safe to call twice. Later sends do nothing."""
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
