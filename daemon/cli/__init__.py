"""The command line: ``lunad`` and its sub-commands, one module each (``serve``,
``record``, ``bench``...), on a shared core (``main``), with the flags that choose a
source (``source_args``), the argument types they share (``arg_types``) and the signal
handling of commands (``signals``). Each sub-command imports its heavy dependencies
inside ``run``, so ``lunad --help`` stays quick.
"""

from lunad.daemon.cli.arg_types import int_at_least, positive_float, sensor_name
from lunad.daemon.cli.main import SUBCOMMANDS, ArgumentParser, build_parser, main, setup_logging
from lunad.daemon.cli.signals import Interrupts, StartupSignals
from lunad.daemon.cli.source_args import add_source_args, source_overrides

__all__ = [
    "SUBCOMMANDS",
    "ArgumentParser",
    "Interrupts",
    "StartupSignals",
    "add_source_args",
    "build_parser",
    "int_at_least",
    "main",
    "positive_float",
    "sensor_name",
    "setup_logging",
    "source_overrides",
]
