"""Bad command-line input to demo, sim, sweep, watch, eval and keys: one line naming
the flag, the project's exit code, and nothing started (no virtual sensor, no daemon,
no fit)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.errors import EX_CONFIG


@pytest.mark.parametrize(
    ("flags", "complaint"),
    [
        (["--every", "0"], "argument --every: expected an integer >= 1, got 0"),
        (["--rate", "7000"], "--rate must be 500/n Hz (250, 166, 125, 100, ..., 1), got 7000"),
        (["--rate", "240"], "--rate must be 500/n Hz (250, 166, 125, 100, ..., 1), got 240"),
        (["--duration", "nan"], "argument --duration: expected a positive number, got 'nan'"),
        (["--duration", "-1"], "argument --duration: expected a positive number, got '-1'"),
        (["--duration", "0.5"], "--duration must be at least 2 s"),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else "",
)
def test_demo_refuses_a_bad_option_before_it_starts(
    helpers: Any, flags: list[str], complaint: str
) -> None:
    """A rate the daemon refuses started the virtual sensor, waited out the demo and
    reported the daemon's exit 78 as if SIGTERM had stopped it; ``--duration nan`` ran
    for ever, and ``--every 0`` reached watch()'s ``readings % every`` mid-demo."""
    r = run_lunad(helpers, "demo", *flags)
    assert r.returncode == 2, r.stderr
    assert complaint in r.stderr and "Traceback" not in r.stderr
    assert r.stdout == ""  # nothing started: no virtual sensor line, no daemon


def test_demo_tells_a_daemon_that_exited_by_itself() -> None:
    """The demo's summary said "exited ... after SIGTERM" of a daemon that had exited
    with 78 long before: a real child that ends by itself is not signalled."""
    from lunad.daemon.cli.demo import stop_daemon

    child = subprocess.Popen([sys.executable, "-c", "raise SystemExit(78)"])
    child.wait(timeout=30)
    assert stop_daemon(child) == (78, True)
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        code, by_itself = stop_daemon(child)
    finally:
        if child.poll() is None:
            child.kill()
    assert (code, by_itself) == (-signal.SIGTERM, False)


def test_sim_truth_out_in_a_missing_directory(tmp_path: Path, helpers: Any) -> None:
    out = tmp_path / "nodir" / "truth.csv"
    link = tmp_path / "tfluna"
    r = subprocess.run(
        [*helpers.lunad, "sim", "--truth-out", str(out), "--duration", "1", "--link", str(link)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == EX_CONFIG, r.stderr
    assert r.stderr == f"lunad sim: --truth-out: cannot write {out}: No such file or directory\n"
    assert r.stdout == "" and not link.exists()  # the virtual sensor never started


def run_lunad(helpers: Any, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*helpers.lunad, *args], capture_output=True, text=True, timeout=60, check=False
    )


@pytest.mark.parametrize(
    ("flags", "line"),
    [
        (["--distance", "nan"], "--distance must be within 0.01..100, got nan"),
        (["--lux", "inf"], "--lux must be within 0..200000, got inf"),
        (["--noise-scale", "nan"], "--noise-scale must be above 0 and at most 1000, got nan"),
        (["--noise-scale", "1e308"], "--noise-scale must be above 0 and at most 1000"),
        (["--scenario", "static", "--lux", "90000"], "--lux: --scenario sets the truth"),
        (["--scenario", "static", "--distance", "2"], "--distance: --scenario sets the truth"),
        (["--reflectivity", "nan", "--profile", "paper"], "--reflectivity must be within 0..10"),
        (["--angle", "95"], "--angle must be within 0..90, got 95.0"),
    ],
)
def test_sim_rejects_truth_flags_out_of_range(
    tmp_path: Path, helpers: Any, flags: list[str], line: str
) -> None:
    """A NaN or infinite truth used to kill the device thread: the sim ran mute, exit 0."""
    link = tmp_path / "tfluna"
    r = run_lunad(helpers, "sim", *flags, "--duration", "0.3", "--link", str(link))
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"lunad sim: {line}") and r.stderr.count("\n") == 1
    assert r.stdout == "" and not link.exists()


def test_sim_link_never_replaces_a_file(tmp_path: Path, helpers: Any) -> None:
    """``--link notes.txt`` used to replace the file with the symlink and delete it at exit."""
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    r = run_lunad(helpers, "sim", "--link", str(notes), "--duration", "0.3")
    assert r.returncode == 2, r.stderr
    assert r.stderr == (
        f"lunad sim: --link: cannot make {notes}: "
        "exists and is not a symlink; refusing to replace it\n"
    )
    assert r.stdout == "" and notes.read_text() == "my notes\n"


def test_sim_link_where_no_folder_can_be_made(helpers: Any) -> None:
    r = run_lunad(helpers, "sim", "--link", "/proc/no-such-pid/tfluna", "--duration", "0.3")
    assert r.returncode == 2, r.stderr
    assert r.stderr == (
        "lunad sim: --link: cannot make /proc/no-such-pid/tfluna: No such file or directory\n"
    )


def test_sim_scenario_rate_is_named_as_the_scenario_field(tmp_path: Path, helpers: Any) -> None:
    """A scenario with rate_hz = 200 was refused with a message about --rate, never given."""
    scenario = tmp_path / "rate200.toml"
    scenario.write_text("rate_hz = 200\nduration_s = 1\n")
    r = run_lunad(helpers, "sim", "--scenario", str(scenario), "--link", str(tmp_path / "x"))
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"lunad sim: --scenario: {scenario}: rate_hz must be")
    assert "--rate" not in r.stderr


def test_sim_exits_non_zero_when_the_device_thread_dies(tmp_path: Path, helpers: Any) -> None:
    """A device thread that dies (here its --truth-out is a full disk, /dev/full) used
    to leave the sim up, mute, to exit 0 at the end of --duration."""
    link = tmp_path / "tfluna"
    r = run_lunad(
        helpers, "sim", "--truth-out", "/dev/full", "--duration", "30", "--link", str(link)
    )
    assert r.returncode == 1, r.stderr
    assert r.stderr == (
        "lunad sim: the virtual sensor stopped: OSError: [Errno 28] No space left on device\n"
    )
    assert not link.exists()


def test_sweep_rejects_a_negative_seed(helpers: Any) -> None:
    """numpy refuses negative seeds: ``--seed -1`` used to end in a ValueError traceback."""
    r = run_lunad(helpers, "sweep", "--profile", "paper", "--readings", "10", "--seed", "-1")
    assert r.returncode == 2, r.stderr
    assert r.stderr.endswith(
        "lunad sweep: error: argument --seed: expected a non-negative integer, got -1\n"
    )
    assert "Traceback" not in r.stderr and r.stdout == ""


@pytest.mark.parametrize(
    ("endpoint", "why"),
    [
        ("/run/lunad/front.sock", "Invalid argument"),
        ("127.0.0.1:7781", "Invalid argument"),
        ("tcp://localhost", "Invalid argument"),
        ("tcp://127.0.0.1:99999", "the TCP port must be 1..65535"),
        ("tcp://127.0.0.1:0", "the TCP port must be 1..65535"),
    ],
)
def test_watch_rejects_an_endpoint_it_cannot_connect_to(
    helpers: Any, endpoint: str, why: str
) -> None:
    """A path or a HOST:PORT without a scheme used to end in a ZMQError traceback, exit 1;
    a port above 65535 was taken modulo 2**16 and watched, silently, the wrong port."""
    r = run_lunad(helpers, "watch", "--connect", endpoint, "--duration", "1")
    assert r.returncode == 2, r.stderr
    assert r.stderr == (
        f"lunad watch: --connect {endpoint!r}: {why}; expected tcp://HOST:PORT or ipc:///PATH\n"
    )
    assert r.stdout == ""


@pytest.mark.parametrize(
    "flags",
    [
        ["--format", "json"],
        ["--plot", "figs"],
        ["--readings", "200"],
        ["--seed", "7"],
        ["--profile", "calibrated"],
        ["--profile", "both", "--plot", "figs"],
    ],
    ids=lambda f: " ".join(f),
)
def test_sweep_fit_refuses_the_sweep_options(
    tmp_path: Path, helpers: Any, flags: list[str]
) -> None:
    """``--fit`` used to run the fit (about 15 s) and drop these without a word: no JSON,
    no plots, the same fit whatever --seed or --readings said."""
    r = subprocess.run(
        [*helpers.lunad, "sweep", "--fit", *flags],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    given = ", ".join(f for f in flags if f.startswith("--"))
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"lunad sweep: error: argument --fit: not allowed with {given} (")
    assert r.stderr.count("\n") == 1 and r.stdout == ""
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    ("flags", "complaint"),
    [
        (["--duration", "nan"], "argument --duration: expected a positive number, got 'nan'"),
        (["--duration", "-1"], "argument --duration: expected a positive number, got '-1'"),
        (["--count", "0"], "argument --count: expected an integer >= 1, got 0"),
        (["--every", "0"], "argument --every: expected an integer >= 1, got 0"),
        (["--sensor", "a/b"], "argument --sensor: expected 1-64 letters, digits"),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else "",
)
def test_watch_refuses_a_bad_option(helpers: Any, flags: list[str], complaint: str) -> None:
    """``--duration nan`` watched for ever, ``--count 0`` and a sensor name no topic can
    carry printed "0 readings" as if the daemon were silent."""
    r = run_lunad(helpers, "watch", "--connect", "tcp://127.0.0.1:7781", *flags)
    assert r.returncode == 2, r.stderr
    assert complaint in r.stderr and r.stdout == ""


@pytest.mark.parametrize(
    ("flags", "complaint"),
    [
        (["--summary", "--format", "json"], "--summary is a table; --format json gives every run"),
        (["--check", "--true-noise"], "--check judges lunad as the daemon runs it"),
    ],
    ids=["summary json", "check true-noise"],
)
def test_eval_flags_that_do_not_go_together_are_a_usage_error(
    helpers: Any, flags: list[str], complaint: str
) -> None:
    """They exited 78, the code of a bad scenario or config file, not 2."""
    r = run_lunad(helpers, "eval", *flags)
    assert r.returncode == 2, r.stderr
    assert complaint in r.stderr and r.stdout == ""


def test_keys_into_a_file_says_it_is_not_a_directory(tmp_path: Path, helpers: Any) -> None:
    """It said "cannot write ...: File exists", of a folder it was asked to make."""
    f = tmp_path / "server"
    f.write_text("mine\n")
    r = run_lunad(helpers, "keys", "server", str(f))
    assert r.returncode == 1, r.stderr
    assert r.stderr == f"lunad keys: {f}: not a directory: give the folder the key pair goes in\n"
    assert f.read_text() == "mine\n"


def test_record_says_once_that_its_device_is_absent(tmp_path: Path, helpers: Any) -> None:
    """``lunad record`` on an absent port logged a warning on every retry, one every
    2 s for ever; as ``serve`` does, it says so once, then once a minute."""
    out = tmp_path / "absent.lunarec"
    r = run_lunad(
        helpers,
        "record",
        "--device",
        str(tmp_path / "nothing"),
        "--duration",
        "6",
        "--out",
        str(out),
    )
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "cannot open" in line]
    assert len(said) == 1 and "retrying every 2.0 s at most" in said[0], r.stderr


def _sim_up(helpers: Any, link: Path) -> subprocess.Popen[str]:
    """``lunad sim --link link``, once it says it is up (its link made)."""
    p = subprocess.Popen(
        [*helpers.lunad, "sim", "--link", str(link)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert p.stdout is not None and "virtual TF-Luna on" in p.stdout.readline()
    return p


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGTERM, signal.SIGINT], ids=str)
def test_sim_removes_its_link_on_a_hangup_as_on_a_stop(
    tmp_path: Path, helpers: Any, sig: signal.Signals
) -> None:
    """Killed by SIGHUP (its terminal closed), the sim left its link to a pty number the
    next pty takes: a daemon opening the link read another sim. It stops as on SIGTERM:
    the link goes, the summary is printed, exit 0."""
    link = tmp_path / "tfluna"
    p = _sim_up(helpers, link)
    try:
        assert link.is_symlink()
        p.send_signal(sig)
        out, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "good frames" in out and not os.path.lexists(link)


@pytest.mark.parametrize("delay_s", [0.0, 0.1, 0.25])
@pytest.mark.parametrize(
    ("command", "sig"),
    [
        ("record", signal.SIGTERM),
        ("record", signal.SIGINT),
        ("sim", signal.SIGTERM),
        ("sim", signal.SIGHUP),
        ("watch", signal.SIGTERM),
        ("watch", signal.SIGINT),
    ],
    ids=lambda v: v if isinstance(v, str) else signal.Signals(v).name,
)
def test_a_stop_while_a_tool_starts_exits_0(
    tmp_path: Path, helpers: Any, command: str, sig: int, delay_s: float
) -> None:
    """A stop in the first 0.3 s of ``lunad record`` ended it by the signal (143, or a
    KeyboardInterrupt traceback), where its help says exit 0; so did ``sim`` and
    ``watch``. From the moment lunad's first code runs, a stop is noted and acted on
    once the command's own handlers are in place: exit 0, and a sim leaves no link."""
    link = tmp_path / "tfluna"
    args = {
        "record": ["--device", str(tmp_path / "none"), "--out", str(tmp_path / "r.lunarec")],
        "sim": ["--link", str(link)],
        "watch": ["--connect", f"ipc://{tmp_path}/nobody.sock"],
    }[command]
    p = subprocess.Popen(
        [*helpers.lunad, command, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        helpers.wait_caught(p, signal.SIGTERM)
        assert "pydantic_core" not in Path(f"/proc/{p.pid}/maps").read_text(), (
            "caught its first SIGTERM only after its imports"
        )
        time.sleep(delay_s)  # the moment of the signal is what this test is about
        p.send_signal(sig)
        _, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "Traceback" not in err and not os.path.lexists(link), err


def test_a_second_stop_while_the_sim_stops_is_ignored(tmp_path: Path, helpers: Any) -> None:
    """A second Ctrl-C while the sim removed its link got the signal's default action
    back from Python's shutdown, and ended it by the signal; it is ignored once the
    first has stopped it."""
    link = tmp_path / "tfluna"
    for _ in range(3):
        p = _sim_up(helpers, link)
        try:
            p.send_signal(signal.SIGINT)
            for _ in range(20):
                time.sleep(0.005)
                if p.poll() is not None:
                    break
                p.send_signal(signal.SIGTERM)
            _, err = p.communicate(timeout=30)
        finally:
            p.kill()
        assert p.returncode == 0, err
        assert not os.path.lexists(link), err


def test_record_over_i2c_names_the_bus_in_its_header(tmp_path: Path, helpers: Any) -> None:
    """``lunad record --bus`` wrote "i2c /dev/serial0" into the header, the serial
    default; it names the bus and address, as ``serve --record`` does."""
    from lunad.daemon.sources.recording import Replay

    out = tmp_path / "i2c.lunarec"
    r = run_lunad(helpers, "record", "--bus", "sim", "--duration", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    with Replay(out) as rep:
        assert rep.header.source_desc == "i2c bus sim address 0x10"


@pytest.mark.parametrize(
    ("command", "line"),
    [
        (
            ["eval", "--noise-scale", "1e308"],
            "argument --noise-scale: at most 1000, got '1e308'",  # an OverflowError, exit 1
        ),
        (
            ["sweep", "--readings", "1000000000"],
            "argument --readings: at most 100000, got '1000000000'",  # past 5 GB in 15 s
        ),
        (
            ["soak", "--duration", "100000h"],
            "--duration: '100000h' is over a week (168h), the longest soak",  # 1.2 GB in 12 s
        ),
    ],
    ids=lambda v: v[0] if isinstance(v, list) else "",
)
def test_sizes_past_what_a_machine_holds_are_bad_options(
    helpers: Any, command: list[str], line: str
) -> None:
    r = run_lunad(helpers, *command)
    assert r.returncode == 2, r.stderr
    assert line in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_second_sim_on_a_running_sims_link_is_refused(tmp_path: Path, helpers: Any) -> None:
    """A second ``lunad sim`` on the same --link took the link over without a word, and
    removed it when it ended: the first sim, still running, had no link left."""
    link = tmp_path / "tfluna"
    first = _sim_up(helpers, link)
    try:
        target = os.readlink(link)
        r = run_lunad(helpers, "sim", "--link", str(link), "--duration", "1")
        assert r.returncode == 2, r.stderr
        assert r.stderr == (
            f"lunad sim: --link: {link} points at {target}, a pty still open (another "
            "lunad sim?); stop that one, give another --link, or remove the link\n"
        )
        assert os.readlink(link) == target and first.poll() is None
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=30)
    finally:
        first.kill()
    assert first.returncode == 0 and not os.path.lexists(link)
    r = run_lunad(helpers, "sim", "--link", str(link), "--duration", "0.5")  # free again
    assert r.returncode == 0, r.stderr
