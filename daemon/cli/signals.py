"""Signals for the sub-commands: ``Interrupts`` for those that start children or make
temporary files, ``StartupSignals`` for ``lunad serve`` while it starts."""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator
from types import FrameType


class Interrupts:
    """Signals that interrupt the main thread as Ctrl-C does (``KeyboardInterrupt``).

    For commands that start children or make temporary files (``demo``, ``bench``):
    SIGTERM's default action ends the process at once, and the ``finally`` blocks that
    stop the children and remove the files never run. The first signal interrupts; the
    rest are ignored while those blocks clean up. Inside ``held()`` (starting a child
    or a thread, before the ``try`` that stops it exists) the interruption waits until
    the block ends, so nothing is started that nobody stops.

    Attributes:
        got: the signal's number once one came; a command exits 128 + it, as a shell does.
    """

    def __init__(self, *signums: int) -> None:
        import signal

        self.got: list[int] = []
        self._signums = signums
        self._held = 0
        self._pending = False
        for signum in signums:
            signal.signal(signum, self._interrupt)

    def _interrupt(self, signum: int, _frame: object) -> None:
        import signal

        self.got.append(signum)
        for each in self._signums:
            signal.signal(each, signal.SIG_IGN)
        if self._held:
            self._pending = True
        else:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Hold an interruption until the block ends, then raise it."""
        self._held += 1
        try:
            yield
        finally:
            self._held -= 1
        if self._pending and not self._held:
            self._pending = False
            raise KeyboardInterrupt

    def exit_code(self, prog: str) -> int:
        """Say ``prog`` was stopped early; 128 + the signal's number, as a shell gives."""
        import signal

        signum = self.got[0] if self.got else signal.SIGINT
        print(f"{prog}: stopped by {signal.Signals(signum).name}", file=sys.stderr)
        return 128 + signum


class StartupSignals:
    """SIGHUP, SIGTERM and SIGINT noted while ``lunad serve`` starts, for the daemon.

    Python gives SIGHUP and SIGTERM their default action, which ends the process, until
    the daemon installs its own handlers, after the imports of pydantic and pyzmq and
    the config: about 0.2 s here and 2 s on a Pi Zero. A SIGHUP in that window would
    kill the daemon, and systemd, which counts death by SIGHUP as a clean exit, would
    not restart it. ``main`` installs this before any sub-command is imported; the
    signals only mark what was asked, and ``lunad serve`` acts on it once the daemon's
    own handlers are in place (``lunad.daemon.cli.serve.run``): a stop stops it, a reload re-reads
    the config if it came while the config was being read. What no Python code can
    cover is the interpreter's own start, before ``main`` runs (30-50 ms here).

    Attributes:
        stop: the first SIGTERM or SIGINT, or None.
        reloads: how many SIGHUPs came.
    """

    SIGNALS = (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)

    def __init__(self) -> None:
        self.stop: int | None = None
        self.reloads = 0
        for signum in self.SIGNALS:
            signal.signal(signum, self._note)

    def _note(self, signum: int, _frame: FrameType | None) -> None:
        if signum == signal.SIGHUP:
            self.reloads += 1
        elif self.stop is None:
            self.stop = signum


def ignore_while_exiting() -> None:
    """Ignore SIGHUP, SIGTERM and SIGINT for the rest of the process: ``lunad serve``
    and ``lunad record``, once they have stopped. While Python shuts down it gives every
    signal with a Python handler its default action back, and SIGTERM's ends the process
    by the signal: a stop sent as the daemon ended by itself (a replay's end) made it
    exit -15 instead of its own code. An ignored signal stays ignored, and nothing is
    left to stop."""
    for signum in StartupSignals.SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
