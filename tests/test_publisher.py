"""The publisher's waker thread stops at once when the publisher closes, and one pump
reads a bounded number of frames.

Its waking the loop for a late subscriber is tested end to end in test_serve_field.py;
the publisher against peers that are not honest subscribers in
test_publisher_attacks.py."""

from __future__ import annotations

import threading
import time
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


def test_pump_stops_at_its_bound_and_asks_to_be_called_again(tmp_path: Path) -> None:
    """Three bounds' worth of frames queued: each call reads at most PUMP_EVENTS, sets
    ``pending`` and wakes the loop while frames are left, and the last leaves it clear."""
    endpoint = f"ipc://{tmp_path}/p.sock"
    pub = Publisher(endpoint)
    wakes: list[int] = []
    pub._wake = lambda: wakes.append(1)  # the loop's wake-up, without a waker thread
    ctx = zmq.Context()
    peer = ctx.socket(zmq.XSUB)
    try:
        peer.connect(endpoint)
        deadline = time.monotonic() + 5
        while not pub.peers:  # counted, then admitted (ZAP), by pump
            assert time.monotonic() < deadline, "the peer never connected"
            pub.pump()
        frames = 3 * publisher.PUMP_EVENTS
        for _ in range(frames):
            peer.send(b"\x07not a subscription")
        read: list[int] = []
        deadline = time.monotonic() + 5
        while sum(read) < frames and time.monotonic() < deadline:
            before = pub.junk_frames
            pub.pump()
            read.append(pub.junk_frames - before)
            if read[-1] == publisher.PUMP_EVENTS:
                assert pub.pending and wakes, "a pump stopped at its bound did not ask again"
            wakes.clear()
        assert sum(read) == frames
        assert max(read) <= publisher.PUMP_EVENTS
        pub.pump()
        assert not pub.pending
    finally:
        peer.close(0)
        ctx.term()
        pub.close()


def test_an_ipc_endpoint_never_clobbers_what_is_at_its_path(tmp_path: Path) -> None:
    """libzmq unlinks whatever is at an ipc path before it binds: a regular file was
    deleted, and another live daemon's socket taken over with its subscribers."""
    from lunad.daemon.errors import PublishError

    regular = tmp_path / "file.sock"
    regular.write_text("keep me")
    with pytest.raises(PublishError, match="not a socket"):
        Publisher(f"ipc://{regular}")
    assert regular.read_text() == "keep me"

    live = f"ipc://{tmp_path}/live.sock"
    first = Publisher(live)
    try:
        with pytest.raises(PublishError, match="another process is listening"):
            Publisher(live)
    finally:
        first.close()
    assert not (tmp_path / "live.sock").exists(), "our socket file is removed at close"

    import socket as _socket

    stale = tmp_path / "stale.sock"
    left = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    left.bind(str(stale))  # a socket file whose owner died: nobody listens
    left.close()
    again = Publisher(f"ipc://{stale}")
    again.close()


def test_a_cached_range_is_marked_and_turns_stale(tmp_path: Path) -> None:
    """A late subscriber tells a cached message from a live one, and its age, from the
    message alone; one older than the staleness limit is a ``stale`` dropout."""
    from lunad.protocol.messages import RangeMessage, encode_range, range_ident, topic

    endpoint = f"ipc://{tmp_path}/c.sock"
    pub = Publisher(endpoint, stale_after_s=0.3)
    ctx = zmq.Context()
    try:
        payload = encode_range(
            range_ident("c", "00000000000000c1"), 5, 1, 1, 2, 2.0, 1800, 40.0, 0.9, 2.0,
            0.004, 100.0, "ok", b"[]", "stable",
        )  # fmt: skip
        pub.send(topic("range", "c"), payload)

        def join() -> RangeMessage:
            sub = ctx.socket(zmq.SUB)
            sub.setsockopt(zmq.SUBSCRIBE, b"range/c/")
            sub.connect(endpoint)
            try:
                deadline = time.monotonic() + 5.0
                while time.monotonic() < deadline:
                    pub.pump()
                    if sub.poll(50):
                        return RangeMessage.model_validate_json(sub.recv_multipart()[1])
                pytest.fail("no cached message")
            finally:
                sub.close(linger=0)

        fresh = join()
        assert fresh.cached and fresh.status == "ok" and fresh.range_m == 2.0
        assert 0 <= fresh.age_ms < 300
        time.sleep(0.8)  # older than the limit, and past the replay interval
        old = join()
        assert old.cached and old.age_ms >= 300
        assert old.status == "dropout" and old.range_m is None and old.reasons == ["stale"]
    finally:
        pub.close()
        ctx.term()
