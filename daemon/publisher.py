"""The ZeroMQ PUB socket that robot code subscribes to.

Sends never block the read loop: they use ``NOBLOCK``, and when a subscriber's queue
is at the high-water mark ZeroMQ drops the message; ``dropped_sends`` counts what the
socket refused, and health reports it.
"""

from __future__ import annotations

from pathlib import Path

import zmq

from lunad.daemon.errors import PublishError

LINGER_MS = 200  # on close, how long queued messages may still go out


class Publisher:
    """A bound PUB socket sending two-frame messages (topic, JSON)."""

    def __init__(self, endpoint: str, sndhwm: int = 1000) -> None:
        self.endpoint = endpoint
        self.dropped_sends = 0
        self.sent = 0
        if endpoint.startswith("ipc://"):
            Path(endpoint.removeprefix("ipc://")).parent.mkdir(parents=True, exist_ok=True)
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.PUB)
        self._sock.setsockopt(zmq.SNDHWM, sndhwm)
        self._sock.setsockopt(zmq.LINGER, LINGER_MS)
        try:
            self._sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.close()
            raise PublishError(f"cannot bind {endpoint}: {exc}") from exc

    def send(self, topic: bytes, payload: bytes) -> bool:
        """Queue one message; False (and counted) when the socket refused it."""
        try:
            self._sock.send_multipart((topic, payload), flags=zmq.NOBLOCK, copy=True)
        except zmq.Again:
            self.dropped_sends += 1
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        """Close the socket and its context; safe to call twice."""
        self._sock.close()
        self._ctx.term()
