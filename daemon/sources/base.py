"""Where bytes come from: one small interface for every backend (serial, I2C, replay).

Modelled on python-can's ``BusABC``: the public ``read`` does the timestamping once,
each backend overrides the protected ``_read``. Every source yields the same type,
a ``Chunk`` of UART-format bytes, so there is one parser path and one record format.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from time import monotonic_ns
from types import TracebackType
from typing import TYPE_CHECKING, NamedTuple, Self

if TYPE_CHECKING:
    from lunad.daemon.config import SourceSection


class Chunk(NamedTuple):
    """Bytes read in one call, and when (``time.monotonic_ns()`` after the read).

    Immutable; a ``NamedTuple`` (see ``lunad.protocol.frame.Frame``): one per read."""

    data: bytes
    t_mono_ns: int


_new = tuple.__new__
"""Builds a ``Chunk`` without the ``NamedTuple``'s generated Python ``__new__``: one C
call instead of a Python frame, on every read."""


class Source(ABC):
    """A byte source. ``read`` blocks at most ``timeout_s``; ``close`` is idempotent."""

    def read(self, timeout_s: float | None) -> Chunk | None:
        """The next bytes, or None when none arrived within ``timeout_s`` seconds.

        Raises:
            SourceLostError: the device went away; close this source and reopen.
        """
        data = self._read(timeout_s)
        if not data:
            return None
        return _new(Chunk, (data, monotonic_ns()))

    @abstractmethod
    def _read(self, timeout_s: float | None) -> bytes:
        """Backend read: up to what is available, after waiting at most ``timeout_s``."""

    @property
    def exhausted(self) -> bool:
        """True when the source has nothing more to give (the end of a recording)."""
        return False

    @property
    def frame_rate_hz(self) -> int | None:
        """The rate the frames were sent at, Hz, when the source knows it better than
        the configuration does (a recording says what the live run's sensor was set
        to); None: the configured rate."""
        return None

    @property
    def recovered_faults(self) -> tuple[int, str | None]:
        """Faults this source recovered from by itself, and the last one.

        (count since open, description): a transfer retried after an error, a hung
        sensor rebooted. (0, None) for sources that never do either. The daemon
        reports a rising count on ``health`` (docs/architecture.md: a bus error is counted and
        reported, and the daemon keeps running).
        """
        return 0, None

    @property
    def buffers(self) -> bool:
        """True when bytes wait in a buffer while nobody reads (a serial port's), so
        that one ``read(0)`` after a sleep returns everything that came meanwhile: the
        low-power loop may then sleep until each publish time. False, the default, for
        sources that give one reading a read: an I2C source measures when it is read,
        and a replay hands out one recorded read at a time."""
        return False

    def write(self, data: bytes) -> None:  # noqa: B027 - optional for read-only sources
        """Send command bytes to the sensor (sources that cannot send ignore them)."""

    def cancel(self) -> None:  # noqa: B027 - optional
        """Wake a blocked ``read`` from another thread or a signal handler."""

    @abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


BACKENDS: dict[str, tuple[str, str]] = {
    "serial": ("lunad.daemon.sources.serial", "SerialSource"),
    "i2c": ("lunad.daemon.sources.i2c", "I2CSource"),
    "replay": ("lunad.daemon.sources.replay", "ReplaySource"),
}
"""Source kind -> (module, class); the module is imported only when used."""


def open_source(cfg: SourceSection) -> Source:
    """Open the source ``cfg`` describes.

    Raises:
        SourceOpenError: the device cannot be opened now (absent, busy, no permission).
    """
    import importlib

    module_name, class_name = BACKENDS[cfg.kind]
    cls = getattr(importlib.import_module(module_name), class_name)
    source: Source = cls.from_config(cfg)
    return source
