"""ZeroMQ CURVE on TCP endpoints, end to end: ``lunad serve`` as a real subprocess on
the simulated I2C sensor (``--bus sim``), bound to a free loopback port, with real
``Subscriber``s; ``lunad keys`` as a real subprocess; the config's checks through
``load_config`` and ``lunad serve``'s exit code.

Every negative test ("receives nothing") runs while a control receives: an allowed
client on the same daemon, or a subscriber that the forged publisher does serve, so
that it fails if the stream could be read after all. Every wait is bounded."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import stat
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zmq
from zmq.auth import load_certificate

from lunad.daemon.cli.keys import make_pair
from lunad.daemon.config import load_config
from lunad.daemon.errors import ConfigError
from lunad.protocol.client import Subscriber
from lunad.protocol.curve_keys import MAX_KEY_FILE_BYTES
from lunad.protocol.messages import RangeMessage, encode_range, range_ident, topic

SILENCE_S = 2.0
"""How long a refused subscriber is watched for a message, seconds, while its control
receives some 200 (100 Hz): a leak shows in milliseconds."""
CONTROL_MESSAGES = 20  # what the control must receive meanwhile
LOG_WAIT_S = 30.0  # a daemon's start-up lines, on a loaded machine (STARTUP_S)
HANG_GUARD_S = 30.0
"""How long a call that must not block is given before the test calls it blocked: only
a guard, far above the milliseconds it takes."""


@dataclass
class Keys:
    """The key files of one test: the daemon's pair, its client directory holding
    ``robot``'s public key, and ``stranger``, a valid pair not on the list."""

    server_public: Path
    server_secret: Path
    clients: Path
    robot_secret: Path
    stranger_public: Path
    stranger_secret: Path


@pytest.fixture
def keys(tmp_path: Path) -> Keys:
    server_public, server_secret, _ = make_pair(tmp_path / "server", "server")
    robot_public, robot_secret, _ = make_pair(tmp_path / "robot", "robot")
    stranger_public, stranger_secret, _ = make_pair(tmp_path / "robot", "stranger")
    clients = tmp_path / "clients"
    clients.mkdir()
    shutil.copy(robot_public, clients / "robot.key")
    return Keys(
        server_public, server_secret, clients, robot_secret, stranger_public, stranger_secret
    )


def free_tcp_endpoint(host: str = "127.0.0.1") -> str:
    with socket.socket() as s:
        s.bind((host, 0))
        port = s.getsockname()[1]
    return f"tcp://{host}:{port}"


@pytest.fixture
def tcp_endpoint() -> str:
    return free_tcp_endpoint()


@pytest.fixture
def curve_daemon(
    start_daemon: Callable[..., Any], keys: Keys, tcp_endpoint: str
) -> Callable[..., Any]:
    """Starts ``lunad serve`` on the simulated sensor, a CURVE server on ``tcp_endpoint``."""

    def start(*extra: str) -> Any:
        return start_daemon(
            "--bus", "sim", "--rate", "100", "--name", "c1", "--publish", tcp_endpoint,
            "--curve-secret-key", str(keys.server_secret),
            "--curve-clients", str(keys.clients), *extra,
        )  # fmt: skip

    return start


@pytest.fixture
def robot(keys: Keys, tcp_endpoint: str) -> Iterator[Subscriber]:
    """The allowed client, pinning the daemon's key, keys given as paths."""
    with Subscriber(
        tcp_endpoint,
        curve_server_key=keys.server_public,
        curve_client_key=keys.robot_secret,
    ) as sub:
        yield sub


def first_range(sub: Subscriber, timeout_s: float) -> RangeMessage:
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        msg = sub.recv(timeout_s=left)
        if isinstance(msg, RangeMessage):
            return msg
    pytest.fail(f"no range message within {timeout_s} s")


def assert_silent_while(refused: Subscriber, control: Subscriber) -> None:
    """``refused`` gets nothing for ``SILENCE_S`` while ``control`` keeps receiving."""
    got = 0
    deadline = time.monotonic() + SILENCE_S
    while time.monotonic() < deadline:
        if control.recv(timeout_s=0.05) is not None:
            got += 1
        leaked = refused.recv(timeout_s=0)
        assert leaked is None, f"a refused subscriber received {leaked!r}"
    assert got >= CONTROL_MESSAGES, f"the control received only {got} messages"


def wait_for_log(d: Any, text: str, timeout_s: float = LOG_WAIT_S) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        log = str(d.log)
        if text in log:
            return log
        if d.proc.poll() is not None:
            pytest.fail(f"the daemon exited {d.proc.returncode} before logging {text!r}:\n{log}")
        time.sleep(0.05)
    pytest.fail(f"{text!r} not logged within {timeout_s} s:\n{d.log}")


# --- the daemon as a CURVE server ---------------------------------------------------------


def test_an_allowed_client_receives_range_messages_and_bad_key_files_are_skipped(
    curve_daemon: Callable[..., Any], keys: Keys, robot: Subscriber, helpers: Any
) -> None:
    """Files in the client directory that are not key files (junk, a FIFO, a directory,
    one over the size cap) are logged and skipped; the daemon starts and serves."""
    (keys.clients / "junk.key").write_text("not a certificate\n")
    os.mkfifo(keys.clients / "fifo.key")  # opened, it would block the loop
    (keys.clients / "dir.key").mkdir()
    (keys.clients / "big.key").write_bytes(b"#" * (MAX_KEY_FILE_BYTES + 1))
    (keys.clients / "notes.txt").write_text("not a *.key: not looked at\n")
    d = curve_daemon()
    first = first_range(robot, helpers.startup_s)
    # The first readings after a start are published stale, with no estimate, until
    # the noise is measured (docs/messages.md): a client that joins at once sees them.
    while first.range_m is None and "stale" in first.reasons:
        first = first_range(robot, 5.0)
    msgs = [first] + [first_range(robot, 5.0) for _ in range(CONTROL_MESSAGES)]
    assert all(m.sensor == "c1" and m.range_m is not None for m in msgs)
    log = wait_for_log(d, "admitting 1 client key(s)")
    for name in ("junk.key", "fifo.key", "dir.key", "big.key"):
        assert f"skipping a client key: {keys.clients / name}" in log, name
    assert "notes.txt" not in log
    server_key = keys.server_public.read_text().split('public-key = "')[1][:40]
    assert f"CURVE server with public key {server_key}" in log
    assert d.proc.poll() is None


def test_a_client_whose_key_is_not_on_the_list_receives_nothing(
    curve_daemon: Callable[..., Any], keys: Keys, robot: Subscriber, tcp_endpoint: str, helpers: Any
) -> None:
    """A valid CURVE client that pins the right server key but whose key is not in the
    directory is refused by ZAP (400), and the refusal names its key in Z85."""
    d = curve_daemon()
    first_range(robot, helpers.startup_s)
    with Subscriber(
        tcp_endpoint, curve_server_key=keys.server_public, curve_client_key=keys.stranger_secret
    ) as stranger:
        assert_silent_while(stranger, robot)
    stranger_z85 = load_certificate(keys.stranger_public)[0].decode()
    log = wait_for_log(d, f"CURVE: refused {stranger_z85} from 127.0.0.1")
    assert "key not in" in log


def test_a_plain_subscriber_receives_nothing(
    curve_daemon: Callable[..., Any], robot: Subscriber, tcp_endpoint: str, helpers: Any
) -> None:
    """A subscriber without CURVE (the NULL mechanism) fails the handshake."""
    curve_daemon()
    first_range(robot, helpers.startup_s)
    with Subscriber(tcp_endpoint) as plain:
        assert_silent_while(plain, robot)


def test_a_subscriber_pinning_another_server_key_receives_nothing(
    curve_daemon: Callable[..., Any],
    keys: Keys,
    robot: Subscriber,
    tcp_endpoint: str,
    tmp_path: Path,
    helpers: Any,
) -> None:
    """A client with a key on the list that pins another server key (say, an old one)
    cannot read the daemon: it would not be talking to the server it trusts."""
    curve_daemon()
    first_range(robot, helpers.startup_s)
    other_public, _, _ = make_pair(tmp_path / "other", "server")
    with Subscriber(
        tcp_endpoint, curve_server_key=other_public, curve_client_key=keys.robot_secret
    ) as wrong:
        assert_silent_while(wrong, robot)


def test_the_client_directory_is_re_read_when_it_changes(
    curve_daemon: Callable[..., Any], keys: Keys, robot: Subscriber, tcp_endpoint: str, helpers: Any
) -> None:
    """A key copied into the directory admits its client without a restart; removed,
    new connections with it are refused again (connections already admitted stay)."""
    d = curve_daemon()
    first_range(robot, helpers.startup_s)

    def stranger() -> Subscriber:
        return Subscriber(
            tcp_endpoint,
            curve_server_key=keys.server_public,
            curve_client_key=keys.stranger_secret,
        )

    # ALLOWLIST_CHECK_S after the last look, the next handshake re-reads the directory
    shutil.copy(keys.stranger_public, keys.clients / "stranger.key")
    deadline = time.monotonic() + 10.0
    admitted = False
    while not admitted and time.monotonic() < deadline:
        with stranger() as sub:  # a refused libzmq SUB does not retry: a new one each time
            admitted = sub.recv(timeout_s=1.0) is not None
    assert admitted, "a key added to the directory was not admitted within 10 s"
    wait_for_log(d, "admitting 2 client key(s)")

    (keys.clients / "stranger.key").unlink()
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        with stranger() as sub:
            if sub.recv(timeout_s=1.0) is None:
                break
    else:
        pytest.fail("a key removed from the directory was still admitted after 10 s")
    with stranger() as sub:
        assert_silent_while(sub, robot)


def test_a_sighup_that_moves_a_curve_endpoint_keeps_it_curve(
    start_daemon: Callable[..., Any], keys: Keys, tmp_path: Path, helpers: Any
) -> None:
    """The endpoint is changed in the file and the daemon reloaded: on the new port an
    allowed client receives and a plain subscriber receives nothing."""
    cfg = tmp_path / "c.toml"

    def write(endpoint: str) -> None:
        cfg.write_text(
            f'[publish]\nendpoint = "{endpoint}"\n'
            f'curve_secret_key = "{keys.server_secret}"\ncurve_clients = "{keys.clients}"\n'
        )

    first, moved = free_tcp_endpoint(), free_tcp_endpoint()
    write(first)
    d = start_daemon("--bus", "sim", "--rate", "100", "--config", str(cfg))
    allowed: dict[str, Any] = {
        "curve_server_key": keys.server_public,
        "curve_client_key": keys.robot_secret,
    }
    with Subscriber(first, **allowed) as sub:
        first_range(sub, helpers.startup_s)
    write(moved)
    d.proc.send_signal(signal.SIGHUP)
    wait_for_log(d, "SIGHUP: configuration reloaded")
    with Subscriber(moved, **allowed) as robot, Subscriber(moved) as plain:
        first_range(robot, 5.0)
        assert_silent_while(plain, robot)


def test_a_forged_publisher_cannot_be_read_by_a_subscriber_that_pins_the_server_key(
    keys: Keys,
) -> None:
    """A publisher without the daemon's secret key on the daemon's endpoint, in clear
    text or with a CURVE key of its own, sends valid range messages: a subscriber that
    pins the daemon's key gets none, while one that trusts the forger (the control)
    does, so the forged stream is readable by anyone who does not pin."""
    ident = range_ident("c1", "00000000000000f0")
    ctx = zmq.Context()
    forger_public, forger_secret = zmq.curve_keypair()
    try:
        for mechanism in ("NULL", "CURVE"):
            pub = ctx.socket(zmq.PUB)
            pub.setsockopt(zmq.LINGER, 0)
            if mechanism == "CURVE":  # no ZAP handler in this context: every key admitted
                pub.curve_server = True
                pub.curve_publickey = forger_public
                pub.curve_secretkey = forger_secret
            endpoint = free_tcp_endpoint()
            pub.bind(endpoint)
            control_keys: dict[str, Any] = (
                {}
                if mechanism == "NULL"
                else {"curve_server_key": forger_public, "curve_client_key": keys.robot_secret}
            )
            try:
                with (
                    Subscriber(endpoint, **control_keys) as control,
                    Subscriber(
                        endpoint,
                        curve_server_key=keys.server_public,
                        curve_client_key=keys.robot_secret,
                    ) as pinned,
                ):
                    got = seq = 0
                    deadline = time.monotonic() + SILENCE_S
                    while time.monotonic() < deadline:
                        payload = encode_range(
                            ident, seq, 1, 1, 2, 1.0, 500, 30.0, 0.25, 1.0, 0.01, 10.0,
                            "ok", b"[]", "stable",
                        )  # fmt: skip
                        pub.send_multipart([topic("range", "c1"), payload])
                        seq += 1
                        if control.recv(timeout_s=0.01) is not None:
                            got += 1
                        assert pinned.recv(timeout_s=0) is None, mechanism
                    assert got >= CONTROL_MESSAGES, (mechanism, got)
            finally:
                pub.close()
    finally:
        ctx.term()


# --- the warning for a clear-text endpoint other hosts can reach ---------------------------

WARNING_TEXT = "the stream is readable by any host that can reach it"


@pytest.mark.parametrize(
    ("host", "curve", "warned"),
    [("0.0.0.0", False, True), ("127.0.0.1", False, False), ("0.0.0.0", True, False)],
)
def test_a_non_loopback_bind_without_curve_logs_one_warning(
    start_daemon: Callable[..., Any], keys: Keys, host: str, curve: bool, warned: bool
) -> None:
    endpoint = free_tcp_endpoint("127.0.0.1").replace("127.0.0.1", host)
    extra = (
        ["--curve-secret-key", str(keys.server_secret), "--curve-clients", str(keys.clients)]
        if curve
        else []
    )
    d = start_daemon("--bus", "sim", "--rate", "100", "--publish", endpoint, *extra)
    log = wait_for_log(d, "serving sensor")
    lines = [line for line in log.splitlines() if WARNING_TEXT in line]
    if warned:
        assert len(lines) == 1, log
        assert lines[0].startswith("WARNING") and endpoint in lines[0]
        assert "curve_secret_key" in lines[0] and "docs/security.md" in lines[0]
    else:
        assert not lines, log


# --- lunad keys ----------------------------------------------------------------------------


def lunad_keys(helpers: Any, *args: str) -> subprocess.CompletedProcess[str]:
    """``lunad keys ARGS`` with umask 0, so that the files' modes are the command's own."""
    return subprocess.run(
        [*helpers.lunad, "keys", *args],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=lambda: os.umask(0),
    )


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_lunad_keys_makes_pairs_with_the_right_modes_and_refuses_to_overwrite(
    tmp_path: Path, helpers: Any
) -> None:
    out = tmp_path / "curve"  # made by the command
    r = lunad_keys(helpers, "server", str(out))
    assert r.returncode == 0, r.stderr
    public, secret = out / "server.key", out / "server.key_secret"
    assert (mode(public), mode(secret)) == (0o644, 0o600)
    pub_key, sec_key = load_certificate(secret)
    assert sec_key is not None and zmq.curve_public(sec_key) == pub_key
    assert load_certificate(public) == (pub_key, None)
    assert f"public key: {pub_key.decode()}" in r.stdout
    assert sorted(p.name for p in out.iterdir()) == ["server.key", "server.key_secret"]

    before = (public.read_bytes(), secret.read_bytes())
    r = lunad_keys(helpers, "server", str(out))
    assert r.returncode == 1 and "--force" in r.stderr and str(public) in r.stderr
    assert (public.read_bytes(), secret.read_bytes()) == before
    secret.unlink()  # one file of the pair left: still refused, still untouched
    r = lunad_keys(helpers, "server", str(out))
    assert r.returncode == 1 and not secret.exists() and public.read_bytes() == before[0]

    r = lunad_keys(helpers, "server", str(out), "--force")
    assert r.returncode == 0, r.stderr
    assert (mode(public), mode(secret)) == (0o644, 0o600)
    assert load_certificate(public)[0] != pub_key

    r = lunad_keys(helpers, "client", "robot1", str(out))
    assert r.returncode == 0, r.stderr
    assert (mode(out / "robot1.key"), mode(out / "robot1.key_secret")) == (0o644, 0o600)
    r = lunad_keys(helpers, "client", "robot1", str(out))
    assert r.returncode == 1 and "--force" in r.stderr
    r = lunad_keys(helpers, "client", "../escape", str(out))
    assert r.returncode == 2 and "NAME" in r.stderr
    assert not (tmp_path / "escape.key").exists()

    r = lunad_keys(helpers, "list", str(out))
    assert r.returncode == 0, r.stderr
    listed = dict(line.split() for line in r.stdout.splitlines())
    assert listed == {
        "robot1": load_certificate(out / "robot1.key")[0].decode(),
        "server": load_certificate(public)[0].decode(),
    }
    assert not list(out.glob(".lunad-keys-*"))  # no temporary directory left behind


# --- configuration errors name the field ----------------------------------------------------


def test_config_errors_name_the_field(keys: Keys, tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.key_secret"
    os.mkfifo(fifo)  # read, it would block the start
    big = tmp_path / "big.key_secret"
    big.write_bytes(b"#" * (MAX_KEY_FILE_BYTES + 1))
    secret, clients = str(keys.server_secret), str(keys.clients)
    tcp = "tcp://127.0.0.1:7781"
    cases: list[tuple[dict[str, str], list[str]]] = [
        ({"curve_secret_key": secret}, ["curve_clients (--curve-clients) is not set"]),
        ({"curve_clients": clients}, ["curve_secret_key (--curve-secret-key) is not set"]),
        (
            {"curve_secret_key": secret, "curve_clients": clients, "endpoint": "ipc:///x.sock"},
            ["curve_secret_key (--curve-secret-key)", "tcp://", "ipc:///x.sock"],
        ),
        (
            {"curve_secret_key": str(keys.server_public), "curve_clients": clients},
            ["publish.curve_secret_key (--curve-secret-key)", "holds no secret key"],
        ),
        (
            {"curve_secret_key": str(fifo), "curve_clients": clients},
            ["publish.curve_secret_key (--curve-secret-key)", "is a FIFO"],
        ),
        (
            {"curve_secret_key": str(big), "curve_clients": clients},
            ["publish.curve_secret_key (--curve-secret-key)", "larger than"],
        ),
        (
            {"curve_secret_key": str(tmp_path / "absent"), "curve_clients": clients},
            ["publish.curve_secret_key (--curve-secret-key)", "does not exist"],
        ),
        (
            {"curve_secret_key": secret, "curve_clients": secret},
            ["publish.curve_clients (--curve-clients)", "not a directory"],
        ),
        (
            {"curve_secret_key": secret, "curve_clients": str(tmp_path / "absent")},
            ["publish.curve_clients (--curve-clients)", "does not exist"],
        ),
    ]
    for fields, wanted in cases:
        fields.setdefault("endpoint", tcp)
        with pytest.raises(ConfigError) as err:
            load_config(None, {f"publish.{k}": v for k, v in fields.items()})
        for text in wanted:
            assert text in str(err.value), (fields, str(err.value))
    ok = load_config(
        None,
        {
            "publish.endpoint": tcp,
            "publish.curve_secret_key": secret,
            "publish.curve_clients": clients,
        },
    )
    assert ok.publish.curve is not None and ok.publish.curve.clients == keys.clients


def test_a_curve_config_error_exits_78_naming_the_field_as_written_in_the_file(
    keys: Keys, tmp_path: Path, helpers: Any
) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[publish]\ncurve_clients = "{keys.clients}"\n')
    r = subprocess.run(
        [*helpers.lunad, "serve", "--bus", "sim", "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 78, r.stderr
    assert "curve_secret_key (--curve-secret-key) is not set" in r.stderr
    assert str(cfg) in r.stderr


# --- Subscriber's key arguments ---------------------------------------------------------------


def test_subscriber_checks_its_curve_keys(keys: Keys, tcp_endpoint: str) -> None:
    server = load_certificate(keys.server_public)[0]
    robot_public, robot_secret = load_certificate(keys.robot_secret)
    assert robot_secret is not None
    big = keys.robot_secret.with_name("big.key_secret")
    big.write_bytes(b"#" * (MAX_KEY_FILE_BYTES + 1))
    for server_key in (server, server.decode(), keys.server_public, str(keys.server_public)):
        Subscriber(
            tcp_endpoint, curve_server_key=server_key, curve_client_key=(robot_public, robot_secret)
        ).close()
    bad: list[tuple[dict[str, Any], str]] = [
        ({"curve_server_key": server}, "go together"),
        ({"curve_client_key": keys.robot_secret}, "go together"),
        (
            {"curve_server_key": server[:-1], "curve_client_key": keys.robot_secret},
            "curve_server_key",
        ),
        (
            {"curve_server_key": server, "curve_client_key": keys.stranger_public},
            "holds no secret key",
        ),
        (
            {"curve_server_key": server, "curve_client_key": (robot_public, server)},
            "not the secret key's",
        ),
        (
            {
                "curve_server_key": keys.clients / "absent.key",
                "curve_client_key": keys.robot_secret,
            },
            "curve_server_key: .*absent.key does not exist",
        ),
        (
            {"curve_server_key": server, "curve_client_key": big},
            "curve_client_key: .*larger than",
        ),
    ]
    for kwargs, text in bad:
        with pytest.raises(ValueError, match=text):
            Subscriber(tcp_endpoint, **kwargs)


def test_subscriber_names_a_fifo_given_as_a_key_file_instead_of_blocking(
    keys: Keys, tcp_endpoint: str, tmp_path: Path
) -> None:
    """A FIFO as ``curve_server_key`` is refused by what it is, before it is opened:
    opened for reading, it would block the robot's code until some writer came."""
    fifo = tmp_path / "server.key"
    os.mkfifo(fifo)
    raised: list[BaseException] = []

    def subscribe() -> None:
        try:
            Subscriber(
                tcp_endpoint, curve_server_key=str(fifo), curve_client_key=keys.robot_secret
            ).close()
        except BaseException as exc:  # handed to the test's thread
            raised.append(exc)

    worker = threading.Thread(target=subscribe, daemon=True)
    worker.start()
    worker.join(HANG_GUARD_S)
    if worker.is_alive():  # blocked in open(): a writer's open and close gives it EOF
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        worker.join(HANG_GUARD_S)
        pytest.fail(f"Subscriber blocked on the FIFO {fifo} for {HANG_GUARD_S} s")
    assert len(raised) == 1 and isinstance(raised[0], ValueError), raised
    assert str(raised[0]) == f"curve_server_key: {fifo} is a FIFO, not a regular file"


def test_lunad_watch_reads_a_curve_endpoint_with_its_keys(
    curve_daemon: Callable[..., Any], keys: Keys, tcp_endpoint: str
) -> None:
    """``lunad watch --curve-server-key --curve-client-key`` reads the stream as robot
    code would; one key alone is refused with exit 2, naming both flags."""
    import sys

    curve_daemon()
    watch = [sys.executable, "-m", "lunad.daemon.cli", "watch", "--connect", tcp_endpoint]
    done = subprocess.run(
        [*watch, "--json", "--count", "5", "--duration", "20",
         "--curve-server-key", str(keys.server_public),
         "--curve-client-key", str(keys.robot_secret)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if '"topic":"range/c1/"' in line]
    assert len(lines) >= 5, done.stdout[-500:]
    half = subprocess.run(
        [*watch, "--count", "1", "--curve-server-key", str(keys.server_public)],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert half.returncode == 2
    assert "--curve-server-key and --curve-client-key go together" in half.stderr


def test_key_files_read_as_zmq_auth_reads_them(tmp_path: Path) -> None:
    """``read_key_file`` parses the ZPL text itself (it reads the file it opened, so a
    path swapped for a FIFO after the check cannot block it): on the files
    ``zmq.auth.create_certificates`` writes it finds what ``load_certificate`` finds."""
    import zmq.auth

    from lunad.protocol.curve_keys import read_key_file

    public_file, secret_file = zmq.auth.create_certificates(tmp_path, "peer")
    assert read_key_file(public_file) == zmq.auth.load_certificate(public_file)
    assert read_key_file(secret_file, secret=True) == zmq.auth.load_certificate(secret_file)
