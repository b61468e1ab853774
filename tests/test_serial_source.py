"""SerialSource on real pseudo-terminals: reads, what a read after a sleep returns, and
hang-ups."""

from __future__ import annotations

import os
import socket
import termios
import time
from collections.abc import Iterator
from contextlib import contextmanager

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


@contextmanager
def socket_port() -> Iterator[tuple[SerialSource, socket.socket, int]]:
    """A ``socket://`` source on a loopback server: the source, the server's side of
    the connection and its port; the source is closed after."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        src = SerialSource(f"socket://127.0.0.1:{port}")
        try:
            conn, _ = server.accept()
            with conn:
                yield src, conn, port
        finally:
            src.close()


def read_sizes(src: SerialSource, total: int) -> list[int]:
    """The size of each chunk ``src`` reads until ``total`` bytes came (5 s at most)."""
    sizes: list[int] = []
    deadline = time.monotonic() + 5.0
    while sum(sizes) < total and time.monotonic() < deadline:
        chunk = src.read(0.5)
        if chunk:
            sizes.append(len(chunk[0]))
    return sizes


def test_a_read_of_a_url_port_takes_at_most_one_read_of_a_tty() -> None:
    """pyserial's path (URLs) read all that waited: after a stall an ``rfc2217://``
    bridge could hand over 64 KiB in one chunk, one record of a recording, which a power
    cut would tear into more than a torn record may be (``MAX_TORN_BYTES``). A read
    takes at most ``READ_MAX_BYTES``, as ``os.read`` on a tty does; the rest comes in
    the next reads. ``spy://`` on a pty takes pyserial's path and counts what waits as
    those bridges do."""
    from lunad.daemon.sources.recording import MAX_TORN_BYTES
    from lunad.daemon.sources.serial import READ_MAX_BYTES

    sent = FRAME * 1000  # 9 kB: more than two reads, less than a pty holds
    master, slave = os.openpty()
    src = SerialSource(f"spy://{os.ttyname(slave)}")
    try:
        os.write(master, sent)
        time.sleep(0.2)
        sizes = read_sizes(src, len(sent))
    finally:
        src.close()
        os.close(master)
        os.close(slave)
    assert sum(sizes) == len(sent)
    # a pty hands over 4095 or 4096 bytes a read, by kernel: at most one read of it
    assert max(sizes) <= READ_MAX_BYTES and 2 * READ_MAX_BYTES + 16 <= MAX_TORN_BYTES


def test_a_socket_port_reads_what_came_not_two_bytes_at_a_time() -> None:
    """pyserial's ``socket://`` says 1 byte waits whenever any do, so each read took 2
    bytes: 5 reads a frame, and in a recording 5 records of 16 bytes' overhead each.
    A read takes what came, up to ``READ_MAX_BYTES``."""
    from lunad.daemon.sources.serial import READ_MAX_BYTES

    sent = FRAME * 1000
    with socket_port() as (src, conn, _port):
        conn.sendall(sent)
        sizes = read_sizes(src, len(sent))
        conn.close()
    assert sum(sizes) == len(sent)
    assert len(sizes) < len(sent) // 100 and max(sizes) <= READ_MAX_BYTES, sizes[:20]


def test_a_socket_port_whose_server_went_away_is_source_lost() -> None:
    """``socket://`` (ser2net, a Wi-Fi bridge): the server closing is a lost source the
    daemon reconnects to, not an exception out of ``read`` that ends it."""
    with socket_port() as (src, conn, port):
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
