"""The ``lunad`` command: one entry point, thin sub-commands on a shared core.

Each sub-command module offers ``add_parser(subparsers)`` and ``run(args) -> int`` and
imports its heavy dependencies inside ``run``, so ``lunad --help`` and the daemon's
start stay quick. Nothing is printed while parsing; diagnostics go to logging
(stderr), a command's output to stdout.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from lunad.daemon.cli.signals import ignore_while_exiting, startup_signals

SUBCOMMANDS = (
    "lunad.daemon.cli.serve",
    "lunad.daemon.cli.sim",
    "lunad.daemon.cli.watch",
    "lunad.daemon.cli.demo",
    "lunad.daemon.cli.record",
    "lunad.daemon.cli.calibrate",
    "lunad.daemon.cli.sweep",
    "lunad.daemon.cli.evaluate",
    "lunad.daemon.cli.bench",
    "lunad.daemon.cli.soak",
    "lunad.daemon.cli.keys",
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``lunad`` console script."""
    words = sys.argv[1:] if argv is None else list(argv)
    # The sub-command's name is the first word (lunad's own options all exit at once).
    command = words[0] if words else None
    startup = startup_signals(command)
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
    finally:
        if startup is not None:
            # Their stop handlers get the default action back while Python shuts down:
            # a stop then would end the process by the signal instead of their code.
            ignore_while_exiting()
    return code
