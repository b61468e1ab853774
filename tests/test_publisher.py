"""The publisher's waker thread stops at once when the publisher closes.

Its waking the loop for a late subscriber is tested end to end in test_serve_field.py."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
import zmq

from lunad.daemon import publisher
from lunad.daemon.publisher import Publisher


class _HeldClear(threading.Event):
    """An Event whose ``clear`` the test can hold, to order two threads exactly."""

    def __init__(self) -> None:
        super().__init__()
        self.hold = False
        self.clearing = threading.Event()
        self.release = threading.Event()

    def clear(self) -> None:
        if self.hold:
            self.clearing.set()
            self.release.wait(5)
        super().clear()

    def set(self) -> None:
        super().set()
        if self.hold:
            self.release.set()


def test_close_does_not_wait_for_a_handshake_the_loop_will_never_give(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The loop has stopped when the socket stirs (a subscriber leaving as the daemon
    stops): the waker must not then wait out its handshake. Here the waker is held just
    before it re-arms its handshake, until ``close`` has signalled it; the old code then
    cleared that signal and slept WAKER_HANDSHAKE_S (the daemon's 1 s slow exits), so
    with a 60 s handshake the waker outlived close's 2 s join."""
    monkeypatch.setattr(publisher, "WAKER_HANDSHAKE_S", 60.0)
    endpoint = f"ipc://{tmp_path}/p.sock"
    pub = Publisher(endpoint)
    pumped = _HeldClear()
    pumped.hold = True  # the waker's first wake-up, whatever stirred the socket, is held
    pub._pumped = pumped
    pub.start_waker(lambda: None)
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    try:
        sub.connect(endpoint)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        assert pumped.clearing.wait(5), "the socket never woke the waker"
        waker = pub._waker
        assert waker is not None
        pub.close()
    finally:
        sub.close(0)
        ctx.term()
    assert not waker.is_alive(), "the waker was still waiting for the loop's handshake"
