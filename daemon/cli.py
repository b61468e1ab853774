"""The ``lunad`` command: one entry point, thin sub-commands on a shared core.

Each sub-command module offers ``add_parser(subparsers)`` and ``run(args) -> int`` and
imports its heavy dependencies inside ``run``, so ``lunad --help`` and the daemon's
start stay quick. Nothing is printed while parsing; diagnostics go to logging
(stderr), a command's output to stdout.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import signal
import sys
from collections.abc import Iterator, Sequence
from types import FrameType

SUBCOMMANDS = (
    "lunad.daemon.cmd_serve",
    "lunad.daemon.cmd_sim",
    "lunad.daemon.cmd_watch",
    "lunad.daemon.cmd_demo",
    "lunad.daemon.cmd_record",
    "lunad.daemon.cmd_calibrate",
    "lunad.daemon.cmd_sweep",
    "lunad.daemon.cmd_eval",
    "lunad.daemon.cmd_bench",
    "lunad.daemon.cmd_soak",
    "lunad.daemon.cmd_keys",
)

EPILOG = """\
examples:
  lunad sim                                  # virtual TF-Luna on a pty
  lunad serve --device /dev/serial0          # the daemon, publishing on tcp://127.0.0.1:7781
  lunad watch --connect tcp://127.0.0.1:7781 # live view of the stream
  lunad demo                                 # all three together for a few seconds

Every sub-command has --help with examples.
"""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a settable exit code for usage errors (``serve`` uses 78)."""

    usage_exit_code = 2

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(self.usage_exit_code, f"{self.prog}: error: {message}\n")


def build_parser() -> ArgumentParser:
    """The full ``lunad`` parser with every sub-command that is installed."""
    parser = ArgumentParser(
        prog="lunad",
        description="Edge daemon for the Benewake TF-Luna LiDAR.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from lunad import daemon

    parser.add_argument("--version", action="version", version=f"lunad {daemon.__version__}")
    sub = parser.add_subparsers(
        title="commands", metavar="COMMAND", parser_class=ArgumentParser, required=True
    )
    for name in SUBCOMMANDS:
        before = set(sub.choices)
        importlib.import_module(name).add_parser(sub)
        for added in set(sub.choices) - before:
            sub.choices[added].set_defaults(_parser=sub.choices[added])
    return parser


def setup_logging(level: str = "info") -> None:
    """One line per event on stderr; timestamps only on a terminal (journald adds its own)."""
    fmt = "%(levelname)s %(name)s: %(message)s"
    if sys.stderr.isatty():
        fmt = "%(asctime)s " + fmt
    logging.basicConfig(level=level.upper(), format=fmt, stream=sys.stderr, force=True)


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
    own handlers are in place (``cmd_serve.run``): a stop stops it, a reload re-reads
    the config if it came while the config was being read. What no Python code can
    cover is the interpreter's own start, before ``main`` runs (about 25 ms here).

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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``lunad`` console script."""
    words = sys.argv[1:] if argv is None else list(argv)
    # The sub-command's name is the first word (lunad's own options all exit at once).
    startup = StartupSignals() if words[:1] == ["serve"] else None
    parser = build_parser()
    args, extra = parser.parse_known_args(words)
    if extra:
        args._parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if startup is not None:
        args.startup_signals = startup
    setup_logging(getattr(args, "log_level", None) or "info")
    try:
        code: int = args.func(args)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    return code


if __name__ == "__main__":
    sys.exit(main())
