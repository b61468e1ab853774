"""The subscriber client against a real PUB socket: typed messages, gaps, restarts, junk."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zmq

from lunad.protocol.client import StaleStream, Subscriber
from lunad.protocol.messages import RangeMessage, encode_range, range_ident, topic

RUN = "00000000000000a1"


def msg(seq: int, sensor: str = "c", run: str = RUN, frames: int = 1) -> bytes:
    return encode_range(
        range_ident(sensor, run), seq, frames, 1, 2, 1.0, 500, 30.0, 0.25, 1.0, 0.01, 10.0,
        "ok", b"[]", "stable",
    )  # fmt: skip


@contextmanager
def publishing(ep: str, sensors: tuple[str, ...], hz: float = 200.0) -> Iterator[None]:
    """A PUB socket on ``ep`` sending each sensor's range messages, seq 0, 1, 2, ...,
    ``hz`` rounds a second from a thread, until the block ends."""
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    stop = threading.Event()

    def run() -> None:
        seq = 0
        while not stop.wait(1.0 / hz):
            for name in sensors:
                pub.send_multipart([topic("range", name), msg(seq, name)])
            seq += 1

    t = threading.Thread(target=run)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join()
        pub.close(linger=0)
        ctx.term()


def test_recv_returns_at_its_timeout_while_other_sensors_talk(tmp_path: Path) -> None:
    """Only ``frontleft`` talks: ``range/front/`` matches none of its messages, and the
    wait for ``front`` ends at its timeout, or robot code blocks forever."""
    ep = f"ipc://{tmp_path}/o.sock"
    returned: list[object] = []
    with publishing(ep, ("frontleft",)), Subscriber(ep, sensor="front") as sub:
        t = threading.Thread(target=lambda: returned.append(sub.recv(timeout_s=0.5)))
        t.start()
        t.join(timeout=10.0)
        assert not t.is_alive(), "recv(timeout_s=0.5) still blocked after 10 s"
    assert returned == [None]


def test_lost_is_counted_per_sensor(tmp_path: Path) -> None:
    """Two sensors on one endpoint, every message received: nothing lost. One seq
    counter for both would see 0, 0, 1, 1, ... and count repeats and gaps."""
    ep = f"ipc://{tmp_path}/two.sock"
    got: dict[str, list[int]] = {"a": [], "b": []}
    with publishing(ep, ("a", "b")), Subscriber(ep, kinds=["range"]) as sub:
        deadline = time.monotonic() + 20.0
        while min(len(v) for v in got.values()) < 100:
            assert time.monotonic() < deadline, {k: len(v) for k, v in got.items()}
            m = sub.recv(timeout_s=5.0)
            assert isinstance(m, RangeMessage)
            got[m.sensor].append(m.seq)
        assert sub.lost == 0
    for seqs in got.values():
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))


def _watch(ep: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "lunad.daemon.cli", "watch", "--connect", ep, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_watch_prints_its_summary_on_ctrl_c_and_keeps_its_duration(tmp_path: Path) -> None:
    ep = f"ipc://{tmp_path}/w.sock"
    with publishing(ep, ("front",)):
        w = _watch(ep, "--sensor", "front")
        try:
            assert w.stdout is not None
            for _ in range(5):
                assert w.stdout.readline().startswith("#")
            w.send_signal(signal.SIGINT)
            _, err = w.communicate(timeout=10)
        finally:
            w.kill()
        assert w.returncode == 0
        assert "readings, 0 lost (seq gaps)" in err
    with publishing(ep, ("frontleft",)):
        only_front2 = _watch(ep, "--sensor", "front", "--duration", "1")
        try:
            _, err = only_front2.communicate(timeout=20)  # it waited forever before
        finally:
            only_front2.kill()
        assert only_front2.returncode == 0 and "0 readings, 0 lost" in err


def test_watch_says_what_to_check_when_nothing_comes(tmp_path: Path) -> None:
    """No daemon on the endpoint (or a socket it may not read): ZeroMQ is silent about
    it, so watch says so itself after a few seconds, once, and keeps waiting."""
    w = _watch(f"ipc://{tmp_path}/nobody.sock", "--duration", "7", "--sensor", "Front")
    _, err = w.communicate(timeout=30)
    assert w.returncode == 0
    assert err.count("nothing from ipc://") == 1 and "group lunad" in err
    assert "Does the daemon call its sensor 'Front'" in err  # a name that is not the one


def test_watch_says_when_what_comes_does_not_decode(tmp_path: Path) -> None:
    """A publisher whose messages are not lunad's contract (another version, or not
    lunad): watch skipped them and said "nothing yet" and "0 readings, 0 lost", as if
    nothing came. It says they came and did not decode, and counts them."""
    ep = f"ipc://{tmp_path}/u.sock"
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    stop = threading.Event()

    def send() -> None:
        while not stop.wait(0.05):
            pub.send_multipart([topic("range", "front"), b'{"kind": "range", "seq": -1}'])

    sender = threading.Thread(target=send)
    sender.start()
    try:
        w = _watch(ep, "--duration", "7")
        _, err = w.communicate(timeout=30)
    finally:
        stop.set()
        sender.join()
        pub.close(linger=0)
        ctx.term()
    assert w.returncode == 0
    assert err.count("did not decode and were skipped") == 1 and "nothing from" not in err
    summary = err.strip().splitlines()[-1]
    assert summary.startswith("0 readings, 0 lost (seq gaps), ")
    assert int(summary.split(", ")[2].split()[0]) >= 50, summary


def test_gaps_duplicates_folding_restarts_and_bad_messages(tmp_path: Path) -> None:
    ep = f"ipc://{tmp_path}/c.sock"
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    try:
        with Subscriber(ep, sensor="c") as sub:
            deadline = time.monotonic() + 5
            first = None
            while first is None and time.monotonic() < deadline:  # slow-joiner handshake
                pub.send_multipart([topic("range", "c"), msg(0)])
                first = sub.recv(timeout_s=0.05)
            assert isinstance(first, RangeMessage)
            while sub.recv(timeout_s=0.1) is not None:
                pass
            sends = [
                (topic("range", "c"), msg(1)),
                (topic("range", "c"), msg(2)),
                (topic("range", "c"), msg(5)),  # 3 and 4 lost
                (topic("range", "c"), msg(5)),  # the cache's copy: a duplicate
                (topic("range", "c"), msg(9, frames=4)),  # 6-9 folded into one: no loss
                (topic("range", "c"), b"{not json"),
                (topic("range", "other"), msg(99, "other")),
                (topic("range", "cc"), msg(99, "cc")),  # a longer name: never delivered
                (topic("range", "c"), msg(0, run="00000000000000b2")),  # a restart
                (topic("range", "c"), msg(1, run="00000000000000b2")),
            ]
            for frames in sends:
                pub.send_multipart(list(frames))
            got = []
            while (m := sub.recv(timeout_s=0.3)) is not None:
                assert isinstance(m, RangeMessage)
                got.append((m.run[-2:], m.seq))
            assert got == [("a1", 1), ("a1", 2), ("a1", 5), ("a1", 9), ("b2", 0), ("b2", 1)]
            assert sub.lost == 2
            assert sub.duplicates == 1
            assert sub.bad_messages == 1
    finally:
        pub.close(linger=0)
        ctx.term()


def test_a_silent_daemon_raises_stale_stream(tmp_path: Path) -> None:
    """``for msg in sub`` once blocked for ever when the daemon died; with a limit it
    raises, and ``alive`` says the same."""
    ep = f"ipc://{tmp_path}/s.sock"
    with Subscriber(ep, sensor="front", stale_after_s=0.3) as sub:
        with publishing(ep, ("front",)):
            it = iter(sub)
            assert isinstance(next(it), RangeMessage)
            assert sub.alive and sub.rate_hz > 0
        t0 = time.monotonic()
        with pytest.raises(StaleStream) as err:
            while True:
                next(it)
        assert 0.2 < time.monotonic() - t0 < 5.0
        assert err.value.silent_s >= 0.3
        assert not sub.alive
    with pytest.raises(ValueError):
        Subscriber(ep, stale_after_s=0.0)


def test_a_repeated_health_message_is_dropped(tmp_path: Path) -> None:
    """The daemon's last-value cache sends the cached health to every subscriber when
    another one subscribes; robot code counting state changes saw each one twice."""
    from lunad.protocol.messages import HealthMessage, encode_health

    def health(t_unix_ns: int, sensor: str = "c") -> bytes:
        return encode_health(
            HealthMessage(
                sensor=sensor, run=RUN, t_unix_ns=t_unix_ns, t_mono_ns=1, state="waiting",
                frames=0, checksum_errors=0, bytes_discarded=0, fps=0.0, frame_rate_hz=250.0,
                dropout_ratio=0.0, dropped_sends=0, uptime_s=0.0, last_error=None,
                firmware=None,
            )
        )  # fmt: skip

    ep = f"ipc://{tmp_path}/h.sock"
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    try:
        with Subscriber(ep, kinds=["health"]) as sub:
            deadline = time.monotonic() + 5
            first = None
            t = 0
            while first is None and time.monotonic() < deadline:  # slow-joiner handshake
                t += 1
                pub.send_multipart([topic("health", "c"), health(t)])
                first = sub.recv(timeout_s=0.05)
            while sub.recv(timeout_s=0.1) is not None:
                pass
            for payload in (health(10**9), health(10**9), health(10**9, "d"), health(2 * 10**9)):
                pub.send_multipart([topic("health", json.loads(payload)["sensor"]), payload])
            got = []
            while (m := sub.recv(timeout_s=0.3)) is not None:
                got.append((m.sensor, m.t_unix_ns))
            assert got == [("c", 10**9), ("d", 10**9), ("c", 2 * 10**9)]
    finally:
        pub.close(linger=0)
        ctx.term()


@contextmanager
def joined(ep: str, **kw: object) -> Iterator[tuple[zmq.Socket[bytes], Subscriber]]:
    """A PUB socket bound on ``ep`` and a ``Subscriber`` that has got its first message
    (the slow-joiner handshake done), its queue drained."""
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    try:
        with Subscriber(ep, sensor="c", **kw) as sub:  # type: ignore[arg-type]
            deadline = time.monotonic() + 5
            first = None
            while first is None and time.monotonic() < deadline:
                pub.send_multipart([topic("range", "c"), msg(0)])
                first = sub.recv(timeout_s=0.05)
            assert first is not None
            while sub.recv(timeout_s=0.1) is not None:
                pass
            yield pub, sub
    finally:
        pub.close(linger=0)
        ctx.term()


def _with(n: int, **fields: object) -> bytes:
    """``msg(n)`` with ``fields`` set."""
    doc = json.loads(msg(n))
    doc.update(fields)
    return json.dumps(doc).encode()


def test_what_the_schema_refuses_the_client_refuses(tmp_path: Path) -> None:
    """The client converted ``"seq": "5"`` and ``"cached": 1`` and took a ``dropout``
    with a range, or a message of sensor ``rear`` on ``range/c/``; a consumer checking
    the shipped JSON Schema refused the first ones, and nobody the last. Each is now
    skipped and counted, and the schema refuses each rule the client checks."""
    from importlib import resources

    import jsonschema

    schema = json.loads(
        resources.files("lunad.protocol").joinpath("schema", "range.v2.json").read_text()
    )
    bad = [
        _with(1, seq="1"),
        _with(2, range_m="1.5"),
        _with(3, cached=1),
        _with(4, amp="500"),
        _with(5, status="dropout"),  # with a range and a sigma
        _with(6, status="degraded", range_m=None),
        _with(7, reasons=["outlier"]),  # ok, with a reason
        _with(8, zone="unreliable"),  # ok, in the unreliable zone
    ]
    for payload in bad:
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(json.loads(payload), schema)
    rear = json.loads(msg(9))
    rear["sensor"] = "rear"
    with joined(f"ipc://{tmp_path}/s.sock") as (pub, sub):
        for payload in [*bad, json.dumps(rear).encode(), msg(10)]:
            pub.send_multipart([topic("range", "c"), payload])
        got = []
        while (m := sub.recv(timeout_s=0.3)) is not None:
            got.append(m)
        assert [m.seq for m in got] == [10]  # type: ignore[union-attr]
        assert sub.bad_messages == len(bad) + 1


def test_an_oversized_message_costs_the_client_little(tmp_path: Path) -> None:
    """A 7.6 MiB message breaking the schema in many fields cost the client 1.3 GB
    (pydantic copied the input into each error), and a 190 MiB one ran a machine out
    of memory. A message over ``MAX_MESSAGE_BYTES`` is refused before it is parsed
    (here 4 MiB of them, 512 KiB each), and the next good one still arrives; libzmq
    reads none over ``SOCKET_MAX_MESSAGE_BYTES``."""
    ep = f"ipc://{tmp_path}/big.sock"
    child = subprocess.Popen(
        [sys.executable, "-c", (
            "import resource, sys\n"
            "from lunad.protocol.client import Subscriber\n"
            "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            f"with Subscriber({ep!r}, sensor='c') as sub:\n"
            "    print('up', flush=True)\n"
            "    m = sub.recv(timeout_s=20)\n"
            "grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before\n"
            "print(m is not None and m.seq, grown // 1024, sub.bad_messages, flush=True)\n"
        )],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    try:
        assert child.stdout is not None and child.stdout.readline() == "up\n"
        huge = b'{"v":2,"reasons":[' + b'"stale",' * (1 << 16) + b'"stale"]}'
        time.sleep(0.5)  # the child's subscription has reached this socket
        for _ in range(8):
            pub.send_multipart([topic("range", "c"), huge])
        pub.send_multipart([topic("range", "c"), msg(7)])
        out, _ = child.communicate(timeout=20)
    finally:
        child.kill()
        pub.close(linger=0)
        ctx.term()
    seq, grown_mib, bad = out.split()
    assert seq == "7", out
    assert int(grown_mib) < 32, out
    assert bad == "8", out


def test_a_cached_message_counts_from_when_it_was_made(tmp_path: Path) -> None:
    """A cached ``ok`` 480 ms old came to a subscriber with ``stale_after_s=0.2`` as
    live, with ``alive`` true and ``age_s`` 0: robot code acting on ``range_m`` acted
    on a reading older than its own limit. It comes as a ``stale`` dropout, as the
    daemon sends one older than its own limit, and counts as silence."""
    with joined(f"ipc://{tmp_path}/c.sock", stale_after_s=0.2) as (pub, sub):
        pub.send_multipart([topic("range", "c"), _with(5, cached=True, age_ms=480)])
        m = sub.recv(timeout_s=2)
        assert isinstance(m, RangeMessage) and m.seq == 5
        assert m.status == "dropout" and m.range_m is None and m.sigma_m is None
        assert m.reasons == ["stale"] and m.zone == "unreliable"
        assert sub.age_s >= 0.48 and not sub.alive
        pub.send_multipart([topic("range", "c"), _with(6, cached=True, age_ms=50)])
        m = sub.recv(timeout_s=2)
        assert isinstance(m, RangeMessage) and m.status == "ok" and m.range_m == 1.0
        assert sub.alive


def test_iterating_again_after_stale_stream_waits_another_spell(tmp_path: Path) -> None:
    """A loop that caught ``StaleStream`` and iterated again to wait for the daemon got
    it again at once, without waiting: 495,321 times in 2 s, a CPU busy."""
    with Subscriber(f"ipc://{tmp_path}/none.sock", stale_after_s=0.1) as sub:
        raised = 0
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            try:
                for _ in sub:
                    pass
            except StaleStream:
                raised += 1
    assert 1 <= raised <= 11


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"kinds": ["ranges"]}, "kinds: 'range' and/or 'health'"),
        ({"kinds": []}, "kinds: 'range' and/or 'health'"),
        ({"sensor": "front/"}, "sensor: 1-64 of"),
        ({"sensor": ""}, "sensor: 1-64 of"),
    ],
)
def test_arguments_that_would_subscribe_to_nothing_are_refused(
    tmp_path: Path, kw: dict[str, object], needle: str
) -> None:
    """Each subscribed to topics that never come and waited in silence: a typo looked
    like a dead daemon."""
    with pytest.raises(ValueError, match=needle):
        Subscriber(f"ipc://{tmp_path}/x.sock", **kw)  # type: ignore[arg-type]


def test_kinds_may_be_one_name(tmp_path: Path) -> None:
    """``kinds="range"`` subscribed to each of its letters, and got nothing."""
    with joined(f"ipc://{tmp_path}/k.sock", kinds="range") as (pub, sub):
        pub.send_multipart([topic("range", "c"), msg(3)])
        assert isinstance(sub.recv(timeout_s=2), RangeMessage)
