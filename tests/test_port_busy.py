"""A serial port that another process holds, and one that is missing: what
``SerialSource``, ``lunad record`` and ``lunad calibrate`` say and do.

The port is a real pseudo-terminal held with ``serial.Serial(..., exclusive=True)``, as
``lunad serve`` holds a sensor's port; the commands run as real subprocesses.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from lunad.daemon.errors import SourceOpenError
from lunad.daemon.sources.base import Chunk
from lunad.daemon.sources.recording import Recorder, Replay
from lunad.daemon.sources.serial import PortBusyError, SerialSource, port_holder

LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]
EX_UNAVAILABLE = 69


@pytest.fixture
def held_port() -> Iterator[str]:
    """A pty's path, opened exclusively by this process as the daemon opens its port."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)
    holder = serial.Serial(path, exclusive=True)
    try:
        yield path
    finally:
        holder.close()
        os.close(master)


def test_a_held_port_names_its_holder(held_port: str) -> None:
    with pytest.raises(PortBusyError) as caught:
        SerialSource(held_port)
    exc = caught.value
    assert isinstance(exc, SourceOpenError)  # the daemon retries it like an absent port
    assert exc.holder is not None and exc.holder.pid == os.getpid()
    assert str(exc).startswith(
        f"cannot open {held_port}: the port is in use by pid {os.getpid()} ("
    )
    assert str(exc).endswith("); stop that process first")
    assert "\n" not in str(exc)


def test_the_holders_unit_gives_the_command_that_stops_it(tmp_path: Path) -> None:
    """Under systemd the holder's cgroup names its unit: the fix is that unit's stop
    command. /proc is laid out in a directory, as the kernel shows it."""
    device = tmp_path / "ttyAMA0"
    device.touch()
    st = device.stat()
    lock = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    proc = tmp_path / "proc"
    (proc / "812").mkdir(parents=True)
    (proc / "locks").write_text(
        f"1: FLOCK  ADVISORY  WRITE 99 00:1a:4 0 EOF\n"
        f"2: FLOCK  ADVISORY  WRITE 812 {lock} 0 EOF\n"
        f"2: -> FLOCK  ADVISORY  WRITE 900 {lock} 0 EOF\n"
    )
    (proc / "812" / "cgroup").write_text(
        "0::/system.slice/system-lunad.slice/lunad@front.service\n"
    )
    (proc / "812" / "cmdline").write_bytes(
        b"/opt/lunad/venv/bin/python3\0/opt/lunad/venv/bin/lunad\0serve\0--config\0front.toml\0"
    )
    holder = port_holder(str(device), proc)
    assert holder is not None
    assert (holder.pid, holder.unit, holder.user_unit) == (812, "lunad@front.service", False)
    assert holder.command == "python3 /opt/lunad/venv/bin/lunad serve --config front.toml"
    assert str(PortBusyError(str(device), holder)) == (
        f"cannot open {device}: the port is in use by lunad@front.service (pid 812); "
        "stop it first: sudo systemctl stop lunad@front"
    )
    # a lock held from another pid namespace shows pid 0: nobody to name
    (proc / "locks").write_text(f"1: FLOCK  ADVISORY  WRITE 0 {lock} 0 EOF\n")
    assert port_holder(str(device), proc) is None
    assert str(PortBusyError(str(device), None)) == (
        f"cannot open {device}: the port is in use by another process; "
        f"`sudo fuser -v {device}` names it; if it is lunad: sudo systemctl stop lunad@NAME"
    )


def _run(*args: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*LUNAD, *args], capture_output=True, text=True, timeout=timeout)


def test_record_on_a_held_port_stops_at_once_and_leaves_no_file(
    held_port: str, tmp_path: Path
) -> None:
    """It recorded nothing for --duration, said ``recorded 0 chunks``, exited 0 and left a
    header-only file."""
    out = tmp_path / "none.lunarec"
    t0 = time.monotonic()
    r = _run("record", "--device", held_port, "--out", str(out), "--duration", "20")
    assert r.returncode == EX_UNAVAILABLE, r.stderr
    assert time.monotonic() - t0 < 15  # it did not wait out --duration
    assert r.stdout == ""
    assert r.stderr.startswith(
        f"lunad record: cannot open {held_port}: the port is in use by pid {os.getpid()} ("
    )
    assert r.stderr.endswith("); stop that process first\n") and r.stderr.count("\n") == 1
    assert not out.exists()


def test_record_on_a_held_port_keeps_an_existing_recording(held_port: str, tmp_path: Path) -> None:
    out = tmp_path / "earlier.lunarec"
    with Recorder(out, "earlier") as rec:
        rec(Chunk(b"\x59\x59", 1))
    before = out.read_bytes()
    r = _run("record", "--device", held_port, "--out", str(out), "--duration", "20")
    assert r.returncode == EX_UNAVAILABLE, r.stderr
    assert out.read_bytes() == before
    with Replay(out) as rep:
        assert list(rep) == [Chunk(b"\x59\x59", 1)]


def test_calibrate_on_a_held_port_says_so(held_port: str) -> None:
    r = _run(
        "calibrate", "--device", held_port, "--reflectivity", "0.9", "--distance", "2",
        "--seconds", "20",
    )  # fmt: skip
    assert r.returncode == EX_UNAVAILABLE, r.stderr
    assert r.stderr.startswith(
        f"lunad calibrate: cannot open {held_port}: the port is in use by pid {os.getpid()} ("
    )
    assert r.stderr.endswith("); stop that process first\n") and r.stderr.count("\n") == 1


UART_HINT = (
    "(UART not enabled? on a Raspberry Pi: raspi-config, Interface Options, Serial Port:"
    " login shell no, hardware yes (sets enable_uart=1; on a Pi 5 dtparam=uart0=on),"
    " then reboot"
)


@pytest.mark.parametrize(
    ("device", "pi5"),
    [("/dev/serial0", True), ("/dev/ttyAMA63", False), ("/dev/ttyS0", False)],
)
def test_a_missing_pi_uart_gets_the_hint_to_enable_it(device: str, pi5: bool) -> None:
    if os.path.exists(device):
        pytest.skip(f"{device} exists here")
    with pytest.raises(SourceOpenError) as caught:
        SerialSource(device)
    pi5_note = "; on a Pi 5 /dev/serial0 is the debug connector: use /dev/ttyAMA0" if pi5 else ""
    assert str(caught.value) == (
        f"cannot open {device}: No such file or directory {UART_HINT}{pi5_note};"
        " docs/raspberry-pi.md)"
    )


def test_other_missing_ports_get_no_uart_hint(tmp_path: Path) -> None:
    for device in ("/dev/ttyUSB-lunad-absent", str(tmp_path / "serial0")):
        with pytest.raises(SourceOpenError) as caught:
            SerialSource(device)
        assert str(caught.value) == f"cannot open {device}: No such file or directory"


def test_the_hint_is_in_the_retry_log_line(tmp_path: Path) -> None:
    """What a user sees: the warning that the port is missing, retried."""
    device = "/dev/ttyAMA63"
    if os.path.exists(device):
        pytest.skip(f"{device} exists here")
    out = tmp_path / "r.lunarec"
    r = _run("record", "--device", device, "--out", str(out), "--duration", "0.3")
    assert r.returncode == 0, r.stderr
    warning = next(line for line in r.stderr.splitlines() if "cannot open" in line)
    assert warning.endswith(f"{UART_HINT}; docs/raspberry-pi.md); retrying every 2.0 s at most")
