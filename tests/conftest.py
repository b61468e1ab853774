"""Shared fixtures: a virtual sensor on a real pty, the daemon as a real subprocess,
a real ZeroMQ subscriber, and a guard that fails any test leaving a pty or thread open."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from hypothesis import settings

from lunad.protocol import client as client_module
from lunad.protocol import messages as messages_module
from lunad.protocol.client import Subscriber
from lunad.protocol.messages import HealthMessage, Message, RangeMessage
from lunad.sim.pty_device import DeviceError, PtyDevice

settings.register_profile("lunad", deadline=None)
settings.load_profile("lunad")
"""No per-example deadline for hypothesis (200 ms by default): it is a timed assertion,
and a loaded CI machine (a 10 min run) failed ``test_truth_stays_within_its_keyframes``
on it. Speed is the benchmarks' business."""

_SCHEMAS = {
    kind: jsonschema.Draft202012Validator(
        json.loads(
            resources.files("lunad.protocol").joinpath("schema", f"{kind}.v2.json").read_text()
        )
    )
    for kind in ("range", "health")
}


@pytest.fixture(autouse=True)
def every_message_validates_against_the_shipped_schema(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every message a test receives through ``Subscriber`` validates against the JSON
    Schema shipped in the package (protocol/schema/), as a consumer in another language
    would check it, besides the pydantic model (docs/messages.md)."""
    decode = messages_module.decode

    def checked(topic_frame: bytes, payload: bytes) -> Message:
        msg = decode(topic_frame, payload)  # raises first on what the model refuses
        _SCHEMAS[msg.kind].validate(json.loads(payload))
        if not topic_frame.endswith(b"/"):
            raise ValueError(f"topic {topic_frame!r} does not end in '/'")
        return msg

    monkeypatch.setattr(client_module, "decode", checked)


LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]
STARTUP_S = 30.0
"""How long a test waits for a new daemon's first reading. About 1 s here, but a loaded
CI machine has taken over 10 s (two tests failed so in one `make test`); waiting longer
only slows a failure down."""


def _open_ptys() -> set[str]:
    found = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("/dev/pts/") or target == "/dev/ptmx":
            found.add(f"{fd}->{target}")
    return found


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """Fail a test that leaves a pty fd or a non-daemon thread (or a device thread) behind."""
    ptys = _open_ptys()
    threads = set(threading.enumerate())
    yield
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        extra_threads = [
            t
            for t in threading.enumerate()
            if t not in threads and t.is_alive() and (not t.daemon or t.name == "pty-device")
        ]
        extra_ptys = _open_ptys() - ptys
        if not extra_threads and not extra_ptys:
            return
        time.sleep(0.05)
    pytest.fail(f"test leaked threads {extra_threads} or ptys {extra_ptys}")


class DaemonProc:
    """``lunad serve`` as a real subprocess, with its stderr kept for assertions."""

    def __init__(
        self,
        args: list[str],
        tmp: Path,
        env: dict[str, str] | None = None,
        preexec_fn: Callable[[], None] | None = None,
    ) -> None:
        self.log_path = tmp / f"daemon-{time.monotonic_ns()}.log"
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [*LUNAD, "serve", *args],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
            preexec_fn=preexec_fn,
        )

    @property
    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 5.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
            self._log.close()
        return code


@pytest.fixture
def endpoint(tmp_path: Path) -> str:
    return f"ipc://{tmp_path}/lunad.sock"


@pytest.fixture
def start_daemon(tmp_path: Path) -> Iterator[Callable[..., DaemonProc]]:
    procs: list[DaemonProc] = []

    def start(
        *args: str,
        env: dict[str, str] | None = None,
        preexec_fn: Callable[[], None] | None = None,
    ) -> DaemonProc:
        d = DaemonProc(list(args), tmp_path, env, preexec_fn)
        procs.append(d)
        return d

    yield start
    for d in procs:
        d.stop(signal.SIGKILL)


@pytest.fixture
def device(tmp_path: Path) -> Iterator[Callable[..., PtyDevice]]:
    """Factory for a started virtual sensor behind ``tmp_path/tfluna``; closed after the test."""
    made: list[PtyDevice] = []

    def make(**kw: Any) -> PtyDevice:
        kw.setdefault("link", tmp_path / "tfluna")
        dev = PtyDevice(**kw).start()
        made.append(dev)
        return dev

    yield make
    errors = []
    for dev in made:
        try:
            dev.close()
        except DeviceError as exc:  # a device thread died: fail the test, after closing all
            errors.append(exc)
    if errors:
        raise errors[0]


@pytest.fixture
def subscriber(endpoint: str) -> Iterator[Subscriber]:
    with Subscriber(endpoint) as sub:
        yield sub


def wait_for(sub: Subscriber, pred: Callable[[Message], bool], timeout: float = 5.0) -> Message:
    """The first message matching ``pred`` within ``timeout`` seconds, else fail."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = sub.recv(timeout_s=left)
        if msg is not None and pred(msg):
            return msg
    pytest.fail(f"no matching message within {timeout} s")


def is_range(msg: Message) -> bool:
    return isinstance(msg, RangeMessage)


def ranges_through(sub: Subscriber, last_seq: int, timeout_s: float = 15.0) -> list[RangeMessage]:
    """Every range message up to and including seq ``last_seq``; fail after ``timeout_s``.

    Tests wait for a condition, never count what arrives in a fixed window: a shared
    machine can stall the daemon or the device thread for a second or more.
    """
    out: list[RangeMessage] = []
    deadline = time.monotonic() + timeout_s
    while not out or out[-1].seq < last_seq:
        m = sub.recv(timeout_s=max(0.0, deadline - time.monotonic()))
        if m is None:
            at = out[-1].seq if out else None
            pytest.fail(f"seq {last_seq} not reached within {timeout_s} s (last seen {at})")
        if isinstance(m, RangeMessage):
            out.append(m)
    return out


def health_state(state: str) -> Callable[[Message], bool]:
    return lambda m: isinstance(m, HealthMessage) and m.state == state


def recording_refused(device: str, endpoint: str, path: Path) -> list[str]:
    """Run ``lunad record --out path`` and ``lunad serve --record path`` on ``device``,
    assert each exits 78 with one ``lunad ...`` line, no traceback and ``path`` left
    byte for byte, and return the two lines."""
    before = path.read_bytes()
    commands = (
        ["record", "--device", device, "--out", str(path), "--duration", "5"],
        ["serve", "--device", device, "--publish", endpoint, "--record", str(path)],
    )
    said = []
    for args in commands:
        r = subprocess.run([*LUNAD, *args], capture_output=True, text=True, timeout=30)
        assert r.returncode == 78, r.stderr
        errors = [line for line in r.stderr.splitlines() if line.startswith("lunad ")]
        assert len(errors) == 1 and "Traceback" not in r.stderr, r.stderr
        assert path.read_bytes() == before
        said.append(errors[0])
    return said


def wait_caught(proc: subprocess.Popen[Any], signum: int, timeout_s: float = 30.0) -> None:
    """Wait until ``proc`` catches ``signum`` (its SigCgt mask in /proc): lunad's first
    handlers are installed as ``main`` starts. Before that the interpreter is still
    starting, which no Python code can cover: about 30-50 ms here, and several times
    that on a loaded machine, so a signal sent a fixed time after the spawn tested the
    machine's load instead of lunad."""
    deadline = time.monotonic() + timeout_s
    status = Path(f"/proc/{proc.pid}/status")
    while time.monotonic() < deadline and proc.poll() is None:
        for line in status.read_text().splitlines():
            if line.startswith("SigCgt:") and int(line.split()[1], 16) >> (signum - 1) & 1:
                return
        time.sleep(0.001)
    pytest.fail(f"{proc.args!r} caught no {signal.Signals(signum).name} within {timeout_s} s")


@pytest.fixture
def helpers() -> Any:
    """Small helpers for tests (conftest modules are not importable by name)."""

    class H:
        recording_refused = staticmethod(recording_refused)
        wait_caught = staticmethod(wait_caught)
        wait_for = staticmethod(wait_for)
        is_range = staticmethod(is_range)
        health_state = staticmethod(health_state)
        ranges_through = staticmethod(ranges_through)
        lunad = LUNAD
        startup_s = STARTUP_S

    return H
