"""The publisher against peers that are not honest subscribers.

Each test runs a real ``Publisher`` in this process with a loop thread that drives it as
``lunad serve`` does (a ``range`` message every 4 ms, ``pump`` when ``pending`` is set,
the waker waking it), a real ZeroMQ SUB as the honest subscriber, and the attacker in a
child process: this file run as a script, speaking ZMTP 3.0 NULL on a raw socket, or a
``zmq.XSUB``. Every test asserts what an honest subscriber and the daemon must keep:
every message published after the subscriber joined arrives, with no ``seq`` gap; each
cached message reaches it at most a few times; no ``pump`` call takes long; the
process's resident memory grows by less than ``RSS_LIMIT_MIB``.

Run by hand, ``python tests/test_publisher_attacks.py KIND ENDPOINT SECONDS [ARG
[SOURCE_IP]]`` attacks an endpoint (``KIND`` is one of ``ATTACKS``) and prints what it
did as JSON.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zmq

from lunad.daemon import publisher as publisher_module
from lunad.daemon.publisher import Publisher

RANGE = b"range/tfluna"
HEALTH = b"health/tfluna"
PERIOD_S = 0.004  # one range message every 4 ms, the TF-Luna's 250 Hz
HEALTH_EVERY_S = 30.0
"""The loop's health interval, seconds: longer than a test, so a health message that
reaches a subscriber after the first can only be the last-value cache's."""
ATTACK_S = 3.0  # how long each attacker runs
RSS_LIMIT_MIB = 20.0  # growth of this process's VmRSS over an attack
PUMP_LIMIT_S = 0.05
"""Longest one ``pump`` may take, seconds: at most a few milliseconds of work, with room
for a preemption on a loaded machine."""
LATE_JOIN_LIMIT_S = 1.5
"""A subscriber joining mid-attack gets the cached ``health`` within this, seconds:
``REPLAY_INTERVAL_S`` (0.5) and the backlog ahead of its subscription."""
RSS_ABORT_MIB = 400.0
"""An attack growing this process by more than this is stopped at once, so that a
publisher without bounds cannot take a shared machine's memory."""
JOIN_TIMEOUT_S = 5.0
ATTACKER_IP = "127.0.0.2"
"""The TCP attacker's source address: another host, as far as the publisher can tell
(the honest subscribers connect from 127.0.0.1)."""


def _rss_mib() -> float:
    """This process's resident set size, MiB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def _open_fds() -> int:
    """Descriptors this process has open."""
    return len(os.listdir("/proc/self/fd"))


class Loop(threading.Thread):
    """``lunad serve``'s use of the publisher, reduced to its timing: a ``range``
    message with the next ``seq`` every ``PERIOD_S``, a ``health`` message at start,
    and ``pump`` whenever ``pending`` is set, woken by the publisher's waker."""

    def __init__(self, pub: Publisher) -> None:
        super().__init__(name="publisher-loop")
        self.pub = pub
        self.seq = -1
        self.pump_s: list[float] = []
        self._wake = threading.Event()
        self._stopping = False

    def stop(self) -> None:
        self._stopping = True
        self._wake.set()
        self.join(10)
        assert not self.is_alive(), "the loop did not stop within 10 s (a pump never returned)"

    def run(self) -> None:
        pub = self.pub
        pub.start_waker(self._wake.set)
        next_send = next_health = time.monotonic()
        while not self._stopping:
            now = time.monotonic()
            if now >= next_health:
                pub.send(HEALTH, json.dumps({"t": now}).encode())
                next_health = now + HEALTH_EVERY_S
            if pub.pending:
                t0 = time.perf_counter()
                pub.pump()
                self.pump_s.append(time.perf_counter() - t0)
            now = time.monotonic()
            if now >= next_send:
                self.seq += 1
                pub.send(RANGE, b'{"seq": %d}' % self.seq)
                next_send += PERIOD_S
            left = min(next_send, next_health) - time.monotonic()
            if left > 0:
                self._wake.wait(left)
                self._wake.clear()


@dataclass
class Figures:
    """What one attack did to the publisher and the honest subscriber."""

    published: int = 0
    received: int = 0
    missing: int = 0
    range_repeats: int = 0  # range messages received more than once (cache replays)
    most_repeats: int = 0  # most times one range message arrived
    health_received: int = 0  # the one health message, live once, then replayed
    late_join_s: float | None = None
    pumps: int = 0
    pump_max_ms: float = 0.0
    pump_p99_ms: float = 0.0
    rss_growth_mib: float = 0.0
    fd_growth_max: int = 0
    peers_max: int = 0
    aborted: str = ""
    attacker: dict[str, int] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)

    def line(self) -> str:
        return " ".join(f"{k}={v}" for k, v in vars(self).items())


class Honest:
    """A plain SUB on ``range/`` and ``health/`` that keeps every message it gets."""

    def __init__(self, ctx: zmq.Context[zmq.Socket[bytes]], endpoint: str, prefixes: list[bytes]):
        self.sock = ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RCVHWM, 100_000)  # a stalled test thread must not cause a gap
        for p in prefixes:
            self.sock.setsockopt(zmq.SUBSCRIBE, p)
        self.sock.connect(endpoint)
        self.seqs: list[int] = []
        self.health: list[bytes] = []

    def take(self, timeout_s: float) -> bool:
        """Receive what arrives within ``timeout_s``; True when anything came."""
        got = False
        if not self.sock.poll(int(timeout_s * 1000)):
            return False
        while True:
            try:
                topic, payload = self.sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return got
            got = True
            if topic == RANGE:
                self.seqs.append(json.loads(payload)["seq"])
            else:
                self.health.append(payload)


def _attacker(
    kind: str, endpoint: str, seconds: float, arg: str, source_ip: str
) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, __file__, kind, endpoint, str(seconds), arg, source_ip],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def run_attack(
    endpoint: str,
    kind: str,
    arg: str = "",
    make: Callable[[str], Publisher] = Publisher,
    attack_s: float = ATTACK_S,
    source_ip: str = ATTACKER_IP,
    late_wait_s: float = 0.5,
) -> Figures:
    """Publish, join an honest subscriber, run the attacker for ``attack_s`` from
    ``source_ip`` (TCP) while a second subscriber joins half-way, give that one up to
    ``late_wait_s`` more after the attack, and measure."""
    fig = Figures()
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    pub = make(endpoint)
    loop = Loop(pub)
    honest = Honest(ctx, endpoint, [b"range/", b"health/"])
    late: Honest | None = None
    proc: subprocess.Popen[bytes] | None = None
    try:
        loop.start()
        deadline = time.monotonic() + JOIN_TIMEOUT_S
        while not honest.seqs:
            assert time.monotonic() < deadline, "the honest subscriber never joined"
            honest.take(0.1)
        honest.take(0.3)
        rss0, fds0 = _rss_mib(), _open_fds()
        proc = _attacker(kind, endpoint, attack_s, arg, source_ip)
        started = time.monotonic()
        late_at = started + attack_s / 2
        late_joined = 0.0
        while proc.poll() is None:
            honest.take(0.02)
            now = time.monotonic()
            growth = _rss_mib() - rss0
            fig.rss_growth_mib = max(fig.rss_growth_mib, growth)
            fig.fd_growth_max = max(fig.fd_growth_max, _open_fds() - fds0)
            fig.peers_max = max(fig.peers_max, getattr(pub, "peers", 0))
            if late is None and now >= late_at:
                late = Honest(ctx, endpoint, [b"health/"])
                late_joined = now
            if late is not None and fig.late_join_s is None and late.take(0):
                fig.late_join_s = time.monotonic() - late_joined
            if growth > RSS_ABORT_MIB:
                fig.aborted = f"RSS grew by {growth:.0f} MiB"
                break
            if now > started + attack_s + 10:
                fig.aborted = "the attacker did not stop"
                break
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate(timeout=10)
        if proc.returncode == 0 and out.strip():
            fig.attacker = json.loads(out.decode().strip().splitlines()[-1])
        elif not fig.aborted:
            fig.aborted = f"attacker exit {proc.returncode}: {err.decode()[-500:]}"
        end = time.monotonic() + late_wait_s
        while time.monotonic() < end:
            honest.take(0.05)
            if late is not None and fig.late_join_s is None and late.take(0):
                fig.late_join_s = time.monotonic() - late_joined
            if fig.late_join_s is not None and now + 0.5 < time.monotonic():
                break
        loop.stop()
        last = loop.seq
        end = time.monotonic() + 3.0
        while (not honest.seqs or honest.seqs[-1] < last) and time.monotonic() < end:
            honest.take(0.05)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if loop.is_alive():
            loop.stop()
        honest.sock.close()
        if late is not None:
            late.sock.close()
        ctx.term()
        for name in (
            "sent",
            "subscriptions",
            "replays",
            "junk_frames",
            "refused_peers",
            "flooding_peers",
            "dropped_sends",
        ):
            if hasattr(pub, name):
                fig.counters[name] = getattr(pub, name)
        pub.close()
    first = honest.seqs[0]
    fig.published = loop.seq - first + 1
    fig.received = len(set(honest.seqs))
    fig.missing = len(set(range(first, loop.seq + 1)) - set(honest.seqs))
    counts = Counter(honest.seqs)
    fig.range_repeats = len(honest.seqs) - fig.received
    fig.most_repeats = max(counts.values())
    fig.health_received = len(honest.health)
    fig.pumps = len(loop.pump_s)
    if loop.pump_s:
        ordered = sorted(loop.pump_s)
        fig.pump_max_ms = round(ordered[-1] * 1000, 3)
        fig.pump_p99_ms = round(ordered[int(len(ordered) * 0.99)] * 1000, 3)
    fig.rss_growth_mib = round(fig.rss_growth_mib, 1)
    return fig


def assert_honest_kept(fig: Figures, attack_s: float = ATTACK_S, late_join: bool = True) -> None:
    """What every attack must leave intact. ``late_join``: the subscriber joining
    mid-attack is served at once (not when the attack holds every connection slot)."""
    print(fig.line())
    assert not fig.aborted, fig.aborted
    assert fig.missing == 0, f"{fig.missing} of {fig.published} messages never arrived"
    replays_max = int(attack_s / publisher_module.REPLAY_INTERVAL_S) + 3
    assert fig.range_repeats <= replays_max, f"{fig.range_repeats} repeated range messages"
    assert fig.most_repeats <= 2, f"one range message arrived {fig.most_repeats} times"
    assert fig.health_received <= 1 + replays_max, f"health arrived {fig.health_received} times"
    assert fig.pump_max_ms <= PUMP_LIMIT_S * 1000, f"a pump took {fig.pump_max_ms} ms"
    assert fig.rss_growth_mib < RSS_LIMIT_MIB, f"RSS grew by {fig.rss_growth_mib} MiB"
    assert fig.late_join_s is not None, "a subscriber joining mid-attack got no cached health"
    assert not late_join or fig.late_join_s < LATE_JOIN_LIMIT_S, (
        f"the cached health took {fig.late_join_s} s"
    )


@pytest.fixture
def tcp_endpoint() -> Iterator[str]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    yield f"tcp://127.0.0.1:{port}"


def test_xsub_subscribing_as_fast_as_it_can(tcp_endpoint: str) -> None:
    """A zmq.XSUB repeating ``b"\\x01range/tfluna"``: it is disconnected as a flood,
    and honest subscribers get a replay at most every ``REPLAY_INTERVAL_S``."""
    fig = run_attack(tcp_endpoint, "xsub")
    assert_honest_kept(fig)
    assert fig.counters["flooding_peers"] >= 1


def test_raw_subscription_flood_over_tcp(tcp_endpoint: str) -> None:
    """A raw ZMTP peer writing subscriptions as fast as the socket takes them,
    reconnecting each time it is cut off."""
    fig = run_attack(tcp_endpoint, "subscribe")
    assert_honest_kept(fig)
    assert fig.counters["flooding_peers"] >= 1


def test_frames_that_are_not_subscriptions_over_ipc(tmp_path: Path) -> None:
    """``b"\\x07hello"`` repeated over ipc: dropped one receive each, never answered;
    the flood check works on a unix socket too."""
    fig = run_attack(f"ipc://{tmp_path}/p.sock", "junk")
    assert_honest_kept(fig)
    assert fig.counters["replays"] <= fig.counters["subscriptions"]
    assert fig.counters["flooding_peers"] >= 1


def test_a_one_megabyte_topic_ends_the_connection(tcp_endpoint: str) -> None:
    """A 1 MB subscription frame, over and over on new connections: ``ZMQ_MAXMSGSIZE``
    drops each connection before libzmq allocates the frame."""
    fig = run_attack(tcp_endpoint, "big", "1000000")
    assert_honest_kept(fig)
    assert fig.attacker["connections"] >= 2
    assert fig.rss_growth_mib < 5


@pytest.mark.parametrize("length", [20, 120])
def test_ten_thousand_distinct_topics(tcp_endpoint: str, length: int) -> None:
    """10 000 distinct random topics (20 bytes, or 120, about the longest a frame may
    be), again on each new connection: libzmq would store each in its trie (about 1.2
    and 6 KiB); the peer is cut as a flood long before, and kept out for a while."""
    fig = run_attack(tcp_endpoint, "distinct", str(length))
    assert_honest_kept(fig)
    assert fig.counters["subscriptions"] < 10_000  # never all of them in libzmq's trie


def test_distinct_topics_slowly_enough_never_to_be_behind(tcp_endpoint: str) -> None:
    """2000 distinct random 120-byte topics a second, in 10 ms batches: the socket
    never backs up, but the peer's bytes while such topics come are counted
    (``FOREIGN_BYTES_MAX``), and it is cut after about 130 topics, again on each new
    connection; unchecked, libzmq's trie would grow by some 12 MiB a second."""
    fig = run_attack(tcp_endpoint, "trickle", "2000")
    assert_honest_kept(fig)
    assert fig.counters["flooding_peers"] >= 1
    per_connection = fig.counters["subscriptions"] / fig.attacker["connections"]
    assert per_connection < 2 * publisher_module.FOREIGN_BYTES_MAX / 122


def test_two_hundred_connections(tcp_endpoint: str) -> None:
    """200 connections that complete the ZMTP handshake and stay: at most
    ``MAX_PEERS`` are served, the rest shut down as they come, and the honest
    subscriber (connected first) keeps every message."""
    fig = run_attack(tcp_endpoint, "connections", "200")
    assert_honest_kept(fig, late_join=False)  # peer 201: it gets in once the attack ends
    cap = publisher_module.MAX_PEERS
    assert fig.peers_max <= cap
    assert fig.attacker["held"] <= cap  # the attacker's view: connections still open
    assert fig.counters["refused_peers"] >= 200 - cap
    assert fig.fd_growth_max < cap + 64, f"{fig.fd_growth_max} descriptors more at the peak"


def test_a_flooder_on_the_subscribers_own_address(tcp_endpoint: str) -> None:
    """The flooder shares 127.0.0.1 with the honest subscribers: the one already
    connected keeps every message; the one joining mid-attack is refused while the
    address is penalized, and gets in within ``FLOOD_PENALTY_S`` after the attack."""
    penalty_s = publisher_module.FLOOD_PENALTY_S
    fig = run_attack(tcp_endpoint, "subscribe", source_ip="127.0.0.1", late_wait_s=penalty_s + 2.0)
    assert_honest_kept(fig, late_join=False)
    assert fig.counters["refused_peers"] >= 1
    assert fig.late_join_s is not None
    assert fig.late_join_s < ATTACK_S / 2 + penalty_s + 2.0


def test_subscribers_joining_inside_the_replay_interval(tcp_endpoint: str) -> None:
    """Without an attack: three subscribers joining 0.1 s apart all get the cached
    health; the later two from one deferred replay, so the first sees it twice, not
    three times, and the second once."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    pub = Publisher(tcp_endpoint)
    loop = Loop(pub)
    subs: list[Honest] = []
    try:
        loop.start()
        for _ in range(3):
            subs.append(Honest(ctx, tcp_endpoint, [b"health/"]))
            time.sleep(0.1)
        deadline = time.monotonic() + 3.0
        while not all(s.health for s in subs) and time.monotonic() < deadline:
            for s in subs:
                s.take(0.02)
        for s in subs:
            s.take(0.2)
    finally:
        loop.stop()
        for s in subs:
            s.sock.close()
        ctx.term()
        pub.close()
    assert [len(s.health) for s in subs] == [2, 1, 1]


# -- the attacker, run as a child process --------------------------------------------

ATTACKS = ("xsub", "subscribe", "junk", "big", "distinct", "trickle", "connections")


def _zmtp_hello() -> bytes:
    """A ZMTP 3.0 NULL greeting and READY as an XSUB (RFC 23)."""
    greeting = b"\xff" + bytes(8) + b"\x7f" + b"\x03\x00" + b"NULL".ljust(20, b"\0") + bytes(32)
    body = b"\x05READY\x0bSocket-Type" + (4).to_bytes(4, "big") + b"XSUB"
    return greeting + b"\x04" + bytes([len(body)]) + body


def _frame(body: bytes) -> bytes:
    """One ZMTP message frame, short or long form."""
    if len(body) < 256:
        return bytes([0, len(body)]) + body
    return b"\x02" + len(body).to_bytes(8, "big") + body


def _read_exactly(s: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        got = s.recv(n - len(data))
        if not got:
            raise ConnectionResetError("closed during the handshake")
        data += got
    return data


@dataclass
class _Target:
    """Where the attacker connects, and from which address (TCP)."""

    endpoint: str
    source_ip: str

    def connect(self) -> socket.socket:
        """A raw connection through the ZMTP handshake, as an XSUB."""
        if self.endpoint.startswith("tcp://"):
            host, port = self.endpoint.removeprefix("tcp://").rsplit(":", 1)
            s = socket.create_connection(
                (host, int(port)), timeout=2, source_address=(self.source_ip, 0)
            )
        else:
            s = socket.socket(socket.AF_UNIX)
            s.settimeout(2)
            s.connect(self.endpoint.removeprefix("ipc://"))
        s.sendall(_zmtp_hello())
        _read_exactly(s, 64)  # the publisher's greeting, then its READY command
        flags, size = _read_exactly(s, 2)
        _read_exactly(s, size if flags == 0x04 else int.from_bytes(_read_exactly(s, 7), "big"))
        return s  # libzmq takes a message sent before its own READY for a bad command

    def flood(self, until: float, chunk: bytes, stats: Counter[str]) -> None:
        """Write ``chunk`` over and over, reconnecting whenever the publisher cuts us off."""
        while time.monotonic() < until:
            try:
                s = self.connect()
            except OSError:
                stats["refused"] += 1
                time.sleep(0.01)
                continue
            stats["connections"] += 1
            s.settimeout(0.2)
            try:
                while time.monotonic() < until:
                    try:
                        stats["bytes"] += s.send(chunk)
                    except TimeoutError:
                        continue
            except OSError:
                stats["cut"] += 1
            finally:
                s.close()


def _attack(kind: str, target: _Target, seconds: float, arg: str) -> dict[str, int]:
    until = time.monotonic() + seconds
    stats: Counter[str] = Counter()
    if kind == "xsub":
        ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        x = ctx.socket(zmq.XSUB)
        x.setsockopt(zmq.LINGER, 0)
        x.connect(target.endpoint.replace("tcp://", f"tcp://{target.source_ip}:0;"))
        msgs = (b"\x01" + RANGE, b"\x01" + HEALTH)
        while time.monotonic() < until:
            for _ in range(1000):
                x.send(msgs[stats["frames"] & 1])
                stats["frames"] += 1
        x.close()
        ctx.term()
    elif kind == "subscribe":
        target.flood(until, _frame(b"\x01" + RANGE) * 4096, stats)
    elif kind == "junk":
        target.flood(until, _frame(b"\x07hello") * 8192, stats)
    elif kind == "big":
        target.flood(until, _frame(b"\x01" + b"x" * int(arg)), stats)
    elif kind == "distinct":
        topics = b"".join(_frame(b"\x01" + os.urandom(int(arg))) for _ in range(10_000))
        while time.monotonic() < until:  # all 10 000 again on each new connection
            try:
                s = target.connect()
            except OSError:
                stats["refused"] += 1
                time.sleep(0.01)
                continue
            stats["connections"] += 1
            try:
                s.sendall(topics)
                s.settimeout(max(0.01, until - time.monotonic()))
                while s.recv(65536):  # the topics stay subscribed while it is open
                    pass
                stats["cut"] += 1
            except TimeoutError:
                pass
            except OSError:
                stats["cut"] += 1
            finally:
                s.close()
    elif kind == "trickle":  # distinct 120-byte topics, ARG a second, never behind
        rate = int(arg)
        while time.monotonic() < until:
            try:
                s = target.connect()
            except OSError:
                stats["refused"] += 1
                time.sleep(0.01)
                continue
            stats["connections"] += 1
            try:
                while time.monotonic() < until:
                    s.sendall(
                        b"".join(_frame(b"\x01" + os.urandom(120)) for _ in range(rate // 100))
                    )
                    stats["frames"] += rate // 100
                    time.sleep(0.01)
            except OSError:
                stats["cut"] += 1
            finally:
                s.close()
    elif kind == "connections":
        held = []
        for _ in range(int(arg)):
            try:
                held.append(target.connect())
            except OSError:
                stats["refused"] += 1
        stats["connections"] = len(held)
        time.sleep(max(0.0, until - time.monotonic()))
        for s in held:  # still open when a read would block; b"" or an error: cut
            s.setblocking(False)
            try:
                while s.recv(65536):
                    pass
            except BlockingIOError:
                stats["held"] += 1
            except OSError:
                pass
            s.close()
    else:
        raise SystemExit(f"unknown attack {kind!r}; one of {', '.join(ATTACKS)}")
    return dict(stats)


if __name__ == "__main__":
    args = [*sys.argv[1:], "", ATTACKER_IP][:5]
    kind, endpoint, seconds, arg, source_ip = args
    print(json.dumps(_attack(kind, _Target(endpoint, source_ip), float(seconds), arg)))
