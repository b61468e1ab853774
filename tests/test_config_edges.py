"""Hostile or odd inputs to ``lunad serve``, each run on real files, FIFOs and devices
through the real command: a config or recording that is not a regular file, too large,
nested too deep or replaced while the daemon runs; settings that would starve its loop;
endpoints no subscriber could reach; signals that come while it starts.

Every case must end in one line naming the flag or field and exit 78 before anything
is bound, or, once the daemon runs, be reported on health while it goes on serving:
never a traceback, a hang, a death by signal or a restart into the same crash.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.config import load_config
from lunad.daemon.errors import EX_CONFIG, ConfigError
from lunad.protocol.client import Subscriber
from lunad.protocol.messages import HealthMessage, Message, RangeMessage

RUN_TIMEOUT_S = 30.0
"""How long a refused start may take. About 0.5 s here (the imports); the old code
blocked here for ever on a FIFO, so the bound is what makes such a test fail."""
MEMORY_LIMIT_BYTES = 1 << 30
"""Address space given to a daemon reading /dev/zero as its config: it needs a tenth
of it, and reading without end hits the limit within a second or two, not the host's
memory."""


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT_BYTES, MEMORY_LIMIT_BYTES))


def serve(
    helpers: Any, *args: str, preexec_fn: Callable[[], None] | None = None
) -> subprocess.CompletedProcess[str]:
    """Run ``lunad serve ARGS`` to its end; a start that blocks fails the test."""
    try:
        return subprocess.run(
            [*helpers.lunad, "serve", *args],
            capture_output=True,
            text=True,
            timeout=RUN_TIMEOUT_S,
            preexec_fn=preexec_fn,
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"lunad serve {' '.join(args)} blocked for {RUN_TIMEOUT_S} s: {exc.stderr!r}")


def assert_refused(r: subprocess.CompletedProcess[str], *needles: str) -> None:
    """Exit 78 with one line on stderr holding every needle, and no traceback."""
    assert r.returncode == EX_CONFIG, r.stderr[-2000:]
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.stderr.startswith("lunad serve: ") and r.stderr.count("\n") == 1, r.stderr[-2000:]
    for needle in needles:
        assert needle in r.stderr, r.stderr
    assert r.stdout == ""


def write_recording(path: Path, reads: int, frame_rate_hz: int = 100) -> None:
    """A recording of ``reads`` reads of one frame each, ``1 / frame_rate_hz`` apart."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder
    from lunad.protocol.frame import encode_frame

    period_ns = 1_000_000_000 // frame_rate_hz
    with Recorder(path, source_desc="test", frame_rate_hz=frame_rate_hz) as rec:
        for j in range(reads):
            rec(Chunk(encode_frame(200 + j % 7, 1500, 2368), 10**12 + (j + 1) * period_ns))


def replace_with_fifo(path: Path) -> None:
    """Put a FIFO where ``path`` was, in one rename, as a hostile user could."""
    fifo = path.with_name(path.name + ".fifo")
    os.mkfifo(fifo)
    os.replace(fifo, path)


def replace_with_text(path: Path, text: str) -> None:
    new = path.with_name(path.name + ".new")
    new.write_text(text)
    os.replace(new, path)


def wait_for_health(
    sub: Subscriber, proc: subprocess.Popen[bytes], pred: Callable[[HealthMessage], bool]
) -> HealthMessage:
    """The first health message matching ``pred``; fails at once if the daemon died."""
    deadline = time.monotonic() + RUN_TIMEOUT_S
    while time.monotonic() < deadline:
        msg = sub.recv(timeout_s=0.25)
        if isinstance(msg, HealthMessage) and pred(msg):
            return msg
        if proc.poll() is not None:
            pytest.fail(f"the daemon died with code {proc.returncode}")
    pytest.fail(f"no matching health message within {RUN_TIMEOUT_S} s")


def wait_for_log(d: Any, text: str) -> None:
    deadline = time.monotonic() + RUN_TIMEOUT_S
    while text not in d.log:
        if d.proc.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"no {text!r} in the log (code {d.proc.poll()}):\n{d.log}")
        time.sleep(0.02)


# --- 1. settings that would starve the loop ---------------------------------------------


@pytest.mark.parametrize("value", ["1e-9", "0.0", "0.049", "nan", "inf", "61.0", "-1.0"])
def test_health_interval_outside_its_range_is_refused_with_the_reason(
    tmp_path: Path, value: str
) -> None:
    """1e-9 s was taken: the loop sent 21,268 health messages a second, read no frames
    and used 107 % of a core."""
    f = tmp_path / "lunad.toml"
    f.write_text(f"[publish]\nhealth_interval_s = {value}\n")
    with pytest.raises(ConfigError) as info:
        load_config(f)
    assert "publish.health_interval_s: must be 0.05..60 s: every health message wakes" in str(
        info.value
    )


def test_serve_refuses_a_health_interval_that_would_starve_it(tmp_path: Path, helpers: Any) -> None:
    f = tmp_path / "lunad.toml"
    f.write_text("[publish]\nhealth_interval_s = 1e-9\n")
    r = serve(helpers, "--config", str(f), "--device", str(tmp_path / "none"))
    assert_refused(r, "publish.health_interval_s", "0.05")


def test_at_the_shortest_health_interval_every_frame_is_still_published(
    device: Callable[..., Any], start_daemon: Any, endpoint: str, tmp_path: Path, helpers: Any
) -> None:
    """At the floor, 20 health messages a second, the loop still reads and publishes
    every frame the sensor sends."""
    dev = device(rate_hz=100)
    f = tmp_path / "lunad.toml"
    f.write_text("[publish]\nhealth_interval_s = 0.05\n")
    d = start_daemon("--config", str(f), "--device", dev.path, "--publish", endpoint)
    with Subscriber(endpoint) as sub:
        first = helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
        ranges = helpers.ranges_through(sub, first.seq + 150)
    assert [m.seq for m in ranges] == list(range(first.seq + 1, first.seq + 151))
    assert d.stop() == 0


# --- 2. files that are not regular files, or too large -----------------------------------


def test_serve_refuses_a_fifo_as_config(tmp_path: Path, helpers: Any) -> None:
    """``--config FIFO`` blocked the start without a word (and systemd's start job)."""
    fifo = tmp_path / "lunad.toml"
    os.mkfifo(fifo)
    r = serve(helpers, "--config", str(fifo), "--publish", f"ipc://{tmp_path}/x.sock")
    assert_refused(r, f"config file {fifo} (--config) is a FIFO, not a regular file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lunad.toml"]  # nothing bound


def test_serve_refuses_dev_zero_as_config_without_reading_it(tmp_path: Path, helpers: Any) -> None:
    """``--config /dev/zero`` grew the daemon by 660 MB a second (here: to the test's
    1 GiB limit, then a MemoryError traceback)."""
    r = serve(helpers, "--config", "/dev/zero", preexec_fn=_limit_memory)
    assert_refused(r, "config file /dev/zero (--config) is a character device")


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda p: p.mkdir(), "is a directory, not a regular file"),
        (lambda p: p.write_text("# a comment\n" * 100_000), "is larger than 1024 KiB"),
        (lambda p: p.symlink_to("/dev/null"), "is a character device"),
    ],
    ids=["directory", "over 1 MiB", "symlink to a device"],
)
def test_serve_refuses_a_config_that_is_no_config_file(
    tmp_path: Path, helpers: Any, make: Callable[[Path], object], needle: str
) -> None:
    f = tmp_path / "lunad.toml"
    make(f)
    r = serve(helpers, "--config", str(f), "--device", str(tmp_path / "none"))
    assert_refused(r, f"config file {f} (--config) ", needle)


def test_a_config_of_exactly_the_cap_is_read(tmp_path: Path) -> None:
    from lunad.daemon.config import MAX_CONFIG_BYTES

    f = tmp_path / "lunad.toml"
    body = '[sensor]\nname = "front"\n'
    f.write_text(body + "#" * (MAX_CONFIG_BYTES - len(body) - 1) + "\n")
    assert f.stat().st_size == MAX_CONFIG_BYTES
    assert load_config(f).sensor.name == "front"


def test_serve_refuses_a_fifo_as_recording_to_replay(tmp_path: Path, helpers: Any) -> None:
    """``--replay FIFO`` blocked in the start-up check for ever."""
    fifo = tmp_path / "field.lunarec"
    os.mkfifo(fifo)
    r = serve(helpers, "--replay", str(fifo), "--publish", f"ipc://{tmp_path}/x.sock")
    assert_refused(r, "--replay: ", f"{fifo}: is a FIFO, not a regular file")


def test_serve_refuses_a_fifo_to_record_into(tmp_path: Path, helpers: Any) -> None:
    """``--record FIFO`` blocked reading the FIFO for a recording's header."""
    fifo = tmp_path / "field.lunarec"
    os.mkfifo(fifo)
    r = serve(helpers, "--device", str(tmp_path / "none"), "--record", str(fifo))
    assert_refused(r, "source.record (--record): cannot record to", "is a FIFO")


def test_sighup_to_a_config_replaced_by_a_fifo_keeps_the_running_one(
    start_daemon: Any, endpoint: str, tmp_path: Path
) -> None:
    """The reload blocked the daemon's only loop on the FIFO: no readings, no health,
    no watchdog ping. It is refused as any bad config is, and the daemon goes on."""
    f = tmp_path / "lunad.toml"
    f.write_text(f'[source]\ndevice = "{tmp_path / "none"}"\n[publish]\nendpoint = "{endpoint}"\n')
    d = start_daemon("--config", str(f))
    with Subscriber(endpoint) as sub:
        wait_for_health(sub, d.proc, lambda m: m.state == "reconnecting")
        replace_with_fifo(f)
        d.proc.send_signal(signal.SIGHUP)
        wait_for_log(d, "SIGHUP: keeping the running configuration")
        assert "is a FIFO, not a regular file" in d.log
        after = time.monotonic_ns()
        wait_for_health(sub, d.proc, lambda m: m.t_mono_ns > after)  # its loop goes on
    assert d.stop() == 0


@pytest.mark.parametrize(
    "text", ["", "\n  \n", "# all commented out\n# [sensor]\n", "[sensor]\n[source]\n"]
)
def test_sighup_to_a_config_with_no_settings_keeps_the_running_one(
    start_daemon: Any, endpoint: str, tmp_path: Path, text: str
) -> None:
    """A file an editor truncated was read as all defaults: the reload moved the daemon
    to /dev/serial0, tcp://127.0.0.1:7781 and the name tfluna, and its subscribers on
    the configured endpoint lost the stream with one INFO line to say why."""
    f = tmp_path / "lunad.toml"
    f.write_text(
        f'[sensor]\nname = "front"\n[source]\ndevice = "{tmp_path / "none"}"\n'
        f'[publish]\nendpoint = "{endpoint}"\n'
    )
    d = start_daemon("--config", str(f))
    with Subscriber(endpoint) as sub:
        wait_for_health(sub, d.proc, lambda m: m.state == "reconnecting")
        replace_with_text(f, text)
        d.proc.send_signal(signal.SIGHUP)
        wait_for_log(d, "SIGHUP: keeping the running configuration")
        assert "sets nothing" in d.log
        after = time.monotonic_ns()
        health = wait_for_health(sub, d.proc, lambda m: m.t_mono_ns > after)
        assert health.sensor == "front"  # still the configured sensor, on its endpoint
    assert d.stop() == 0


def test_serve_refuses_a_config_with_no_settings(tmp_path: Path, helpers: Any) -> None:
    f = tmp_path / "lunad.toml"
    f.write_text("# nothing set\n")
    r = serve(helpers, "--config", str(f))
    assert_refused(r, f"config file {f} (--config): sets nothing", "built-in defaults")


# --- 3. TOML the parser cannot take -------------------------------------------------------


HOSTILE_TOML = {
    "arrays 5000 deep": ("x = " + "[" * 5000 + "]" * 5000, "nested too deeply"),
    "inline tables 5000 deep": (
        "x = " + "{a=" * 5000 + "1" + "}" * 5000,
        "nested too deeply",
    ),
    "an integer of 5000 digits": ("[publish]\nsndhwm = 1" + "0" * 5000, "4300 digits"),
    "a hex integer of 5000 digits": (
        "[publish]\nsndhwm = 0x" + "f" * 5000,
        "publish.sndhwm: Input should be less than or equal to 1000000; got an integer",
    ),
    "a 100 kB name": (
        '[sensor]\nname = "' + "a" * 100_000 + '"',
        "sensor.name (--name): String should match",
    ),
}


@pytest.mark.parametrize(("text", "needle"), HOSTILE_TOML.values(), ids=HOSTILE_TOML.keys())
def test_hostile_toml_is_a_config_error_of_one_short_line(
    tmp_path: Path, text: str, needle: str
) -> None:
    """load_config is also the SIGHUP path: a ConfigError there keeps the running config."""
    f = tmp_path / "lunad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(f)
    assert needle in str(info.value) and str(info.value).startswith(
        (f"config file {f} (--config)", f"invalid configuration ({f})")
    )
    assert len(str(info.value)) < 400 and "\n" not in str(info.value)


@pytest.mark.parametrize("case", ["arrays 5000 deep", "a hex integer of 5000 digits"])
def test_serve_refuses_hostile_toml_with_78(tmp_path: Path, helpers: Any, case: str) -> None:
    """Nested 5000 deep it was a RecursionError traceback, exit 1, which systemd
    restarts into the same crash (78 stops the restarts: RestartPreventExitStatus)."""
    f = tmp_path / "lunad.toml"
    f.write_text(HOSTILE_TOML[case][0])
    r = serve(helpers, "--config", str(f), "--device", str(tmp_path / "none"))
    assert_refused(r, str(f), HOSTILE_TOML[case][1])


# --- 4. a recording replaced while the daemon runs ----------------------------------------


@pytest.mark.parametrize("swap", ["garbage", "fifo"])
def test_a_recording_replaced_before_the_first_subscriber_is_reported_and_retried(
    start_daemon: Any, endpoint: str, tmp_path: Path, swap: str
) -> None:
    """The start-up check passed, then the file was swapped before a subscriber came:
    the open that the subscriber triggers raised RecordFormatError out of the loop
    (garbage: a traceback, exit 1) or blocked it for ever (a FIFO). It is a source that
    cannot be opened now: health says why, and the replay starts once the file is a
    recording again."""
    rec = tmp_path / "field.lunarec"
    write_recording(rec, 300)
    good = rec.read_bytes()
    d = start_daemon("--replay", str(rec), "--publish", endpoint, "--speed", "max")
    wait_for_log(d, "replay waits for a subscriber")
    if swap == "garbage":
        replace_with_text(rec, "not a recording at all\n" * 10)
        why = "not a lunad recording"
    else:
        replace_with_fifo(rec)
        why = "is a FIFO, not a regular file"
    with Subscriber(endpoint) as sub:
        bad = wait_for_health(sub, d.proc, lambda m: m.state == "reconnecting")
        assert bad.last_error is not None and why in bad.last_error, bad.last_error
        fixed = tmp_path / "fixed.lunarec"
        fixed.write_bytes(good)
        os.replace(fixed, rec)
        seen: list[Message] = []
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while not any(isinstance(m, RangeMessage) for m in seen):
            assert time.monotonic() < deadline and d.proc.poll() is None, d.log
            if (m := sub.recv(timeout_s=0.25)) is not None:
                seen.append(m)
    assert "Traceback" not in d.log, d.log
    assert d.stop() == 0, d.log  # it may have ended the recording by itself: also 0


def test_a_recording_replaced_then_reopened_by_sighup_is_reported(
    start_daemon: Any, endpoint: str, tmp_path: Path
) -> None:
    """A SIGHUP that renames the sensor reopens the source without checking the
    unchanged replay path: a recording swapped for garbage meanwhile raised
    RecordFormatError out of the loop there too."""
    rec = tmp_path / "field.lunarec"
    write_recording(rec, 3000)  # 30 s at 1x: still playing when the SIGHUP comes
    f = tmp_path / "lunad.toml"
    body = f'[source]\nkind = "replay"\npath = "{rec}"\n[publish]\nendpoint = "{endpoint}"\n'
    f.write_text('[sensor]\nname = "a"\n' + body)
    d = start_daemon("--config", str(f))
    with Subscriber(endpoint) as sub:
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while not isinstance(sub.recv(timeout_s=0.25), RangeMessage):
            assert time.monotonic() < deadline and d.proc.poll() is None, d.log
        replace_with_text(rec, "garbage\n" * 100)
        replace_with_text(f, '[sensor]\nname = "b"\n' + body)
        d.proc.send_signal(signal.SIGHUP)
        bad = wait_for_health(sub, d.proc, lambda m: m.sensor == "b" and m.state == "reconnecting")
    assert bad.last_error is not None and "not a lunad recording" in bad.last_error
    assert d.stop() == 0


# --- 5. signals while the daemon starts ---------------------------------------------------


def _wait_serving(d: Any, endpoint: str) -> None:
    with Subscriber(endpoint) as sub:
        wait_for_health(sub, d.proc, lambda m: m.state == "reconnecting")


def _wait_handlers(proc: subprocess.Popen[bytes], helpers: Any) -> None:
    """Wait until ``proc`` catches SIGHUP (``helpers.wait_caught``), and check that it
    did so before the daemon's imports (pyzmq not yet in its memory map): lunad's first
    handlers, for SIGHUP, SIGTERM and SIGINT at once, installed as ``main`` starts
    (SIGINT is the marker no more: the interpreter catches it from its own start)."""
    helpers.wait_caught(proc, signal.SIGHUP, RUN_TIMEOUT_S)
    assert "zmq" not in Path(f"/proc/{proc.pid}/maps").read_text(), (
        "lunad serve caught its first signal only after its imports"
    )


@pytest.mark.parametrize("delay_s", [0.0, 0.05, 0.1, 0.15, 0.2, 0.25])
def test_sighup_while_serve_starts_neither_kills_nor_stops_it(
    start_daemon: Any, endpoint: str, tmp_path: Path, delay_s: float, helpers: Any
) -> None:
    """SIGHUP kept its default action (end the process) until the daemon's handlers
    were installed, after the imports and the config, about 0.2 s after the start: a
    ``systemctl reload`` then killed it, and systemd, for which death by SIGHUP is a
    clean exit, left it dead. From the moment lunad's first code runs (``_wait_handlers``)
    through the imports and the config, it is noted and the daemon serves."""
    d = start_daemon("--device", str(tmp_path / "none"), "--publish", endpoint)
    _wait_handlers(d.proc, helpers)
    time.sleep(delay_s)  # the moment of the signal is what this test is about
    d.proc.send_signal(signal.SIGHUP)
    _wait_serving(d, endpoint)
    assert d.proc.poll() is None
    assert d.stop() == 0, d.log
    assert "Traceback" not in d.log, d.log


@pytest.mark.parametrize("delay_s", [0.0, 0.1, 0.25])
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_stop_while_serve_starts_exits_0(
    start_daemon: Any, endpoint: str, tmp_path: Path, delay_s: float, sig: int, helpers: Any
) -> None:
    """SIGTERM's default action ended the process (code -15) and SIGINT raised
    KeyboardInterrupt (exit 130) while it started; now both stop it cleanly, as they
    do once it runs, from the moment lunad's first code runs (``_wait_handlers``)."""
    d = start_daemon("--device", str(tmp_path / "none"), "--publish", endpoint)
    _wait_handlers(d.proc, helpers)
    time.sleep(delay_s)  # the moment of the signal is what this test is about
    d.proc.send_signal(sig)
    try:
        code = d.proc.wait(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running {RUN_TIMEOUT_S} s after {signal.Signals(sig).name}")
    assert code == 0, d.log
    assert "Traceback" not in d.log, d.log


@pytest.mark.parametrize(
    ("command", "refused"),
    [
        (["serve", "--publish", "tcp://127.0.0.1:*"], "(--publish)"),
        (["record", "--device", "/dev/null", "--out", "no-such-folder/out.lunarec"], "--out:"),
    ],
    ids=["serve", "record"],
)
def test_a_stop_while_serve_or_record_exits_keeps_its_exit_code(
    tmp_path: Path, command: list[str], refused: str
) -> None:
    """While Python shuts down it gives SIGTERM its default action back: a stop sent as
    the daemon ended by itself (a replay's end) made it exit -15. Here ``lunad serve``
    refuses its endpoint and ``lunad record`` its ``--out`` (78, after each installed
    its own stop handlers: record's come before it opens ``--out``), and an object of
    the script's own is finalized slowly after that, the moment a SIGTERM comes: the
    exit code is still 78."""
    script = (
        "import sys, time\n"
        "from lunad.daemon.cli.main import main\n"
        "class Slow:\n"
        "    def __del__(self):\n"
        "        print('finalizing', flush=True)\n"
        "        time.sleep(0.5)\n"
        "keep = Slow()\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script, *command],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == "finalizing\n"
        time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=RUN_TIMEOUT_S)
        err = proc.stderr.read() if proc.stderr else ""
        assert code == EX_CONFIG, err
        assert refused in err, err
    finally:
        proc.kill()
        proc.communicate()


# --- 6. endpoints ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("endpoint", "needle"),
    [
        ("tcp://127.0.0.1:*", "the TCP port is a wildcard (*)"),
        ("tcp://*:*", "the TCP port is a wildcard (*)"),
        ("inproc://lunad", "inproc:// reaches only sockets inside the daemon's own process"),
        ("tcp://::1:7781", "an IPv6 address goes in brackets"),
        ("tcp://[localhost]:7781", "[localhost] is not an IPv6 address"),
        ("tcp://[::1]:0", "the TCP port must be 1..65535"),
        ("tcp://127.0.0.1:7781\n", "must look like tcp://HOST:PORT"),
        ("ipc://lunad.sock", "the ipc path is relative: the daemon would bind it in its own"),
        ("ipc://./run/x.sock", "the ipc path is relative"),
    ],
)
def test_endpoints_no_subscriber_could_reach_are_refused(endpoint: str, needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(None, {"publish.endpoint": endpoint})
    assert f"publish.endpoint (--publish): {needle}" in str(info.value)


@pytest.mark.parametrize("endpoint", ["tcp://127.0.0.1:*", "inproc://lunad"])
def test_serve_refuses_them_before_binding(helpers: Any, tmp_path: Path, endpoint: str) -> None:
    """Both were bound: a port the kernel picked, or a socket only the daemon could
    reach; the daemon ran, publishing to nobody."""
    r = serve(helpers, "--device", str(tmp_path / "none"), "--publish", endpoint)
    assert_refused(r, "publish.endpoint (--publish)")


@pytest.mark.parametrize(
    ("endpoint", "ipv6"),
    [
        ("tcp://[::1]:7781", True),
        ("tcp://[::]:7781", True),
        ("tcp://[fe80::1%eth0]:7781", True),
        ("tcp://127.0.0.1:7781", False),
        ("tcp://*:7781", False),
        ("tcp://localhost:7781", False),
        ("tcp://eth0:7781", False),
        ("ipc:///run/lunad/front.sock", False),
    ],
)
def test_ipv6_endpoints_are_taken_and_known_as_ipv6(endpoint: str, ipv6: bool) -> None:
    """An IPv6 address binds only on a socket with ``zmq.IPV6`` set; the publisher asks
    ``is_ipv6_endpoint`` whether to set it."""
    from lunad.daemon.config import is_ipv6_endpoint

    assert load_config(None, {"publish.endpoint": endpoint}).publish.endpoint == endpoint
    assert is_ipv6_endpoint(endpoint) is ipv6
