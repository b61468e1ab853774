"""Every sub-command's --help runs in a subprocess and shows examples."""

from __future__ import annotations

import subprocess
import sys

import pytest

from lunad.daemon.cli import SUBCOMMANDS, build_parser

LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]
COMMANDS = sorted(build_parser()._subparsers._group_actions[0].choices)  # type: ignore[union-attr]


def test_every_command_module_is_installed() -> None:
    assert len(COMMANDS) == len(SUBCOMMANDS)


@pytest.mark.parametrize("cmd", [[], *[[c] for c in COMMANDS]])
def test_help(cmd: list[str]) -> None:
    r = subprocess.run([*LUNAD, *cmd, "--help"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert "example" in r.stdout
