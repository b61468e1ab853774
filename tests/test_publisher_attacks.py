"""The publisher against peers that are not honest subscribers.

Two sets of tests play the same attacks. The attacker always runs in a child process:
this file run as a script, speaking ZMTP 3.0 NULL on a raw socket, or a ``zmq.XSUB``.

- In this process: a real ``Publisher`` with a loop thread that drives it as ``lunad
  serve`` does (a ``range`` message every 4 ms, ``pump`` when ``pending`` is set, the
  waker waking it) and a real ZeroMQ SUB as the honest subscriber. They assert the
  mechanisms, from the publisher's own counters: every message published after the
  subscriber joined arrives, with no ``seq`` gap; each cached message reaches it at
  most a few times; no ``pump`` call takes long; the process's resident memory grows
  by less than ``RSS_LIMIT_MIB``; the flood, cap and penalty counters moved.
- Against the daemon (``test_lunad_serve_keeps_its_targets_under_attack``): a real
  ``lunad serve`` subprocess reading the virtual sensor on a pty at 250 Hz, with a
  ``NOTIFY_SOCKET`` and ``WATCHDOG_USEC`` as systemd gives it. They assert issue #21's
  targets from outside, as an operator would see them: every frame the sensor sent
  reaches the honest subscriber with no ``seq`` gap, the daemon's VmRSS grows by less
  than ``RSS_LIMIT_MIB``, SIGTERM at the end of the attack (the attacker still at it)
  ends it within ``STOP_LIMIT_S``, and watchdog pings are never more than
  ``WATCHDOG_GAP_LIMIT_S`` apart.

Environment:

- ``LUNAD_ATTACK_S``: how long each attack plays, seconds (default 2, to keep CI
  short; issue #21 asks for 10). Set, it also plays all ten attacks against the
  daemon, where the default run plays four (``DEFAULT_RUN_ATTACKS``).
- ``LUNAD_ATTACK_REPORT``: a file to which each daemon test appends its figures as
  one JSON line (``DaemonFigures``), before asserting, so a failed target is reported
  too. A report, not an assertion.

Run by hand, ``python tests/test_publisher_attacks.py KIND ENDPOINT SECONDS [ARG
[SOURCE_IP]]`` attacks an endpoint (``KIND`` is one of ``ATTACKS``) and prints what it
did as JSON; SIGTERM ends it early, still printing.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zmq

from lunad.daemon import publisher as publisher_module
from lunad.daemon.publisher import Publisher
from lunad.sim.physics import Truth
from lunad.sim.pty_device import PtyDevice

RANGE = b"range/tfluna"
HEALTH = b"health/tfluna"
PERIOD_S = 0.004  # one range message every 4 ms, the TF-Luna's 250 Hz
HEALTH_EVERY_S = 30.0
"""The loop's health interval, seconds: longer than a test, so a health message that
reaches a subscriber after the first can only be the last-value cache's."""
ATTACK_S_ENV = "LUNAD_ATTACK_S"
REPORT_ENV = "LUNAD_ATTACK_REPORT"


def _attack_seconds() -> float:
    """``LUNAD_ATTACK_S``, else 2 s: long enough for every mechanism to act (the flood
    penalty is 1 s, the replay interval 0.5 s), short enough for CI. At least 1 s, so
    that the attacker child is past its imports, and its SIGTERM handler, when the
    daemon tests stop it."""
    text = os.environ.get(ATTACK_S_ENV, "2")
    try:
        seconds = float(text)
    except ValueError:
        raise ValueError(f"{ATTACK_S_ENV}={text!r} is not a number of seconds") from None
    if not 1.0 <= seconds <= 600.0:
        raise ValueError(f"{ATTACK_S_ENV}={text!r}: give 1 to 600 seconds")
    return seconds


ATTACK_S = _attack_seconds()  # how long each attacker runs
RSS_LIMIT_MIB = 20.0  # growth of VmRSS (this process's, or the daemon's) over an attack
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


def _rss_mib(pid: int | str = "self") -> float:
    """The resident set size of process ``pid`` (this one by default), MiB."""
    rss = _rss_of(pid)
    if rss is None:
        raise AssertionError(f"no VmRSS for process {pid}")
    return rss


def _rss_of(pid: int | str) -> float | None:
    """The resident set size of ``pid``, MiB, or None once it has exited (a zombie's
    status has no VmRSS line)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except FileNotFoundError:
        pass
    return None


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
            if topic.startswith(b"range/"):  # the daemon's topics end in "/"
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


@pytest.mark.parametrize("transport", ["tcp", "ipc"])
def test_distinct_topics_slowly_enough_never_to_be_behind(
    tcp_endpoint: str, tmp_path: Path, transport: str
) -> None:
    """2000 distinct random 120-byte topics a second, in 10 ms batches: the socket
    never backs up, but the peer's bytes while such topics come are counted
    (``FOREIGN_BYTES_MAX``: TCP_INFO over TCP, each frame's ZAP user id over ipc), and
    it is cut after about 130 topics, again on each new connection; unchecked,
    libzmq's trie would grow by some 12 MiB a second."""
    endpoint = tcp_endpoint if transport == "tcp" else f"ipc://{tmp_path}/p.sock"
    fig = run_attack(endpoint, "trickle", "2000")
    assert_honest_kept(fig)
    assert fig.counters["flooding_peers"] >= 1
    per_connection = fig.counters["subscriptions"] / fig.attacker["connections"]
    assert per_connection < 2 * publisher_module.FOREIGN_BYTES_MAX / 122


def test_two_hundred_connections(tcp_endpoint: str, caplog: pytest.LogCaptureFixture) -> None:
    """200 connections that complete the ZMTP handshake and stay: at most
    ``MAX_PEERS`` are served, the rest shut down as they come, and the honest
    subscriber (connected first) keeps every message. The log says so, once a
    ``PEER_REFUSAL_LOG_INTERVAL_S``: a subscriber turned away is told nothing."""
    caplog.set_level(logging.WARNING, logger="lunad.daemon.publisher")
    fig = run_attack(tcp_endpoint, "connections", "200")
    said = [r.getMessage() for r in caplog.records if "at once since the last" in r.getMessage()]
    assert said and f"past the {publisher_module.MAX_PEERS} it serves at once" in said[0]
    assert len(said) <= 1 + ATTACK_S / publisher_module.PEER_REFUSAL_LOG_INTERVAL_S
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


# -- the same attacks against `lunad serve` --------------------------------------------

SENSOR_HZ = 250  # the TF-Luna's fastest rate, which issue #21's targets are set for
STOP_LIMIT_S = 2.0
"""SIGTERM to exit, seconds: systemd's stop, or a restart, must not wait on peers."""
WATCHDOG_USEC = 1_000_000
"""Given to the daemon as systemd would for ``WatchdogSec=1``: it pings every 0.5 s."""
WATCHDOG_GAP_LIMIT_S = 1.0
"""Longest time between two pings, seconds: past it, a ``WatchdogSec=1`` unit would be
killed. The unit has ``WatchdogSec=10``; 1 s is issue #21's target."""
STOP_WAIT_S = 10.0  # how long to wait for the exit before killing (the limit is asserted)
DRAIN_TIMEOUT_S = 15.0
"""After the sensor went quiet, how long the honest subscriber may take to get the last
frame: a shared machine can stall the daemon or this process for seconds."""
ATTACKER_SPARE_S = 60.0
"""The attacker is started for ``ATTACK_S`` plus this, and stopped by SIGTERM once the
daemon has exited, so the attack lasts through the drain and the daemon's stop."""
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; Python does not export it
_TIMESPEC = struct.Struct("@ll")  # struct timespec: seconds, nanoseconds


@dataclass(frozen=True)
class Attack:
    """One attack as the daemon tests play it: ``kind`` and ``arg`` for the attacker
    child, from ``source_ip`` (TCP), on a ``tcp`` or ``ipc`` endpoint."""

    name: str
    kind: str
    arg: str = ""
    source_ip: str = ATTACKER_IP
    transport: str = "tcp"


DAEMON_ATTACKS = (
    Attack("xsub", "xsub"),
    Attack("subscribe", "subscribe"),
    Attack("junk-ipc", "junk", transport="ipc"),
    Attack("big-1MB", "big", "1000000"),
    Attack("distinct-20", "distinct", "20"),
    Attack("distinct-120", "distinct", "120"),
    Attack("trickle-2000", "trickle", "2000"),
    Attack("trickle-2000-ipc", "trickle", "2000", transport="ipc"),
    Attack("connections-200", "connections", "200"),
    Attack("subscribe-own-address", "subscribe", source_ip="127.0.0.1"),
)
"""The attacks of the in-process tests above, one each."""
DEFAULT_RUN_ATTACKS = ("xsub", "big-1MB", "junk-ipc", "connections-200")
"""Those played against the daemon in the default run, one per resource an attacker
goes for: the read loop (a subscription flood), memory (1 MB topics), the ipc path,
and descriptors (200 connections). The in-process tests above play all of them every
time; with ``LUNAD_ATTACK_S`` set (the long run, 10 s each) the daemon gets all ten."""
DAEMON_RUN = tuple(
    a for a in DAEMON_ATTACKS if ATTACK_S_ENV in os.environ or a.name in DEFAULT_RUN_ATTACKS
)


@dataclass
class DaemonFigures:
    """What one attack did to ``lunad serve`` and its honest subscriber: issue #21's
    closing-note figures, one JSON line each in ``LUNAD_ATTACK_REPORT``."""

    attack: str
    transport: str
    attack_s: float  # LUNAD_ATTACK_S: the window before the sensor goes quiet
    duration_s: float = 0.0  # the attacker's own time, start to its SIGTERM
    sensor_frames: int = 0  # sent by the sensor from the honest subscriber's first frame on
    sensor_frames_attack: int = 0  # of which sent during the attack window
    received: int = 0  # distinct seqs the honest subscriber got, of sensor_frames
    seq_missing: int = 0
    seq_gaps: int = 0  # runs of missing seqs
    duplicates: int = 0  # range messages received more than once (cache replays)
    most_repeats: int = 0  # most times one range message arrived
    rss_before_mib: float = 0.0
    rss_after_mib: float = 0.0  # at the end, just before SIGTERM
    rss_max_mib: float = 0.0  # sampled about every 20 ms
    rss_growth_mib: float = 0.0  # max less before
    sigterm_exit_s: float | None = None
    exit_code: int | None = None
    watchdog_pings: int = 0  # from the last one before the attack to SIGTERM
    watchdog_max_s: float | None = None  # longest time without a ping, up to SIGTERM
    aborted: str = ""
    attacker: dict[str, int] = field(default_factory=dict)

    def line(self) -> str:
        return " ".join(f"{k}={v}" for k, v in vars(self).items())


class NotifyListener:
    """The daemon's ``NOTIFY_SOCKET``: a datagram socket bound in ``tmp_path``, as
    systemd binds it. Each datagram keeps the kernel's receive time
    (``SO_TIMESTAMPNS``, the daemon's send time on a unix socket), so a stall in this
    busy process cannot stretch, or shrink, the gaps measured between pings."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.bind(str(path))
        self.sock.setblocking(False)
        self.path = path
        self.got: list[tuple[float, str]] = []  # (time.time() of the send, datagram)
        self.unstamped = 0

    def drain(self) -> None:
        """Take every datagram waiting."""
        while True:
            try:
                data, ancillary, _, _ = self.sock.recvmsg(4096, socket.CMSG_SPACE(_TIMESPEC.size))
            except BlockingIOError:
                return
            stamp = None
            for level, kind, cdata in ancillary:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                    sec, nsec = _TIMESPEC.unpack(cdata[: _TIMESPEC.size])
                    stamp = sec + nsec / 1e9
            if stamp is None:
                self.unstamped += 1
                stamp = time.time()
            self.got.append((stamp, data.decode(errors="replace")))

    def pings(self) -> list[float]:
        return [t for t, m in self.got if m == "WATCHDOG=1"]

    def close(self) -> None:
        self.sock.close()


def _longest_silence(pings: list[float], start: float, end: float) -> tuple[int, float | None]:
    """Pings from the last one before ``start`` to ``end``, and the longest time between
    two of them or from the last to ``end`` (a loop that wedged just before ``end``
    counts); None when there was no ping at all."""
    before = [t for t in pings if t <= start]
    inside = [t for t in pings if start < t <= end]
    window = before[-1:] + inside
    if not window:
        return 0, None
    gaps = [b - a for a, b in itertools.pairwise(window)] + [end - window[-1]]
    return len(window), max(gaps)


def _seq_runs(first: int, last: int, seqs: list[int]) -> tuple[int, int]:
    """Missing seqs in ``first..last`` and the runs they form."""
    got = set(seqs)
    missing = [s for s in range(first, last + 1) if s not in got]
    runs = sum(1 for a, b in itertools.pairwise([first - 2, *missing]) if b != a + 1)
    return len(missing), runs


def _report(fig: DaemonFigures) -> None:
    """Append ``fig`` as one JSON line to ``LUNAD_ATTACK_REPORT``, when it is set."""
    path = os.environ.get(REPORT_ENV)
    if path:
        with open(path, "a") as f:
            f.write(json.dumps(vars(fig)) + "\n")


def run_daemon_attack(
    attack: Attack,
    tmp_path: Path,
    device: Callable[..., PtyDevice],
    start_daemon: Callable[..., Any],
) -> tuple[DaemonFigures, str]:
    """Start the sensor and ``lunad serve``, join an honest subscriber, attack for
    ``ATTACK_S``, then quiet the sensor, wait for its last frame, SIGTERM the daemon
    while the attacker still runs, and stop the attacker. Returns the figures and the
    daemon's log."""
    fig = DaemonFigures(attack.name, attack.transport, ATTACK_S)
    if attack.transport == "tcp":
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            endpoint = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    else:
        endpoint = f"ipc://{tmp_path}/p.sock"
    notify = NotifyListener(tmp_path / "notify.sock")
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    honest: Honest | None = None
    proc: subprocess.Popen[bytes] | None = None
    d: Any = None
    try:
        # the daemon turns output on, as on a real sensor; the quiet room of test_serve
        dev = device(rate_hz=SENSOR_HZ, truth=Truth(2.0, 0.8, 10.0, 100.0), output_enabled=False)
        env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": str(WATCHDOG_USEC)}
        d = start_daemon(
            "--device", dev.path, "--publish", endpoint, "--rate", str(SENSOR_HZ), env=env
        )
        pid = d.proc.pid
        honest = sub = Honest(ctx, endpoint, [b"range/"])
        deadline = time.monotonic() + 30.0  # conftest's STARTUP_S: a loaded CI machine
        while not honest.seqs or "READY=1" not in (m for _, m in notify.got):
            assert d.proc.poll() is None, f"the daemon exited with {d.proc.returncode}"
            assert time.monotonic() < deadline, "no READY=1 and first frame within 30 s"
            honest.take(0.1)
            notify.drain()
        honest.take(0.3)
        rss0 = fig.rss_max_mib = _rss_mib(pid)
        fig.rss_before_mib = round(rss0, 1)
        frames0 = dev.frames_sent
        attack_wall = time.time()
        proc = attacker = _attacker(
            attack.kind, endpoint, ATTACK_S + ATTACKER_SPARE_S, attack.arg, attack.source_ip
        )
        assert attacker.stdout is not None
        ready, _, _ = select.select([attacker.stdout], [], [], 10.0)
        assert ready, "the attacker did not start within 10 s"
        line = attacker.stdout.readline()
        assert line == b"started\n", f"the attacker did not start: {line!r}"
        started = time.monotonic()

        def watch(until: float, done: Callable[[], bool]) -> bool:
            """Read, sample and check until ``until`` or ``done()``; False on abort."""
            while time.monotonic() < until and not done():
                sub.take(0.02)
                notify.drain()
                rss = _rss_of(pid)
                if rss is not None:
                    fig.rss_max_mib = max(fig.rss_max_mib, rss)
                if d.proc.poll() is not None:
                    fig.aborted = f"the daemon exited with {d.proc.returncode} during the attack"
                elif attacker.poll() is not None:
                    fig.aborted = f"the attacker ended early: {attacker.returncode}"
                elif fig.rss_max_mib - rss0 > RSS_ABORT_MIB:
                    fig.aborted = f"the daemon grew by {fig.rss_max_mib - rss0:.0f} MiB"
                if fig.aborted:
                    return False
            return True

        if watch(started + ATTACK_S, lambda: False):
            dev.pause(3600)
            time.sleep(0.1)  # a frame the device was writing when paused
            last = dev.frames_sent - 1
            fig.sensor_frames_attack = dev.frames_sent - frames0
            watch(time.monotonic() + DRAIN_TIMEOUT_S, lambda: max(sub.seqs) >= last)
            rss1 = _rss_mib(pid)
            fig.rss_max_mib = max(fig.rss_max_mib, rss1)
            fig.rss_after_mib = round(rss1, 1)
            first = honest.seqs[0]
            fig.sensor_frames = last - first + 1
            fig.received = len({s for s in honest.seqs if s <= last})
            fig.seq_missing, fig.seq_gaps = _seq_runs(first, last, honest.seqs)
            fig.duplicates = len(honest.seqs) - len(set(honest.seqs))
            fig.most_repeats = max(Counter(honest.seqs).values())
            if not fig.aborted:
                term_wall = time.time()
                t0 = time.monotonic()
                d.proc.send_signal(signal.SIGTERM)
                try:
                    fig.exit_code = d.proc.wait(timeout=STOP_WAIT_S)
                    fig.sigterm_exit_s = round(time.monotonic() - t0, 3)
                except subprocess.TimeoutExpired:
                    fig.aborted = f"the daemon had not exited {STOP_WAIT_S} s after SIGTERM"
                notify.drain()
                fig.watchdog_pings, longest = _longest_silence(
                    notify.pings(), attack_wall, term_wall
                )
                fig.watchdog_max_s = None if longest is None else round(longest, 3)
        fig.rss_max_mib = round(fig.rss_max_mib, 1)
        fig.rss_growth_mib = round(fig.rss_max_mib - rss0, 1)
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
        fig.duration_s = round(time.monotonic() - started, 2)
        if proc.returncode == 0 and out.strip():
            fig.attacker = json.loads(out.decode().strip().splitlines()[-1])
            fig.duration_s = fig.attacker.get("elapsed_ms", 0) / 1000
        elif not fig.aborted:
            fig.aborted = f"attacker exit {proc.returncode}: {err.decode()[-500:]}"
        assert notify.unstamped == 0, "the kernel gave no SO_TIMESTAMPNS: gaps unmeasured"
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if honest is not None:
            honest.sock.close()
        ctx.term()
        notify.close()
    log = d.log if d is not None else ""
    if d is not None:
        d.stop(signal.SIGKILL)  # closes its log; a no-op once it has exited
    return fig, log


@pytest.mark.parametrize("attack", DAEMON_RUN, ids=lambda a: a.name)
def test_lunad_serve_keeps_its_targets_under_attack(
    attack: Attack,
    tmp_path: Path,
    device: Callable[..., PtyDevice],
    start_daemon: Callable[..., Any],
) -> None:
    """Issue #21's targets, for each attack, on the real daemon at 250 Hz: the honest
    subscriber (connected before the attack) gets every frame the sensor sent from its
    first one on, with no ``seq`` gap; the daemon's VmRSS grows by under
    ``RSS_LIMIT_MIB``; SIGTERM, sent while the attacker is still at it, ends the
    daemon with code 0 within ``STOP_LIMIT_S``; watchdog pings are never more than
    ``WATCHDOG_GAP_LIMIT_S`` apart."""
    fig, log = run_daemon_attack(attack, tmp_path, device, start_daemon)
    _report(fig)
    print(fig.line())
    ok = (
        not fig.aborted
        and fig.seq_missing == 0
        and fig.rss_growth_mib < RSS_LIMIT_MIB
        and fig.exit_code == 0
        and fig.sigterm_exit_s is not None
        and fig.sigterm_exit_s < STOP_LIMIT_S
        and fig.watchdog_max_s is not None
        and fig.watchdog_max_s <= WATCHDOG_GAP_LIMIT_S
        and "stopped:" in log
        and "Traceback" not in log
    )
    if not ok:
        print("daemon log (end):\n" + log[-3000:])
    assert not fig.aborted, fig.aborted
    assert fig.attacker.get("connections", 0) + fig.attacker.get("frames", 0) > 0, (
        f"the attacker did nothing: {fig.attacker}"
    )
    assert fig.sensor_frames_attack > ATTACK_S * SENSOR_HZ / 2, (
        f"the sensor sent {fig.sensor_frames_attack} frames in {ATTACK_S} s: no 250 Hz stream"
    )
    assert fig.seq_missing == 0, (
        f"{fig.seq_missing} of {fig.sensor_frames} frames never arrived ({fig.seq_gaps} gaps)"
    )
    replays_max = int(fig.duration_s / publisher_module.REPLAY_INTERVAL_S) + 3  # as above
    assert fig.duplicates <= replays_max, f"{fig.duplicates} repeated range messages"
    assert fig.most_repeats <= 2, f"one range message arrived {fig.most_repeats} times"
    assert fig.rss_growth_mib < RSS_LIMIT_MIB, f"the daemon grew by {fig.rss_growth_mib} MiB"
    assert fig.exit_code == 0, f"the daemon exited with {fig.exit_code} on SIGTERM"
    assert "stopped:" in log and "Traceback" not in log, "not the orderly stop (log above)"
    assert fig.sigterm_exit_s is not None and fig.sigterm_exit_s < STOP_LIMIT_S, (
        f"SIGTERM to exit took {fig.sigterm_exit_s} s"
    )
    assert fig.watchdog_max_s is not None, "no watchdog ping at all"
    assert fig.watchdog_max_s <= WATCHDOG_GAP_LIMIT_S, (
        f"{fig.watchdog_max_s} s without a watchdog ping"
    )


# -- the attacker, run as a child process --------------------------------------------

ATTACKS = ("xsub", "subscribe", "junk", "big", "distinct", "trickle", "connections")
_stop_requested = False
"""Set by SIGTERM: the daemon tests end an attack when they have stopped the daemon
under it, not at a time fixed in advance."""


def _request_stop(_signum: int, _frame: object) -> None:
    global _stop_requested
    _stop_requested = True


def _before(until: float) -> bool:
    """The attack goes on: ``until`` is ahead and no SIGTERM came."""
    return not _stop_requested and time.monotonic() < until


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

    def sessions(self, until: float, stats: Counter[str]) -> Iterator[socket.socket]:
        """Connections one after another until ``until``, each closed when the caller
        asks for the next: a refused attempt is counted and retried after 10 ms."""
        while _before(until):
            try:
                s = self.connect()
            except OSError:
                stats["refused"] += 1
                time.sleep(0.01)
                continue
            stats["connections"] += 1
            try:
                yield s
            finally:
                s.close()

    def flood(self, until: float, chunk: bytes, stats: Counter[str]) -> None:
        """Write ``chunk`` over and over, reconnecting whenever the publisher cuts us off."""
        for s in self.sessions(until, stats):
            s.settimeout(0.2)
            try:
                while _before(until):
                    try:
                        stats["bytes"] += s.send(chunk)
                    except TimeoutError:
                        continue
            except OSError:
                stats["cut"] += 1


def _attack(kind: str, target: _Target, seconds: float, arg: str) -> dict[str, int]:
    started = time.monotonic()
    until = started + seconds
    stats: Counter[str] = Counter()
    if kind == "xsub":
        ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        x = ctx.socket(zmq.XSUB)
        x.setsockopt(zmq.LINGER, 0)
        x.connect(target.endpoint.replace("tcp://", f"tcp://{target.source_ip}:0;"))
        msgs = (b"\x01" + RANGE, b"\x01" + HEALTH)
        while _before(until):
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
        for s in target.sessions(until, stats):  # all 10 000 again on each new connection
            try:
                s.sendall(topics)
                s.settimeout(0.1)  # short, to see a SIGTERM soon
                while _before(until):  # the topics stay subscribed while it is open
                    try:
                        if not s.recv(65536):
                            stats["cut"] += 1
                            break
                    except TimeoutError:
                        continue
            except TimeoutError:
                pass
            except OSError:
                stats["cut"] += 1
    elif kind == "trickle":  # distinct 120-byte topics, ARG a second, never behind
        rate = int(arg)
        for s in target.sessions(until, stats):
            try:
                while _before(until):
                    s.sendall(
                        b"".join(_frame(b"\x01" + os.urandom(120)) for _ in range(rate // 100))
                    )
                    stats["frames"] += rate // 100
                    time.sleep(0.01)
            except OSError:
                stats["cut"] += 1
    elif kind == "connections":
        held = []
        for _ in range(int(arg)):
            try:
                held.append(target.connect())
            except OSError:
                stats["refused"] += 1
        stats["connections"] = len(held)
        while _before(until):
            time.sleep(0.05)
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
    stats["elapsed_ms"] = round((time.monotonic() - started) * 1000)
    return dict(stats)


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _request_stop)
    args = [*sys.argv[1:], "", ATTACKER_IP][:5]
    kind, endpoint, seconds, arg, source_ip = args
    print("started", flush=True)  # past the imports: the daemon tests time the attack from here
    print(json.dumps(_attack(kind, _Target(endpoint, source_ip), float(seconds), arg)))
