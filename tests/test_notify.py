"""sd_notify over a real AF_UNIX datagram socket, path and abstract, as systemd binds it."""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from lunad.daemon.notify import Notifier

RECV_TIMEOUT_S = 2.0


def _bound(address: str | bytes) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(address)
    sock.settimeout(RECV_TIMEOUT_S)
    return sock


@pytest.fixture
def path_socket(tmp_path: Path) -> Iterator[tuple[str, socket.socket]]:
    address = str(tmp_path / "notify.sock")
    with _bound(address) as sock:
        yield address, sock


@pytest.fixture
def abstract_socket() -> Iterator[tuple[str, socket.socket]]:
    name = f"lunad-test-{os.getpid()}-{id(object())}"
    with _bound(b"\0" + name.encode()) as sock:
        yield "@" + name, sock


def _no_datagram(sock: socket.socket) -> bool:
    sock.setblocking(False)
    try:
        sock.recv(4096)
    except BlockingIOError:
        return True
    return False


def test_path_socket_gets_exact_datagrams(path_socket: tuple[str, socket.socket]) -> None:
    address, sock = path_socket
    with Notifier.from_env({"NOTIFY_SOCKET": address}) as n:
        assert n.enabled
        assert n.ready()
        assert sock.recv(4096) == b"READY=1"
        assert n.status("100.0 fps\nconnected  dropout 0.01")
        assert sock.recv(4096) == b"STATUS=100.0 fps connected dropout 0.01"
        assert n.watchdog()
        assert sock.recv(4096) == b"WATCHDOG=1"
        assert n.stopping()
        assert sock.recv(4096) == b"STOPPING=1"
        assert n.send("A=1", "B=2")
        assert sock.recv(4096) == b"A=1\nB=2"
        assert n.errors == 0


def test_abstract_socket(abstract_socket: tuple[str, socket.socket]) -> None:
    address, sock = abstract_socket
    with Notifier.from_env({"NOTIFY_SOCKET": address}) as n:
        assert n.ready()
        assert sock.recv(4096) == b"READY=1"


def test_reloading_carries_monotonic_usec(path_socket: tuple[str, socket.socket]) -> None:
    address, sock = path_socket
    with Notifier(address) as n:
        before_us = time.monotonic_ns() // 1000
        assert n.reloading()
        first, second = sock.recv(4096).split(b"\n")
    assert first == b"RELOADING=1"
    key, _, value = second.partition(b"=")
    assert key == b"MONOTONIC_USEC"
    assert int(value) >= before_us


def test_no_variable_means_disabled_and_silent(caplog: pytest.LogCaptureFixture) -> None:
    """A run by hand (no NOTIFY_SOCKET) is the usual case, not news: one debug line,
    nothing at info or above."""
    caplog.set_level(logging.DEBUG, logger="lunad.daemon.notify")
    n = Notifier.from_env({})
    assert not n.enabled
    assert n.watchdog_interval_s is None
    assert not n.ready()
    assert not n.watchdog()
    assert n.errors == 0
    assert [r.levelno for r in caplog.records] == [logging.DEBUG]
    assert "NOTIFY_SOCKET is not set" in caplog.records[0].getMessage()
    n.close()


def test_a_set_but_unusable_variable_is_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    """Under systemd with a NOTIFY_SOCKET we cannot use, systemd waits for READY=1 in
    vain: that deserves a warning."""
    caplog.set_level(logging.DEBUG, logger="lunad.daemon.notify")
    with Notifier.from_env({"NOTIFY_SOCKET": "vsock:2:1234"}) as n:
        assert not n.enabled
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert "vsock:2:1234" in caplog.records[0].getMessage()


def test_watchdog_interval_is_half_of_watchdog_usec(path_socket: tuple[str, socket.socket]) -> None:
    address, _ = path_socket
    env = {"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000"}
    with Notifier.from_env(env) as n:
        assert n.watchdog_interval_s == 1.0
    with Notifier.from_env({**env, "WATCHDOG_PID": str(os.getpid())}) as n:
        assert n.watchdog_interval_s == 1.0


def test_watchdog_pid_of_another_process_means_no_watchdog(
    path_socket: tuple[str, socket.socket],
) -> None:
    address, _ = path_socket
    env = {"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}
    with Notifier.from_env(env) as n:
        assert n.enabled
        assert n.watchdog_interval_s is None


@pytest.mark.parametrize("usec", ["0", "abc", ""])
def test_unusable_watchdog_usec_means_no_watchdog(
    path_socket: tuple[str, socket.socket], usec: str
) -> None:
    address, _ = path_socket
    with Notifier.from_env({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": usec}) as n:
        assert n.watchdog_interval_s is None


def test_watchdog_without_notify_socket_is_off() -> None:
    with Notifier.from_env({"WATCHDOG_USEC": "2000000"}) as n:
        assert n.watchdog_interval_s is None


def test_unsupported_address_is_ignored() -> None:
    with Notifier.from_env({"NOTIFY_SOCKET": "vsock:2:1234"}) as n:
        assert not n.enabled
        assert not n.ready()


def test_vanished_socket_is_counted_not_raised(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    address = str(tmp_path / "gone.sock")
    _bound(address).close()
    os.unlink(address)
    with Notifier.from_env({"NOTIFY_SOCKET": address}) as n:
        assert not n.ready()
        assert not n.watchdog()
        assert n.errors == 2
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert address in warnings[0].getMessage()


def test_socket_that_comes_back_works_again(tmp_path: Path) -> None:
    address = str(tmp_path / "back.sock")
    with Notifier(address) as n:
        assert not n.ready()
        with _bound(address) as sock:
            assert n.ready()
            assert sock.recv(4096) == b"READY=1"
        assert n.errors == 1


def test_close_is_idempotent_and_silences(path_socket: tuple[str, socket.socket]) -> None:
    address, sock = path_socket
    n = Notifier(address, watchdog_interval_s=1.0)
    n.close()
    n.close()
    assert not n.enabled
    assert not n.ready()
    assert _no_datagram(sock)
