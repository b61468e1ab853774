"""Commands that start processes and make temporary files (``demo``, ``bench``) stop
them and remove the files when a signal ends them, and exit 128 + the signal."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]


@pytest.fixture
def short_tmp() -> Iterator[Path]:
    """A short temporary folder: the commands put ZeroMQ ``ipc://`` sockets in it, and
    a socket path may be at most 107 bytes (pytest's own folders come close)."""
    import shutil
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="lunad-int-"))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def test_sigterm_stops_every_process_demo_started_and_removes_its_files(short_tmp: Path) -> None:
    """Killed with SIGTERM, ``lunad demo`` left its ``lunad serve`` running for ever,
    adopted by init and retrying a virtual sensor that was gone."""
    proc = _start([*LUNAD, "demo", "--duration", "30"], short_tmp, "starting: lunad serve")
    _stop_and_check(proc, signal.SIGTERM, short_tmp)


def test_ctrl_c_on_demo_is_an_interruption_not_lost_frames(short_tmp: Path) -> None:
    """Ctrl-C (SIGINT to the whole process group) ended the demo with its verdict, "sent
    323, published 321", and exit 1, as if frames were lost: the daemon had simply been
    stopped before the sensor."""
    proc = _start([*LUNAD, "demo", "--duration", "30"], short_tmp, "starting: lunad serve", True)
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGINT, err
    assert "stopped by SIGINT" in err and "published" not in out, out + err
    _nothing_left(short_tmp)


def test_sigterm_stops_every_process_bench_started_and_removes_its_files(short_tmp: Path) -> None:
    """SIGTERM (``systemctl stop``, a closed ssh connection) ended ``lunad bench`` at once,
    its ``finally`` blocks unrun: the ``lunad serve`` it was measuring, the receiver and
    the virtual sensor's folder outlived it, the daemon retrying its gone port for ever."""
    proc = _start([*LUNAD, "bench", "--quick"], short_tmp, "serve:")
    _stop_and_check(proc, signal.SIGTERM, short_tmp)


def _start(
    argv: list[str], tmp: Path, ready: str, own_group: bool = False
) -> subprocess.Popen[str]:
    """Start ``argv`` with its temporary files in ``tmp``; return once a line of its
    output contains ``ready`` and its processes have had a second to start."""
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT if not own_group else subprocess.PIPE,
        text=True,
        env={**os.environ, "TMPDIR": str(tmp)},
        start_new_session=own_group,
    )
    assert proc.stdout is not None
    for line in proc.stdout:
        if ready in line:
            break
    time.sleep(1.0)
    assert _processes_under(tmp), f"{argv[3]} started no process in its folder"
    return proc


def _stop_and_check(proc: subprocess.Popen[str], signum: int, tmp: Path) -> None:
    proc.send_signal(signum)
    out = proc.communicate(timeout=30)[0]
    assert proc.returncode == 128 + signum, out
    assert f"stopped by {signal.Signals(signum).name}" in out and "Traceback" not in out, out
    _nothing_left(tmp)


def _nothing_left(tmp: Path) -> None:
    deadline = time.monotonic() + 5.0
    while _processes_under(tmp) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _processes_under(tmp) == []
    assert list(tmp.iterdir()) == []  # its temporary folder is gone


def _processes_under(folder: Path) -> list[str]:
    """Command lines of the running processes that name a path in ``folder``."""
    found = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if str(folder) in cmd:
                found.append(cmd)
    return found


def test_an_interruption_waits_for_the_end_of_a_held_block() -> None:
    """A signal while a child or thread starts (``held``) interrupts at the end of the
    block, inside the caller's ``try``, so the ``finally`` stops what was started; a
    review's scan of SIGTERM delays found demo orphaning its daemon without this."""
    from lunad.daemon.cli import Interrupts

    before = {s: signal.getsignal(s) for s in (signal.SIGUSR1, signal.SIGUSR2)}
    try:
        interrupts = Interrupts(signal.SIGUSR1, signal.SIGUSR2)
        started = stopped = False
        with pytest.raises(KeyboardInterrupt):
            try:
                with interrupts.held():
                    os.kill(os.getpid(), signal.SIGUSR1)  # arrives mid-start
                    started = True
                raise AssertionError("the held interruption was not raised")
            finally:
                stopped = started
        assert started and stopped and interrupts.got == [signal.SIGUSR1]
        assert signal.getsignal(signal.SIGUSR2) == signal.SIG_IGN  # later ones: ignored
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


def test_a_virtual_sensor_whose_start_was_interrupted_closes_cleanly() -> None:
    """``start`` interrupted between making its thread and the thread running: ``close``
    joined a thread never started (RuntimeError, a traceback out of ``lunad demo``)."""
    import threading

    from lunad.sim.pty_device import PtyDevice

    dev = PtyDevice(output_enabled=False)
    dev._thread = threading.Thread(target=lambda: None)  # made, not yet started
    dev.close()
    dev.close()
