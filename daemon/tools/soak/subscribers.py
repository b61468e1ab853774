"""The soak's subscribers: the main one, which reads every message promptly as robot
code would and feeds the ledger, and the slow one of the ``slow_subscriber`` fault."""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Any

from lunad.daemon.tools.soak.ledger import Ledger
from lunad.protocol.messages import topic

NS = 1_000_000_000
SENSOR = "soak"


class Watch:
    """A wait for a message (``MainSubscriber.watch``): set when it arrives, at ``t_ns``."""

    def __init__(self, kind: str, after_ns: int, state: str | None) -> None:
        self.kind, self.after_ns, self.state = kind, after_ns, state
        self.t_ns: int | None = None
        self.event = threading.Event()


class LatencyHistogram:
    """Log-spaced histogram of latencies (4 buckets per octave of microseconds)."""

    def __init__(self) -> None:
        self.counts: dict[int, int] = {}
        self.n = 0
        self.max_us = 0.0

    def add(self, us: float) -> None:
        b = int(4 * math.log2(max(us, 1.0)))
        self.counts[b] = self.counts.get(b, 0) + 1
        self.n += 1
        self.max_us = max(self.max_us, us)

    def quantile(self, q: float) -> float:
        """Upper edge of the bucket holding quantile ``q``, microseconds."""
        if not self.n:
            return float("nan")
        k = q * self.n
        seen = 0
        for b in sorted(self.counts):
            seen += self.counts[b]
            if seen >= k:
                return min(2 ** ((b + 1) / 4), self.max_us)
        return self.max_us


class MainSubscriber(threading.Thread):
    """Reads every message promptly (RCVHWM unlimited), as robot code would, and checks
    it against the ledger and the schema; answers "first frame / health state after t"."""

    def __init__(self, endpoint: str, ledger: Ledger) -> None:
        super().__init__(name="soak-sub", daemon=True)
        import zmq

        self._zmq = zmq
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, 0)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RECONNECT_IVL, 100)
        for kind in ("range", "health"):
            self.sock.setsockopt(zmq.SUBSCRIBE, topic(kind, SENSOR))
        self.sock.connect(endpoint)
        self.ledger = ledger
        self.stop = threading.Event()
        self.bad_messages = 0
        self.health_msgs = 0
        self.last_health: Any = None
        self.states: list[tuple[int, str]] = []
        self.latency = LatencyHistogram()
        self.window_max_lat_us = 0.0
        self.last_range_ns = 0
        self.read_times: deque[int] = deque(maxlen=30_000)  # daemon read time of each frame
        self._watches: list[Watch] = []
        self._wlock = threading.Lock()

    def watch(self, kind: str, after_ns: int, state: str | None = None) -> Watch:
        """Register before the event: the first ``kind`` message after ``after_ns``
        (range: read by the daemon at or after it; health: with ``state``)."""
        w = Watch(kind, after_ns, state)
        with self._wlock:
            self._watches.append(w)
        return w

    def wait(self, w: Watch, timeout_s: float) -> float | None:
        """Seconds from ``after_ns`` to the watched message's arrival, or None."""
        w.event.wait(timeout_s)
        with self._wlock:
            if w in self._watches:
                self._watches.remove(w)
        return None if w.t_ns is None else (w.t_ns - w.after_ns) / NS

    def _notify(self, kind: str, t_ns: int, t_read: int, state: str | None) -> None:
        with self._wlock:
            for w in self._watches:
                if w.t_ns is not None or w.kind != kind:
                    continue
                if kind == "range" and t_read >= w.after_ns:
                    w.t_ns = t_ns
                    w.event.set()
                elif kind == "health" and t_ns >= w.after_ns and state == w.state:
                    w.t_ns = t_ns
                    w.event.set()

    def run(self) -> None:
        from pydantic import ValidationError

        from lunad.protocol.messages import RangeMessage, decode

        zmq = self._zmq
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        mono = time.monotonic_ns
        while not self.stop.is_set():
            if not poller.poll(100):
                continue
            while True:
                try:
                    parts = self.sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                t = mono()
                try:
                    if len(parts) != 2:
                        raise ValueError("not two frames")
                    msg = decode(parts[0], parts[1])
                except (ValueError, ValidationError):
                    self.bad_messages += 1
                    continue
                if isinstance(msg, RangeMessage):
                    if not self.ledger.on_range(msg.seq, msg.raw_m, msg.amp, msg.t_mono_ns):
                        continue
                    self.read_times.append(msg.t_mono_ns)
                    lat_us = (t - msg.t_mono_ns) / 1000
                    self.latency.add(lat_us)
                    self.window_max_lat_us = max(self.window_max_lat_us, lat_us)
                    self.last_range_ns = t
                    self._notify("range", t, msg.t_mono_ns, None)
                else:
                    self.health_msgs += 1
                    self.last_health = msg
                    if not self.states or self.states[-1][1] != msg.state:
                        self.states.append((t, msg.state))
                    self._notify("health", t, t, msg.state)

    def close(self) -> None:
        self.stop.set()
        self.join(2.0)
        self.sock.close(linger=0)
        self.ctx.term()


class SlowSubscriber(threading.Thread):
    """A subscriber with a small RCVHWM that stops reading while ``reading`` is clear."""

    def __init__(self, endpoint: str, rcvhwm: int) -> None:
        super().__init__(name="soak-slow-sub", daemon=True)
        import zmq

        self._zmq = zmq
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, rcvhwm)
        self.sock.setsockopt(zmq.RCVBUF, 4096)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, topic("range", SENSOR))
        self.sock.connect(endpoint)
        self.reading = threading.Event()
        self.reading.set()
        self.stop = threading.Event()
        self.received = 0
        self.lost = 0
        self.last_seq: int | None = None

    def run(self) -> None:
        from lunad.daemon.tools.bench.receiver import seq_of

        zmq = self._zmq
        while not self.stop.is_set():
            if not self.reading.wait(0.1):
                continue
            if not self.sock.poll(100):
                continue
            while self.reading.is_set():
                try:
                    parts = self.sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                seq = seq_of(parts[1])
                last = self.last_seq
                if last is not None and seq <= last:
                    continue
                if last is not None and seq > last + 1:
                    self.lost += seq - last - 1
                self.last_seq = seq
                self.received += 1

    def close(self) -> None:
        self.stop.set()
        self.reading.set()
        self.join(2.0)
        self.sock.close(linger=0)
        self.ctx.term()
