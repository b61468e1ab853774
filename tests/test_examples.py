"""The consumers in other languages (examples/): the C and the Node.js subscriber, each a
real subprocess, against a real publisher on ipc:// (a socket in the test, then the daemon).

They apply docs/messages.md by hand, so these tests hold them to it: exact topics, the
schema version, duplicates and loss from ``run``/``seq``/``frames``, cached messages and
the subscriber's own staleness check. The C one needs ``cc`` and ``zmq.h`` (Debian:
libzmq3-dev), the Node one ``node`` and the zeromq package (``npm install`` in a copy of
examples/ when examples/node_modules is missing); .ci/run installs them, and without them
the tests skip and say why.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

from lunad.protocol.messages import (
    HealthMessage,
    as_cached,
    encode_health,
    encode_range,
    new_run_id,
    range_ident,
    topic,
)
from lunad.sim.pty_device import PtyDevice

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
NODE_FILES = ("package.json", "package-lock.json", "node_subscriber.mjs")
SUBSCRIBE_S = 30.0
"""How long the publisher waits for a consumer's subscriptions: a process start, plus
loading Node and its zeromq addon on a loaded CI machine."""
T_UNIX_NS = 1_795_960_000_123_456_789  # above 2^53, as every t_unix_ns is
OUTLIER = b'["outlier"]'
WEAK = b'["weak_signal"]'


@pytest.fixture(scope="module")
def c_subscriber(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """examples/c_subscriber.c built with the command its header gives."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (cc) on PATH; .ci/run's machine has one")
    probe = subprocess.run(
        [cc, "-E", "-x", "c", "-"], input="#include <zmq.h>\n", capture_output=True, text=True
    )
    if probe.returncode != 0:
        pytest.skip("no zmq.h for cc: apt-get install libzmq3-dev (.ci/run does)")
    exe = tmp_path_factory.mktemp("c") / "c_subscriber"
    src = EXAMPLES / "c_subscriber.c"
    build = subprocess.run(
        [cc, "-O2", "-Wall", "-Wextra", "-o", str(exe), str(src), "-lzmq"],
        capture_output=True,
        text=True,
    )
    assert build.returncode == 0 and "warning" not in build.stderr, build.stderr
    return [str(exe)]


@pytest.fixture(scope="module")
def node_subscriber(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """examples/node_subscriber.mjs with the zeromq package beside it: examples/ itself when
    its node_modules is there, otherwise a copy with ``npm install`` run in it."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("no node on PATH: apt-get install nodejs npm (.ci/run does)")
    folder = EXAMPLES
    if not (EXAMPLES / "node_modules" / "zeromq").is_dir():
        npm = shutil.which("npm")
        if npm is None:
            pytest.skip("no npm on PATH to install zeromq: apt-get install npm (.ci/run does)")
        folder = tmp_path_factory.mktemp("node")
        for name in NODE_FILES:
            shutil.copy(EXAMPLES / name, folder / name)
        try:
            done = subprocess.run(
                [npm, "install", "--no-audit", "--no-fund"],
                cwd=folder,
                capture_output=True,
                text=True,
                timeout=600,
            )
        except subprocess.TimeoutExpired:
            pytest.skip("npm install of examples/package.json took over 10 minutes")
        if done.returncode != 0:
            pytest.skip(f"npm install of examples/package.json failed: {done.stderr[-800:]}")
    load = subprocess.run(
        [node, "-e", "require('zeromq')"], cwd=folder, capture_output=True, text=True
    )
    if load.returncode != 0:
        pytest.skip(f"the zeromq package does not load in node: {load.stderr[-800:]}")
    return [node, str(folder / "node_subscriber.mjs")]


@pytest.fixture(params=["c", "node"])
def consumer(request: pytest.FixtureRequest) -> list[str]:
    """The command that starts one example subscriber (arguments follow)."""
    cmd: list[str] = request.getfixturevalue(f"{request.param}_subscriber")
    return cmd


class Publisher:
    """A socket in the test that publishes as lunad does. An XPUB (a PUB that also hears
    subscriptions), so that it can wait for the consumer's before sending: ZeroMQ drops
    what a PUB sends to nobody."""

    def __init__(self, endpoint: str) -> None:
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.XPUB)
        self.sock.bind(endpoint)

    def wait_for_subscriptions(self, *prefixes: bytes) -> None:
        wanted = {b"\x01" + p for p in prefixes}
        deadline = time.monotonic() + SUBSCRIBE_S
        while wanted:
            left_ms = int((deadline - time.monotonic()) * 1000)
            if left_ms <= 0 or not self.sock.poll(left_ms):
                pytest.fail(f"the consumer did not subscribe within {SUBSCRIBE_S} s: {wanted}")
            wanted.discard(self.sock.recv())

    def send(self, topic_frame: bytes, payload: bytes) -> None:
        self.sock.send_multipart([topic_frame, payload])

    def close(self, linger_ms: int = 0) -> None:
        """Close; with ``linger_ms``, once what was sent has left (or that time passed)."""
        self.sock.close(linger=linger_ms)
        self.ctx.term()


@pytest.fixture
def publisher(tmp_path: Path) -> Iterator[tuple[str, Publisher]]:
    endpoint = f"ipc://{tmp_path}/pub.sock"
    pub = Publisher(endpoint)
    yield endpoint, pub
    if not pub.sock.closed:
        pub.close()


def reading(
    sensor: str,
    run: str,
    seq: int,
    range_m: float | None,
    frames: int = 1,
    status: str = "ok",
    reasons: bytes = b"[]",
) -> bytes:
    """A live range message as the daemon builds it (``encode_range``)."""
    t_ns = seq * 4_000_000  # 250 Hz
    return encode_range(
        range_ident(sensor, run), seq, frames, 81_234_567_890_123 + t_ns, T_UNIX_NS + t_ns,
        range_m, 1500 if range_m else 40, 40.125, 0.75 if range_m else 0.02, range_m,
        None if range_m is None else 0.004, None if range_m is None else 350.0, status,
        reasons, "stable" if range_m else "unreliable",
    )  # fmt: skip


def health(sensor: str, run: str) -> bytes:
    return encode_health(
        HealthMessage(
            sensor=sensor, run=run, t_unix_ns=T_UNIX_NS, t_mono_ns=81_234_567_890_123,
            state="connected", frames=9, checksum_errors=0, bytes_discarded=0, fps=250.0,
            frame_rate_hz=250.0, dropout_ratio=0.0, dropped_sends=0, uptime_s=1.0,
            last_error=None, firmware="3.0.9",
        )
    )  # fmt: skip


def start(cmd: list[str], *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [*cmd, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def finish(proc: subprocess.Popen[str], timeout_s: float) -> tuple[int, str, str]:
    """The consumer's exit code, stdout and stderr; kill it and fail after ``timeout_s``."""
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the consumer did not exit within {timeout_s} s: {out!r} {err!r}")
    return proc.returncode, out, err


def test_rules_of_the_contract(consumer: list[str], publisher: tuple[str, Publisher]) -> None:
    """Exact topics, schema v2, duplicates, folded frames, a gap, a new run and a cached
    message: the printed lines and the summary, exactly."""
    endpoint, pub = publisher
    run_a, run_b, run_l = new_run_id(), new_run_id(), new_run_id()
    assert len({run_a, run_b, run_l}) == 3
    proc = start(consumer, endpoint, "front", "--count", "6", "--stale-ms", "30000")
    try:
        pub.wait_for_subscriptions(b"range/front/", b"health/front/")
        first = reading("front", run_a, 0, 1.0)
        v1 = reading("front", run_a, 9, 1.009).replace(b'"v":2', b'"v":1', 1)
        assert v1 != reading("front", run_a, 9, 1.009)
        b0 = reading("front", run_b, 0, 2.0)
        sends: list[tuple[bytes, bytes]] = [
            (topic("range", "frontleft"), reading("frontleft", run_l, 0, 3.0)),  # never shown
            (topic("range", "front"), as_cached("range", first, 40, 500)),  # a late joiner's
            (topic("health", "front"), health("front", run_a)),
            (topic("range", "front"), reading("front", run_a, 1, 1.001)),
            (topic("range", "front"), reading("front", run_a, 1, 1.001)),  # duplicate
            (topic("range", "frontleft"), reading("frontleft", run_l, 1, 3.0)),
            (topic("health", "frontleft"), health("frontleft", run_l)),
            (topic("range", "front"), reading("front", run_a, 5, 1.005, frames=4)),  # folded
            # 6 and 7 lost: a gap of 2
            (topic("range", "front"), reading("front", run_a, 8, 1.008, 1, "degraded", OUTLIER)),
            (topic("range", "front"), v1),  # another schema: skipped
            (topic("range", "front"), reading("rear", run_a, 9, 1.009)),  # not front's
            (topic("range", "front"), reading("front", run_a, 9, 1.009, 1, "dropout", WEAK)),
            (b"range/front/x", reading("front", run_a, 10, 1.01)),  # not the exact topic
            (topic("range", "front"), b0),  # a daemon restart: seq from 0, not a duplicate
            (topic("range", "front"), as_cached("range", b0, 3, 500)),  # cache re-sent: duplicate
            (topic("range", "front"), reading("front", run_b, 1, None, 1, "dropout", WEAK)),
            (topic("range", "frontleft"), reading("frontleft", run_l, 2, 3.0)),
        ]  # fmt: skip
        for frame, payload in sends:
            pub.send(frame, payload)
        code, out, err = finish(proc, 30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert (code, out) == (
        0,
        "0 1.0000 ok cached\n"
        "1 1.0010 ok\n"
        "5 1.0050 ok\n"
        "8 1.0080 degraded\n"
        "0 2.0000 ok\n"
        "1 null dropout\n"
        "received 6 lost 2 duplicates 2\n",
    ), err
    assert "not schema v2" in err and "health connected" in err, err
    assert err.count("malformed") == 2, err  # another sensor's; a dropout with a range


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_old_cached_reading_is_stale_and_a_stop_prints_the_summary(
    consumer: list[str], publisher: tuple[str, Publisher], sig: int
) -> None:
    """A cached reading older than --stale-ms is printed as a dropout (the daemon's own
    limit, here 60 s, had not marked it); SIGINT and SIGTERM ended the examples
    without their summary line (130, 143)."""
    endpoint, pub = publisher
    run = new_run_id()
    proc = start(consumer, endpoint, "front", "--stale-ms", "30000")
    try:
        pub.wait_for_subscriptions(b"range/front/", b"health/front/")
        pub.send(
            topic("range", "front"), as_cached("range", reading("front", run, 4, 1.5), 40000, 60000)
        )
        pub.send(topic("range", "front"), reading("front", run, 5, 1.5))
        assert proc.stdout is not None
        assert proc.stdout.readline() == "4 null dropout cached\n"
        assert proc.stdout.readline() == "5 1.5000 ok\n"
        proc.send_signal(sig)
        code, out, err = finish(proc, 30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert (code, out) == (0, "received 2 lost 0 duplicates 0\n"), err


def test_silence_is_stale(consumer: list[str], publisher: tuple[str, Publisher]) -> None:
    """The publisher goes away (a dead daemon says nothing): the consumer says STALE and
    exits 3 within --stale-ms, plus a second for a loaded machine."""
    endpoint, pub = publisher
    stale_ms = 1000  # the clock starts with the consumer: room for its subscription handshake
    run = new_run_id()
    proc = start(consumer, endpoint, "front", "--stale-ms", str(stale_ms))
    try:
        pub.wait_for_subscriptions(b"range/front/", b"health/front/")
        for seq in range(3):
            pub.send(topic("range", "front"), reading("front", run, seq, 2.0))
        pub.close(linger_ms=5000)  # returns once the three have left
        stopped = time.monotonic()
        code, out, err = finish(proc, stale_ms / 1000 + 10.0)
        took = time.monotonic() - stopped
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert (code, out) == (
        3,
        "0 2.0000 ok\n1 2.0000 ok\n2 2.0000 ok\n"
        f"STALE no reading for {stale_ms} ms\n"
        "received 3 lost 0 duplicates 0\n",
    ), err
    assert stale_ms / 1000 - 0.1 <= took <= stale_ms / 1000 + 1.0


def test_c_subscriber_against_the_daemon(
    c_subscriber: list[str],
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    helpers: Any,
) -> None:
    """``lunad serve`` on the virtual sensor at 250 Hz: 50 readings in a row, none lost."""
    dev = device(rate_hz=250, output_enabled=False)  # the daemon turns output on
    d = start_daemon("--device", dev.path, "--publish", endpoint, "--name", "t1", "--rate", "250")
    # the silence allowed covers the daemon's start-up on a loaded machine
    stale_ms = str(int(helpers.startup_s * 1000))
    proc = start(c_subscriber, endpoint, "t1", "--count", "50", "--stale-ms", stale_ms)
    code, out, err = finish(proc, helpers.startup_s + 30.0)
    lines = out.splitlines()
    assert code == 0, (out, err, d.log)
    assert re.fullmatch(r"received 50 lost 0 duplicates \d+", lines[-1]), (out, err)
    seqs = [int(line.split()[0]) for line in lines[:-1]]
    assert seqs == list(range(seqs[0], seqs[0] + 50)), out
