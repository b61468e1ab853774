"""Every sub-command's --help runs in a subprocess and shows examples; flags that apply
across a command's output modes do so in each."""

from __future__ import annotations

import argparse
import json
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import pytest

from lunad.daemon.cli import SUBCOMMANDS, build_parser
from lunad.protocol.client import Subscriber
from lunad.sim.pty_device import PtyDevice

LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]


def _command_names() -> list[str]:
    (commands,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sorted(commands.choices)


COMMANDS = _command_names()


def test_every_command_module_is_installed() -> None:
    assert len(COMMANDS) == len(SUBCOMMANDS)


@pytest.mark.parametrize("cmd", [[], *[[c] for c in COMMANDS]])
def test_help(cmd: list[str]) -> None:
    r = subprocess.run([*LUNAD, *cmd, "--help"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert "example" in r.stdout


@pytest.mark.parametrize("mode", [[], ["--json"]], ids=["lines", "json"])
def test_watch_every_thins_each_output_mode(
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    subscriber: Subscriber,
    helpers: Any,
    mode: list[str],
) -> None:
    """``--every 10 --json`` used to print every reading; the lines thinned."""
    dev = device(rate_hz=250, output_enabled=False)
    start_daemon("--device", dev.path, "--publish", endpoint, "--rate", "250")
    helpers.wait_for(subscriber, helpers.is_range, timeout=helpers.startup_s)
    r = subprocess.run(
        [*LUNAD, "watch", "--connect", endpoint, "--every", "10", "--count", "50", *mode],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert r.stderr.startswith("50 readings, ")
    if mode:
        readings = [m for m in map(json.loads, r.stdout.splitlines()) if "seq" in m]
    else:
        readings = [line for line in r.stdout.splitlines() if line.startswith("#")]
    assert len(readings) == 5


def test_watch_stopped_by_sigterm_reports_what_came(
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    subscriber: Subscriber,
    helpers: Any,
) -> None:
    """``timeout 10 lunad watch`` (SIGTERM) ended with 143 and no summary, where Ctrl-C
    gives "N readings, M lost"."""
    dev = device(rate_hz=250, output_enabled=False)
    start_daemon("--device", dev.path, "--publish", endpoint, "--rate", "250")
    helpers.wait_for(subscriber, helpers.is_range, timeout=helpers.startup_s)
    proc = subprocess.Popen(
        [*LUNAD, "watch", "--connect", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        readings = 0
        deadline = time.monotonic() + helpers.startup_s
        with selectors.DefaultSelector() as sel:  # a stalled watcher fails, not hangs
            sel.register(proc.stdout, selectors.EVENT_READ)
            while readings < 20:  # health lines come between the readings
                assert sel.select(timeout=deadline - time.monotonic()), "no readings"
                readings += proc.stdout.readline().startswith("#")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    summary = err.strip().splitlines()[-1]
    readings = int(summary.split()[0])
    assert readings >= 20 and summary == f"{readings} readings, 0 lost (seq gaps)"
