"""SerialSource on real pseudo-terminals: reads, what a read after a sleep returns, and
hang-ups."""

from __future__ import annotations

import os
import termios
import time
from collections.abc import Iterator

import pytest

from lunad.daemon.errors import SourceLostError
from lunad.daemon.sources.serial import SerialSource
from lunad.protocol.frame import encode_frame

FRAME = encode_frame(123, 1500, 2368)


@pytest.fixture
def line() -> Iterator[tuple[int, SerialSource]]:
    """A pty pair: the master end (the 'sensor') and a SerialSource open on the slave."""
    master, slave = os.openpty()
    name = os.ttyname(slave)
    os.close(slave)  # the source opens its own; the master keeps the pty alive
    src = SerialSource(name)
    try:
        yield master, src
    finally:
        src.close()
        try:
            os.close(master)
        except OSError:
            pass


def test_reads_return_each_frame_as_it_comes(line: tuple[int, SerialSource]) -> None:
    master, src = line
    assert termios.tcgetattr(master)[6][termios.VMIN] == 0  # pyserial's: no batching
    os.write(master, FRAME)
    chunk = src.read(1.0)
    assert chunk is not None and chunk.data == FRAME


def test_a_read_after_a_sleep_takes_everything_that_came(line: tuple[int, SerialSource]) -> None:
    """What the low-power loop relies on (``buffers``): it sleeps until a publish time,
    off the port, and one read then returns every frame that arrived meanwhile."""
    master, src = line
    assert src.buffers
    for _ in range(5):
        os.write(master, FRAME)
    time.sleep(0.05)
    chunk = src.read(0.0)
    assert chunk is not None and chunk.data == FRAME * 5
    assert src.read(0.0) is None


def test_hang_up_is_source_lost(line: tuple[int, SerialSource]) -> None:
    master, src = line
    os.write(master, FRAME)
    os.close(master)
    with pytest.raises(SourceLostError):
        for _ in range(3):  # the queued frame may come first
            src.read(2.0)


def test_a_socket_port_whose_server_went_away_is_source_lost() -> None:
    """``socket://`` (ser2net, a Wi-Fi bridge): the server closing is a lost source the
    daemon reconnects to, not an exception out of ``read`` that ends it."""
    import socket

    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        src = SerialSource(f"socket://127.0.0.1:{port}")
        try:
            conn, _ = server.accept()
            conn.sendall(FRAME)
            got = b""
            deadline = time.monotonic() + 5.0
            while len(got) < len(FRAME) and time.monotonic() < deadline:
                chunk = src.read(0.5)
                got += chunk[0] if chunk else b""
            assert got == FRAME
            conn.close()
            with pytest.raises(SourceLostError, match=f"socket://127.0.0.1:{port}"):
                for _ in range(10):
                    src.read(0.5)
        finally:
            src.close()
