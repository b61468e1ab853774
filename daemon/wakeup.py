"""A wake-up that is safe to signal from a signal handler or another thread.

``threading.Event.set`` takes a lock; called from a signal handler that interrupted the
same thread inside ``Event.wait``'s own locked section, it deadlocks. A self-pipe does
not: ``set`` is one non-blocking ``write`` (async-signal-safe), and ``wait`` is a
``select`` on the read end with a timeout. No polling: the waiter sleeps in the kernel.
"""

from __future__ import annotations

import contextlib
import os
import select


class Wakeup:
    """``set()`` from anywhere; ``wait(timeout_s)`` returns True once it was set."""

    def __init__(self) -> None:
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        os.set_blocking(self._w, False)

    def set(self) -> None:
        """Wake the waiter (a pending wake-up is kept until the next ``wait``)."""
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._w, b"\x00")

    def wait(self, timeout_s: float | None) -> bool:
        """Sleep until ``set()`` or ``timeout_s`` seconds; True when woken (and re-armed)."""
        try:
            ready, _, _ = select.select([self._r], [], [], timeout_s)
        except (OSError, ValueError):
            return False
        if not ready:
            return False
        with contextlib.suppress(BlockingIOError, OSError):
            while os.read(self._r, 4096):
                pass
        return True

    def close(self) -> None:
        """Close both ends; safe to call twice."""
        for fd in (self._r, self._w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._r = self._w = -1
