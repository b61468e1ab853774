"""A small subscriber for robot code (the contract: docs/messages.md)::

    from lunad.protocol.client import StaleStream, Subscriber
    with Subscriber("ipc:///run/lunad/front.sock", sensor="front", stale_after_s=0.2) as sub:
        try:
            for msg in sub:
                if msg.kind == "range" and msg.range_m is not None:
                    drive(msg.range_m, msg.sigma_m)
        except StaleStream:
            stop_the_robot()  # the daemon has gone quiet: act on nothing old

Over a LAN, a daemon configured with CURVE (docs/security.md) is reached with the
server's public key and this client's key pair (``lunad keys`` makes both)::

    Subscriber("tcp://192.168.1.10:7781", sensor="front",
               curve_server_key="/etc/robot/curve/server.key",
               curve_client_key="/etc/robot/curve/robot.key_secret")

The stream is then encrypted, and only a publisher holding the secret key of
``curve_server_key`` can be read: any other one fails the handshake and nothing
arrives. The daemon admits the client only if its public key (``robot.key``) is in its
client directory; a client it refused does not retry, so a key added later needs a new
``Subscriber``.

ZeroMQ reconnects a SUB socket by itself, so a daemon restart needs nothing from the
caller. The subscriber applies the contract's rules:

- topics match exactly (``range/<sensor>/``), in the subscription and again here;
- a ``range`` message whose ``seq`` is at most the last one seen in the same ``run`` is
  a duplicate (the daemon's last-value cache answering another subscriber's arrival)
  and is dropped; a ``health`` message repeating its sensor's last one byte for byte
  likewise;
- ``lost`` counts the frames missed, ``seq - last - frames`` when positive, so the
  frames ``--publish-hz`` folds into one message are not loss; a new ``run`` (a daemon
  restart) starts the count again;
- with ``stale_after_s``, iterating raises :class:`StaleStream` once no message has
  come for that long (and, iterated again, after each further spell of that long), and
  ``alive`` says whether one was made within it: a cached message counts from when it
  was made (its ``age_ms``), not from when it came, and one older than
  ``stale_after_s`` comes as a ``dropout`` with the reason ``stale``, as the daemon
  sends one older than its own limit;
- messages that do not decode, break the contract's rules or name another sensor than
  their topic are counted in ``bad_messages`` and skipped, and so is one longer than
  ``MAX_MESSAGE_BYTES`` (64 KiB), before it is parsed; one over 1 MiB ends the
  connection (``SOCKET_MAX_MESSAGE_BYTES``).
"""

from __future__ import annotations

import math
import os
import re
import time
from collections import deque
from collections.abc import Iterable, Iterator
from types import TracebackType

import zmq
from pydantic import ValidationError

from lunad.protocol.curve_keys import Z85_KEY_CHARS, read_key_file, z85_key
from lunad.protocol.messages import (
    HEALTH_TOPIC,
    RANGE_TOPIC,
    SENSOR_NAME_PATTERN,
    HealthMessage,
    Message,
    RangeMessage,
    as_stale,
    decode,
)

RECONNECT_IVL_MS = 100
RECONNECT_IVL_MAX_MS = 2000
SOCKET_MAX_MESSAGE_BYTES = 1 << 20
"""The longest message frame libzmq reads for us, bytes (our bound): past it libzmq ends
the connection, and does not reconnect (a protocol error), rather than hold the message
in memory; the publisher was not a lunad daemon, and ``alive`` and ``StaleStream`` say
that nothing comes. Messages between ``MAX_MESSAGE_BYTES`` and this are read, refused
before they are parsed, and counted in ``bad_messages``."""
RATE_WINDOW_S = 2.0
"""Messages over this many seconds make ``rate_hz`` (our choice: steady, yet it follows a
change of ``--publish-hz`` within a couple of seconds)."""

__all__ = ["HealthMessage", "RangeMessage", "StaleStream", "Subscriber"]

KeyText = str | bytes
"""A CURVE key as 40 Z85 characters."""
KeyPath = str | os.PathLike[str]
"""A ZPL key file, as ``zmq.auth.create_certificates`` and ``lunad keys`` write it."""


class StaleStream(TimeoutError):
    """No message came for longer than the subscriber's ``stale_after_s``.

    Attributes:
        silent_s: seconds since the last message (or since the subscriber started).
    """

    def __init__(self, endpoint: str, silent_s: float) -> None:
        super().__init__(f"no message from {endpoint} for {silent_s:.3f} s")
        self.silent_s = silent_s


class Subscriber:
    """Receives typed ``range`` and ``health`` messages from a lunad daemon.

    Args:
        endpoint: where the daemon publishes, e.g. ``ipc:///run/lunad/front.sock`` or
            ``tcp://127.0.0.1:7781``.
        sensor: only this sensor's messages; None for every sensor on the endpoint.
        kinds: which topics to receive, ``"range"`` and/or ``"health"``.
        stale_after_s: iterating raises :class:`StaleStream` after this many seconds
            without a message; None waits for ever.
        context: a ZeroMQ context to share; by default the process-wide instance.
        curve_server_key: connect with CURVE to a daemon with this public key: 40 Z85
            characters, or the path of its ``.key`` file (``server.key``). Given with
            ``curve_client_key``, or neither.
        curve_client_key: this client's key pair: the path of its ``.key_secret``
            file, or a (public, secret) pair of Z85 keys.

    Raises:
        ValueError: a bad ``stale_after_s``, ``sensor`` or ``kinds``, or a CURVE key that
            is not one (the message says which argument and why).
    """

    def __init__(
        self,
        endpoint: str,
        sensor: str | None = None,
        kinds: Iterable[str] = (RANGE_TOPIC, HEALTH_TOPIC),
        stale_after_s: float | None = None,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
        curve_server_key: KeyText | KeyPath | None = None,
        curve_client_key: KeyPath | tuple[KeyText, KeyText] | None = None,
    ) -> None:
        if stale_after_s is not None and not stale_after_s > 0:
            raise ValueError(f"stale_after_s must be above 0 seconds, got {stale_after_s!r}")
        if sensor is not None and not re.fullmatch(SENSOR_NAME_PATTERN, sensor):
            raise ValueError(
                f"sensor: 1-64 of A-Z a-z 0-9 _ . - (as the daemon's config takes), got {sensor!r}"
            )
        kinds = (kinds,) if isinstance(kinds, str) else tuple(kinds)
        if not kinds or not set(kinds) <= {RANGE_TOPIC, HEALTH_TOPIC}:
            raise ValueError(f"kinds: 'range' and/or 'health', got {kinds!r}")
        if (curve_server_key is None) != (curve_client_key is None):
            raise ValueError(
                "curve_server_key and curve_client_key go together: CURVE needs the "
                "server's public key and this client's key pair"
            )
        curve = None
        if curve_server_key is not None and curve_client_key is not None:
            curve = (_server_key(curve_server_key), *_client_keys(curve_client_key))
        self.endpoint = endpoint
        self.sensor = sensor
        self.stale_after_s = stale_after_s
        self.lost = 0
        self.bad_messages = 0
        self.duplicates = 0
        self.last_seq: int | None = None
        """``seq`` of the last ``range`` message returned, of whichever sensor."""
        self._last: dict[str, tuple[str, int]] = {}  # sensor -> (run, seq)
        self._last_health: dict[bytes, bytes] = {}
        self._t_last = time.monotonic()
        self._quiet_from = self._t_last
        """Since when the silence ``__iter__`` raises ``StaleStream`` for is counted: the
        last message, or the last time it raised."""
        self._arrivals: deque[float] = deque()
        self._received_any = False
        ctx = context or zmq.Context.instance()
        self._sock = ctx.socket(zmq.SUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.MAXMSGSIZE, SOCKET_MAX_MESSAGE_BYTES)
        self._sock.setsockopt(zmq.RECONNECT_IVL, RECONNECT_IVL_MS)
        self._sock.setsockopt(zmq.RECONNECT_IVL_MAX, RECONNECT_IVL_MAX_MS)
        if curve is not None:
            server, public, secret = curve
            self._sock.setsockopt(zmq.CURVE_SERVERKEY, server)
            self._sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
            self._sock.setsockopt(zmq.CURVE_SECRETKEY, secret)
        self._prefixes: list[bytes] = []
        for kind in kinds:
            prefix = f"{kind}/{sensor}/" if sensor else f"{kind}/"
            self._prefixes.append(prefix.encode())
            self._sock.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        self._sock.connect(endpoint)

    @property
    def age_s(self) -> float:
        """Seconds since the last message returned was made (a cached one's ``age_ms``
        counts), or since the start before the first."""
        return time.monotonic() - self._t_last

    @property
    def alive(self) -> bool:
        """Whether a message came within ``stale_after_s`` (True without a limit once
        any message came)."""
        if self.stale_after_s is None:
            return self._received_any
        return self._received_any and self.age_s <= self.stale_after_s

    @property
    def rate_hz(self) -> float:
        """Messages returned per second over the last ``RATE_WINDOW_S`` seconds."""
        self._forget(time.monotonic())
        return len(self._arrivals) / RATE_WINDOW_S

    def _forget(self, now: float) -> None:
        """Drop arrival times older than ``RATE_WINDOW_S`` (bounded memory)."""
        arrivals = self._arrivals
        while arrivals and now - arrivals[0] > RATE_WINDOW_S:
            arrivals.popleft()

    def recv(self, timeout_s: float | None = None) -> Message | None:
        """The next message, or None when none came within ``timeout_s`` seconds
        (messages skipped meanwhile, of another sensor or repeated, count against it)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            if deadline is not None:
                left_ms = max(0, math.ceil((deadline - time.monotonic()) * 1000))
                if not self._sock.poll(left_ms):
                    return None
            parts = self._sock.recv_multipart()
            if len(parts) != 2:
                self.bad_messages += 1
                continue
            topic, payload = parts
            if not self._wanted(topic):
                continue
            health = topic.startswith(b"health/")
            if health and self._last_health.get(topic) == payload:
                self.duplicates += 1
                continue
            try:
                msg = decode(topic, payload)
            except (ValueError, ValidationError):
                self.bad_messages += 1
                continue
            now = made = time.monotonic()
            if isinstance(msg, RangeMessage):
                if not self._track(msg):
                    self.duplicates += 1
                    continue
                if msg.cached:
                    msg = self._stale_if_old(msg)
                    made -= msg.age_ms / 1000
            if health:
                self._last_health[topic] = payload
            self._t_last = self._quiet_from = made
            self._received_any = True
            self._arrivals.append(now)
            self._forget(now)
            return msg

    def __iter__(self) -> Iterator[Message]:
        """Messages as they come; raises :class:`StaleStream` after ``stale_after_s``
        seconds of silence (never without a limit)."""
        while True:
            if self.stale_after_s is None:
                msg = self.recv()
            else:
                left = self.stale_after_s - (time.monotonic() - self._quiet_from)
                msg = self.recv(max(0.0, left))
                if msg is None and time.monotonic() - self._quiet_from >= self.stale_after_s:
                    self._quiet_from = time.monotonic()  # iterating again waits another spell
                    raise StaleStream(self.endpoint, self.age_s)
            if msg is not None:
                yield msg

    def _stale_if_old(self, msg: RangeMessage) -> RangeMessage:
        """A cached ``msg`` older than ``stale_after_s`` as the daemon sends one older
        than its own limit: a ``dropout`` with the reason ``stale`` and no range
        (docs/messages.md, "Cached and stale messages")."""
        limit = self.stale_after_s
        if limit is None or msg.age_ms <= limit * 1000 or msg.status == "dropout":
            return msg
        return as_stale(msg)

    def _wanted(self, topic: bytes) -> bool:
        """Whether ``topic`` is exactly one this subscriber asked for (v2 topics end in
        ``/``; ZeroMQ matched only their prefix)."""
        if not topic.endswith(b"/"):
            return False
        if self.sensor is None:
            return any(topic.startswith(p) for p in self._prefixes) and topic.count(b"/") == 2
        return topic in self._prefixes

    def _track(self, msg: RangeMessage) -> bool:
        """Note ``msg``'s ``seq``; False for a duplicate (``seq`` not beyond the last of
        its run)."""
        last = self._last.get(msg.sensor)
        if last is not None and last[0] == msg.run:
            if msg.seq <= last[1]:
                return False
            gap = msg.seq - last[1] - msg.frames
            if gap > 0:
                self.lost += gap
        self._last[msg.sensor] = (msg.run, msg.seq)
        self.last_seq = msg.seq
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


def _key_text(value: KeyText) -> bytes | None:
    """``value`` as the 40 ASCII bytes of a Z85 CURVE key, or None if it is not one."""
    text = value.encode("ascii", "replace") if isinstance(value, str) else bytes(value)
    return text if z85_key(text) is not None else None


def _read(path: KeyPath, argument: str, secret: bool = False) -> tuple[bytes, bytes | None]:
    """The (public, secret) Z85 keys of the key file ``path``, checked as the daemon
    checks its own (``read_key_file``); a ValueError names ``argument`` first."""
    try:
        return read_key_file(path, secret=secret)
    except ValueError as exc:
        raise ValueError(f"{argument}: {exc}") from None


def _server_key(value: KeyText | KeyPath) -> bytes:
    """The server's public key from 40 Z85 characters or a ``.key`` file's path (a
    ``pathlib.Path`` is always a path)."""
    if isinstance(value, (str, bytes)) and (key := _key_text(value)) is not None:
        return key
    if isinstance(value, bytes):
        raise ValueError(f"curve_server_key: bytes must be {Z85_KEY_CHARS} Z85 characters")
    return _read(value, "curve_server_key")[0]


def _client_keys(value: KeyPath | tuple[KeyText, KeyText]) -> tuple[bytes, bytes]:
    """This client's (public, secret) keys from a ``.key_secret`` file's path or a pair,
    checked to belong together: a mismatched pair fails the handshake without a word."""
    if isinstance(value, tuple):
        public, secret = (_key_text(v) for v in value)
    else:  # read_key_file checks a file's pair itself, and that it has a secret key
        public, secret = _read(value, "curve_client_key", secret=True)
    if public is None or secret is None:
        raise ValueError(
            f"curve_client_key: a (public, secret) pair of {Z85_KEY_CHARS} Z85 characters each"
        )
    if zmq.curve_public(secret) != public:
        raise ValueError("curve_client_key: the public key is not the secret key's")
    return public, secret
