"""A small subscriber for robot code::

    from lunad.protocol.client import Subscriber
    with Subscriber("tcp://127.0.0.1:7781") as sub:
        for msg in sub:
            print(msg.range_m if msg.kind == "range" else msg.state)

ZeroMQ reconnects a SUB socket by itself, so a daemon restart needs nothing from the
caller. The subscriber checks every ``range`` message's ``seq``, sensor by sensor, and
counts the messages it missed in ``lost`` (a daemon restart, seen as ``seq`` going back,
is not a loss; in the daemon's ``--publish-hz`` mode the gaps are frames folded on
purpose). A message repeating its sensor's last ``seq``, or a ``health`` message
repeating its sensor's last one byte for byte, is the daemon's last-value cache
answering another subscriber's arrival, and is dropped. Messages that do not decode
are counted in ``bad_messages`` and skipped.

``lost`` is exact within one run of the daemon. A ``range`` message carries no run
identity (DESIGN.md), so a restart seen only after the new run's ``seq`` has passed
the last one seen (the old run was shorter than the time the subscriber took to
reconnect) reads as a gap and is counted.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from types import TracebackType

import zmq
from pydantic import ValidationError

from lunad.protocol.messages import (
    HEALTH_TOPIC,
    RANGE_TOPIC,
    HealthMessage,
    Message,
    RangeMessage,
    decode,
)

_HEALTH_PREFIX = f"{HEALTH_TOPIC}/".encode()
RECONNECT_IVL_MS = 100
RECONNECT_IVL_MAX_MS = 2000

__all__ = ["HealthMessage", "RangeMessage", "Subscriber"]


class Subscriber:
    """Receives typed ``range`` and ``health`` messages from a lunad daemon.

    Args:
        endpoint: where the daemon publishes, e.g. ``tcp://127.0.0.1:7781`` or
            ``ipc:///run/lunad/front.sock``.
        sensor: only this sensor's messages; None for every sensor on the endpoint.
        kinds: which topics to receive, ``"range"`` and/or ``"health"``.
        context: a ZeroMQ context to share; by default the process-wide instance.
    """

    def __init__(
        self,
        endpoint: str,
        sensor: str | None = None,
        kinds: Iterable[str] = (RANGE_TOPIC, HEALTH_TOPIC),
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.sensor = sensor
        self.lost = 0
        self.bad_messages = 0
        self.last_seq: int | None = None
        """``seq`` of the last ``range`` message returned, of whichever sensor."""
        self._last_seqs: dict[str, int] = {}
        self._last_health: dict[bytes, bytes] = {}
        ctx = context or zmq.Context.instance()
        self._sock = ctx.socket(zmq.SUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.RECONNECT_IVL, RECONNECT_IVL_MS)
        self._sock.setsockopt(zmq.RECONNECT_IVL_MAX, RECONNECT_IVL_MAX_MS)
        self._topics = set()
        for kind in kinds:
            prefix = f"{kind}/{sensor}" if sensor else f"{kind}/"
            self._topics.add(kind)
            self._sock.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        self._sock.connect(endpoint)

    def recv(self, timeout_s: float | None = None) -> Message | None:
        """The next message, or None when none came within ``timeout_s`` seconds
        (messages skipped meanwhile, of another sensor or repeated, count against it)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            if deadline is not None:
                left_ms = max(0, int((deadline - time.monotonic()) * 1000))
                if not self._sock.poll(left_ms):
                    return None
            parts = self._sock.recv_multipart()
            if len(parts) != 2:
                self.bad_messages += 1
                continue
            topic, payload = parts
            if self.sensor is not None and topic.split(b"/", 1)[-1] != self.sensor.encode():
                continue
            health = topic.startswith(_HEALTH_PREFIX)
            if health and self._last_health.get(topic) == payload:
                continue
            try:
                msg = decode(topic, payload)
            except (ValueError, ValidationError):
                self.bad_messages += 1
                continue
            if isinstance(msg, RangeMessage) and not self._track(msg.sensor, msg.seq):
                continue
            if health:
                self._last_health[topic] = payload
            return msg

    def __iter__(self) -> Iterator[Message]:
        while True:
            msg = self.recv()
            if msg is not None:
                yield msg

    def _track(self, sensor: str, seq: int) -> bool:
        """Note ``sensor``'s ``seq``; False for a repeat of its last one (a cache replay)."""
        last = self._last_seqs.get(sensor)
        if last is not None:
            if seq == last:
                return False
            if seq > last + 1:
                self.lost += seq - last - 1
        self._last_seqs[sensor] = seq
        self.last_seq = seq
        return True

    def close(self) -> None:
        """Close the socket; safe to call twice."""
        self._sock.close(linger=0)

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
