"""Signals for the sub-commands: ``Interrupts`` for those that start children or make
temporary files, ``StartupSignals`` for the long-running ones while they start."""

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


STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)  # what stops a command, as Ctrl-C does


class StartupSignals:
    """Signals noted while a long-running command starts, for the command to act on.

    Python gives SIGHUP and SIGTERM their default action, which ends the process, and
    SIGINT raises ``KeyboardInterrupt`` wherever it lands, until the command installs
    its own handlers, after the imports of pydantic and pyzmq and the config: about
    0.2 s here and 2 s on a Pi Zero. A SIGHUP in that window would kill the daemon, and
    systemd, which counts death by SIGHUP as a clean exit, would not restart it; a stop
    would end ``lunad record`` by the signal, where its help promises exit 0. ``main``
    installs this before any sub-command is imported (``STARTUP``); the signals only
    mark what was asked, and the command acts on it once its own handlers are in place:
    a stop stops it, and for ``lunad serve`` (``lunad.daemon.cli.serve.run``) a reload
    re-reads the config if it came while the config was being read. What no Python
    code can cover is the interpreter's own start, before ``main`` runs (30-50 ms here).

    Args:
        stops: the signals that stop the command.
        reload: the signal that reloads it (serve's SIGHUP), or None.

    Attributes:
        stop: the first of ``stops`` that came, or None.
        reloads: how many ``reload`` signals came.
    """

    SIGNALS = (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)

    def __init__(
        self,
        stops: tuple[int, ...] = STOP_SIGNALS,
        reload: int | None = signal.SIGHUP,
    ) -> None:
        self.stop: int | None = None
        self.reloads = 0
        self._reload = reload
        for signum in stops + (() if reload is None else (reload,)):
            signal.signal(signum, self._note)

    def _note(self, signum: int, _frame: FrameType | None) -> None:
        if signum == self._reload:
            self.reloads += 1
        elif self.stop is None:
            self.stop = signum

    def stopped(self, prog: str) -> bool:
        """True, and ``prog`` says so on stderr, when a stop came while it started."""
        if self.stop is None:
            return False
        print(
            f"{prog}: received {signal.Signals(self.stop).name} while starting, stopping",
            file=sys.stderr,
        )
        return True


STARTUP: dict[str, tuple[tuple[int, ...], int | None]] = {
    "serve": (STOP_SIGNALS, signal.SIGHUP),
    "record": (STOP_SIGNALS, None),
    "sim": ((*STOP_SIGNALS, signal.SIGHUP), None),  # a hangup stops it
    "watch": (STOP_SIGNALS, None),
}
"""The commands ``main`` notes signals for while they start: the signals that stop
each, and the one that reloads it (``StartupSignals``' arguments). Each of them, once
its own handlers are in place, acts on what came (``args.startup_signals``), and
ignores these signals while Python shuts down (``ignore_while_exiting``)."""


def startup_signals(command: str | None) -> StartupSignals | None:
    """``StartupSignals`` for ``command`` as ``STARTUP`` says, None for any other."""
    how = STARTUP.get(command or "")
    return None if how is None else StartupSignals(*how)


def ignore_while_exiting() -> None:
    """Ignore SIGHUP, SIGTERM and SIGINT for the rest of the process: the ``STARTUP``
    commands, once they have stopped. While Python shuts down it gives every signal with
    a Python handler its default action back, and SIGTERM's ends the process by the
    signal: a stop sent as the daemon ended by itself (a replay's end) made it exit -15
    instead of its own code, and a second Ctrl-C to the sim while it removed its link
    ended it by the signal. An ignored signal stays ignored, and nothing is left to
    stop."""
    for signum in StartupSignals.SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
