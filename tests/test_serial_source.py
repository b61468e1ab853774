"""SerialSource on real pseudo-terminals: batched reads (the tty's VMIN) and hang-ups."""

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


def vmin(master: int) -> int:
    """The slave's VMIN, read through the master (termios ioctls reach the slave)."""
    value: int = termios.tcgetattr(master)[6][termios.VMIN]
    return value


def test_reads_return_each_frame_without_a_batch(line: tuple[int, SerialSource]) -> None:
    master, src = line
    assert vmin(master) == 0
    os.write(master, FRAME)
    chunk = src.read(1.0)
    assert chunk is not None and chunk.data == FRAME


def test_batch_holds_the_read_until_the_batch_came(line: tuple[int, SerialSource]) -> None:
    master, src = line
    assert src.batch(2 * len(FRAME)) == 18
    assert vmin(master) == 18
    os.write(master, FRAME)
    t0 = time.monotonic()
    assert src.read(0.2) is None  # one frame of two: held, the read times out
    assert time.monotonic() - t0 >= 0.15
    os.write(master, FRAME)
    chunk = src.read(2.0)
    assert chunk is not None and chunk.data == FRAME * 2


def test_unbatching_releases_the_bytes_short_of_a_batch(line: tuple[int, SerialSource]) -> None:
    master, src = line
    assert src.batch(5 * len(FRAME)) == 45
    os.write(master, FRAME * 3)
    assert src.read(0.1) is None
    assert src.batch(0) == 0 and vmin(master) == 0
    chunk = src.read(1.0)
    assert chunk is not None and chunk.data == FRAME * 3


def test_batch_is_capped_at_what_vmin_holds(line: tuple[int, SerialSource]) -> None:
    master, src = line
    assert src.batch(1000) == 255
    assert vmin(master) == 255


def test_close_gives_the_line_back_unbatched(line: tuple[int, SerialSource]) -> None:
    master, src = line
    src.batch(45)
    src.close()
    assert vmin(master) == 0


def test_hang_up_while_batched_is_source_lost(line: tuple[int, SerialSource]) -> None:
    master, src = line
    src.batch(45)
    os.write(master, FRAME)
    os.close(master)
    t0 = time.monotonic()
    with pytest.raises(SourceLostError):
        for _ in range(3):  # the queued frame may come first
            src.read(2.0)
    assert time.monotonic() - t0 < 1.0  # a hang-up does not wait for the batch


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


def test_url_ports_cannot_batch() -> None:
    src = SerialSource("loop://")
    try:
        assert src.batch(45) == 0
    finally:
        src.close()
