"""The ZeroMQ socket robot code subscribes to, with a last-value cache.

How this works: the socket is an XPUB (a PUB that also hears subscriptions) with
``XPUB_VERBOSE``, so every new subscription reaches us, even for a topic someone
already has. The read loop calls ``pump()`` between reads; for each new subscription
it re-sends the last message of every cached topic the subscription matches, so a
late subscriber gets the latest ``range`` and ``health`` at once instead of waiting
(the zguide's "last value cache" pattern, without its extra proxy hop on the hot path).
So that the loop hears a subscription even while it blocks in a read, a waker thread
sleeps in ``select`` on the socket's ``ZMQ_FD`` (it makes no ZeroMQ call, so the socket
stays single-threaded) and calls the loop's wake-up; ``pump`` reads ``ZMQ_EVENTS``,
which re-arms that edge-triggered descriptor, then lets the waker wait again.
Subscribers already connected receive that message a second time with the same
``seq``; ``lunad.protocol.client.Subscriber`` drops such duplicates.

Sends never block the read loop (``NOBLOCK``). At the high-water mark ZeroMQ drops
messages per subscriber without telling the sender; subscribers see those losses as
gaps in ``seq``. ``dropped_sends`` counts what the socket refused outright.
ZMQ_CONFLATE is not used: it breaks multipart messages.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
from collections.abc import Callable
from pathlib import Path
from typing import cast

import zmq

from lunad.daemon.errors import PublishError

LINGER_MS = 200  # on close, how long queued messages may still go out
_EVENTS = int(zmq.EVENTS)  # plain ints: pyzmq's enum arithmetic costs on every call
_POLLIN = int(zmq.POLLIN)
_NOBLOCK = int(zmq.NOBLOCK)
_MORE = int(zmq.NOBLOCK | zmq.SNDMORE)
WAKER_HANDSHAKE_S = 1.0  # the waker re-arms after a pump, or after this at the latest
SUBSCRIBE = 1  # first byte of an XPUB subscription message (zmq_socket(3))


class Publisher:
    """A bound XPUB socket sending two-frame messages (topic, JSON)."""

    def __init__(self, endpoint: str, sndhwm: int = 1000) -> None:
        self.endpoint = endpoint
        self.dropped_sends = 0
        self.sent = 0
        self.subscriptions = 0
        self._last: dict[bytes, bytes] = {}
        self._pumped = threading.Event()
        self._closing = False
        self.pending = True
        """Set by the waker: the socket may hold a subscription; ``pump`` clears it."""
        self._waker: threading.Thread | None = None
        self._waker_stop_r, self._waker_stop_w = -1, -1
        if endpoint.startswith("ipc://"):
            try:
                Path(endpoint.removeprefix("ipc://")).parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise PublishError(f"cannot bind {endpoint}: {exc}") from exc
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.XPUB)
        self._sock.setsockopt(zmq.SNDHWM, sndhwm)
        self._sock.setsockopt(zmq.LINGER, LINGER_MS)
        self._sock.setsockopt(zmq.XPUB_VERBOSE, 1)
        self._send = super(zmq.Socket, self._sock).send
        """pyzmq's backend ``send``, past the Python layer of ``zmq.Socket.send``,
        which only adds the routing_id and group arguments of draft sockets."""
        try:
            self._sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.close()
            raise PublishError(f"cannot bind {endpoint}: {exc}") from exc

    def send(self, topic: bytes, payload: bytes) -> bool:
        """Queue one message and cache it as the topic's last value.

        Returns False (and counts it) when the socket refused the message.
        """
        self._last[topic] = payload
        send = self._send
        try:
            send(topic, _MORE)
            send(payload, _NOBLOCK)  # a PUB that took the first part takes the rest
        except zmq.Again:
            self.dropped_sends += 1
            return False
        self.sent += 1
        return True

    def pump(self) -> int:
        """Answer new subscriptions with the cached last values; returns how many came.

        The loop calls it when ``pending`` is set (the waker saw the socket stir) and
        with every health message as a fallback, so frames do not pay for it.
        """
        sock = self._sock
        self.pending = False
        n = 0
        while cast(int, sock.getsockopt(_EVENTS)) & _POLLIN:
            try:
                msg = sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            if not msg or msg[0] != SUBSCRIBE:
                continue
            n += 1
            prefix = msg[1:]
            for topic, payload in list(self._last.items()):
                if topic.startswith(prefix):
                    try:
                        sock.send_multipart((topic, payload), flags=zmq.NOBLOCK)
                    except zmq.Again:
                        self.dropped_sends += 1
        self.subscriptions += n
        self._pumped.set()
        return n

    def start_waker(self, wake: Callable[[], None]) -> None:
        """Call ``wake`` (from a thread) whenever the socket may have a new subscription."""
        fd = cast(int, self._sock.getsockopt(zmq.FD))
        self._waker_stop_r, self._waker_stop_w = os.pipe()

        def run() -> None:
            while True:
                ready, _, _ = select.select([fd, self._waker_stop_r], [], [])
                if self._waker_stop_r in ready:
                    return
                self._pumped.clear()
                if self._closing:
                    return  # close() may have set _pumped just before that clear; no pump will come
                self.pending = True
                wake()
                self._pumped.wait(WAKER_HANDSHAKE_S)

        self._waker = threading.Thread(target=run, name="lvc-waker", daemon=True)
        self._waker.start()

    def close(self) -> None:
        """Stop the waker, close the socket and its context; safe to call twice."""
        if self._waker is not None:
            self._closing = True
            os.write(self._waker_stop_w, b"x")
            self._pumped.set()  # release a waker waiting for the loop's handshake
            self._waker.join(timeout=2.0)
            self._waker = None
        for fd in (self._waker_stop_r, self._waker_stop_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._waker_stop_r = self._waker_stop_w = -1
        self._sock.close()
        self._ctx.term()
