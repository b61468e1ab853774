"""A recording played back as a Source, so ``lunad serve --replay FILE`` runs the live path.

How this works: the source keeps one chunk of look-ahead from a ``Replay``. ``read``
waits (at most ``timeout_s``) until the ``Pacer`` says that chunk is due, then returns
it with the ``t_mono_ns`` it was recorded with. ``Source.read`` would stamp the time of
the replay read instead, so this class overrides ``read`` itself: the parser and filter
then see the live run's times, and publish the same readings (time-dependent filter
steps included) whatever the replay speed.

``cancel`` sets a ``Wakeup`` (a self-pipe the wait selects on): it is called from the
daemon's signal handler, where taking a ``threading.Event``'s lock could deadlock with a
wait the handler interrupted.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

from lunad.daemon.errors import ConfigError, LunadError, SourceLostError, SourceOpenError
from lunad.daemon.sources.base import Chunk, Source
from lunad.daemon.sources.recording import Pacer, RecordFormatError, Replay, check_speed
from lunad.daemon.wakeup import Wakeup
from lunad.protocol.commands import FRAME_RATES_HZ

if TYPE_CHECKING:
    from lunad.daemon.config import SourceSection

log = logging.getLogger(__name__)

MAX_GAP_S = 1.0  # recorded silences longer than this replay as this long (seconds)


class ReplaySource(Source):
    """Chunks from a recording, paced at ``speed`` times real time.

    Args:
        path: a recording made by ``lunad record`` (``Recorder``).
        speed: 1.0 real time, 2.0 twice as fast, None as fast as the reader takes them.
        max_gap_s: recorded gaps longer than this (seconds) are shortened to it.

    Raises:
        SourceOpenError: the file cannot be opened, or is not a recording this version
            reads (not a regular file, a bad header: ``RecordFormatError``'s message).
            The daemon checks the file at start and at a SIGHUP (``check_replay``), but
            opens it again when the first subscriber comes, after a reload or a lost
            read: a file replaced in between is a source that cannot be opened now,
            reported on health and retried, as an absent serial port is.
        ValueError: ``speed`` is zero, negative or not finite.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        speed: float | None = 1.0,
        max_gap_s: float | None = MAX_GAP_S,
    ) -> None:
        self.path = Path(path)
        self.ignored_writes = 0
        self._max_gap_s = max_gap_s
        self._pacer: Pacer | None = None
        self._due_s: float | None = None
        self.set_speed(speed)
        try:
            self._replay = Replay(self.path)
        except OSError as exc:
            raise SourceOpenError(f"cannot open recording {self.path}: {exc}") from exc
        except RecordFormatError as exc:
            raise SourceOpenError(str(exc)) from exc
        rate = self._replay.header.frame_rate_hz
        if rate not in FRAME_RATES_HZ:  # a header lunad did not write (it writes --rate)
            log.warning(
                "%s: its header gives %d frames a second, a rate the sensor cannot run at "
                "(500/n Hz); frames are timed by --rate until 1.5 s of them show their own",
                self.path,
                rate,
            )
            rate = 0
        self._frame_rate_hz = rate or None
        self._chunks = iter(self._replay)
        try:
            self._next: Chunk | None = next(self._chunks, None)
        except OSError as exc:
            self._replay.close()
            raise SourceOpenError(f"cannot read recording {self.path}: {exc}") from exc
        self._wakeup = Wakeup()
        self._closed = False

    @classmethod
    def from_config(cls, cfg: SourceSection) -> ReplaySource:
        """Open the recording ``cfg.path`` at ``cfg.speed`` (None: as fast as possible)."""
        if cfg.path is None:
            raise SourceOpenError("[source] path: a replay needs the recording's path")
        return cls(cfg.path, cfg.speed)

    @property
    def frame_rate_hz(self) -> int | None:
        """The rate the recording's header gives (format 2), Hz, else None: a format 1
        file, or a rate the sensor cannot run at (logged when the file is opened)."""
        return self._frame_rate_hz

    @property
    def exhausted(self) -> bool:
        """True once the last chunk has been returned; ``read`` then returns None at once."""
        return self._next is None

    @property
    def torn_records(self) -> int:
        """1 when the recording ended in a torn or corrupt record (skipped), else 0."""
        return self._replay.torn_records

    def read(self, timeout_s: float | None) -> Chunk | None:
        """The next recorded chunk once it is due, with its recorded ``t_mono_ns``.

        Returns None when it is not due within ``timeout_s`` seconds, when ``cancel``
        woke the wait, after ``close``, and at once when the recording is exhausted.

        Raises:
            SourceLostError: the file could not be read (an I/O error of the card).
        """
        chunk = self._next
        if chunk is None or self._closed:
            return None
        if self._pacer is not None:
            if self._due_s is None:  # the clock starts at the first read, not at open
                self._due_s = self._pacer.due(chunk.t_mono_ns)
            wait_s = self._due_s - time.monotonic()
            if wait_s > 0:
                if timeout_s is not None and timeout_s < wait_s:
                    self._wait(timeout_s)
                    return None
                if self._wait(wait_s):
                    return None
        elif self._wait(0.0):
            return None
        try:
            self._next = next(self._chunks, None)
        except OSError as exc:
            raise SourceLostError(f"cannot read recording {self.path}: {exc}") from exc
        self._due_s = None
        return chunk

    def set_speed(self, speed: float | None) -> None:
        """Play the rest of the recording at ``speed`` (None: as fast as possible), from
        where it is: a SIGHUP that changes only ``--speed`` does not start it again.

        Raises:
            ValueError: ``speed`` is zero, negative or not finite.
        """
        self.speed = check_speed(speed)
        if speed is not None and self._pacer is not None:
            self._pacer.set_speed(speed)
            if self._due_s is not None:  # the next chunk's due time, at the new speed
                self._due_s = self._pacer.last_due_s
            return
        self._pacer = None if speed is None else Pacer(speed, self._max_gap_s)
        self._due_s = None  # a new pacer's clock starts at the next read

    def _wait(self, timeout_s: float) -> bool:
        """Sleep up to ``timeout_s`` seconds; True (and the wake-up consumed) if cancelled."""
        return self._wakeup.wait(timeout_s)

    def _read(self, timeout_s: float | None) -> bytes:
        chunk = self.read(timeout_s)
        return b"" if chunk is None else chunk.data

    def write(self, data: bytes) -> None:
        """Drop command bytes: a recording cannot answer them (counted, logged once)."""
        self.ignored_writes += 1
        if self.ignored_writes == 1:
            log.info("%s: ignoring command bytes, a recording cannot answer", self)

    def cancel(self) -> None:
        """Wake a pacing wait in ``read``; safe from a signal handler or another thread."""
        self._wakeup.set()

    def close(self) -> None:
        """Close the recording; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._replay.close()
        self._wakeup.close()

    def __str__(self) -> str:
        pace = "max speed" if self.speed is None else f"{self.speed:g}x"
        return f"replay {self.path} at {pace}"


def check_replay(cfg: SourceSection) -> None:
    """Open and close the recording ``cfg`` names, so that a path that is missing or not
    a recording stops ``lunad serve`` before it starts, and a SIGHUP to one is refused.

    Raises:
        ConfigError: naming ``--replay`` and what is wrong with the file.
    """
    try:
        ReplaySource.from_config(cfg).close()
    except (LunadError, ValueError) as exc:
        raise ConfigError(f"--replay: {exc}") from exc
