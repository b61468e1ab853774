"""Config: TOML + flags, and every mistake named by field with exit code 78."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.config import load_config
from lunad.daemon.errors import ConfigError

LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]


def test_defaults() -> None:
    cfg = load_config(None)
    assert cfg.source.device == "/dev/serial0" and cfg.source.baud == 115200
    assert cfg.publish.endpoint == "tcp://127.0.0.1:7781" and cfg.sensor.name == "tfluna"


def test_file_and_flags(tmp_path: Path) -> None:
    f = tmp_path / "front.toml"
    f.write_text(
        '[sensor]\nname = "front"\n[source]\ndevice = "/dev/ttyUSB0"\nbaud = 230400\n'
        "[filter]\namp_ref = 1500\n"
    )
    cfg = load_config(f, {"source.baud": "115200", "publish.endpoint": None})
    assert cfg.sensor.name == "front" and cfg.source.device == "/dev/ttyUSB0"
    assert cfg.source.baud == 115200  # the flag wins
    assert cfg.filter.to_filter_config().amp_ref == 1500.0


@pytest.mark.parametrize(
    ("text", "overrides", "needle"),
    [
        ("[source]\nbaud = 12\n", {}, "source.baud (--baud): must be one of 9600"),
        ("", {"source.baud": "fast"}, "source.baud (--baud)"),
        ("[sensor]\nframe_rate_hz = 99\n", {}, "sensor.frame_rate_hz (--rate): must be 500/n"),
        ('[sensor]\nname = "a b"\n', {}, "sensor.name (--name)"),
        ('[publish]\nendpoint = "http://x"\n', {}, "publish.endpoint (--publish): must look like"),
        ('[source]\ndevcie = "/dev/x"\n', {}, "source.devcie: unknown key"),
        ("[filter]\nampref = 3\n", {}, "filter.ampref: unknown key; allowed: amp_ref"),
        ('[filter]\namp_ref = "big"\n', {}, "filter.amp_ref: must be a number, got 'big'"),
        ("[filter]\nstep_confirm = inf\n", {}, "filter.step_confirm: must be an integer, got inf"),
        ("[filter]\nstep_confirm = nan\n", {}, "filter.step_confirm: must be an integer, got nan"),
        ("[filter]\nstep_confirm = 2.7\n", {}, "filter.step_confirm: must be an integer, got 2.7"),
        ("[filter]\namp_ref = inf\n", {}, "filter.amp_ref: must be a finite number, got inf"),
        ("[filter]\namp_ref = nan\n", {}, "filter.amp_ref: must be a finite number, got nan"),
        ("[filter]\nk_m_per_lux = 1e-320\n", {}, "k_m_per_lux must be between 1e-09 and 1e+09"),
        ("[filter]\naccel_psd = 1e300\n", {}, "accel_psd must be 0 or between 1e-09 and 1e+09"),
        ("[source\n", {}, "is not valid TOML"),
        ("", {"publish.endpoint": "tcp://127.0.0.1:99999"}, "the TCP port must be 1..65535"),
        ("", {"publish.endpoint": "tcp://*:0"}, "publish.endpoint (--publish): the TCP port"),
        ("[sensor]\nframe_rate_hz = true\n", {}, "frame_rate_hz (--rate): must be a number"),
        ("[publish]\nsndhwm = true\n", {}, "publish.sndhwm: must be a number, not true"),
        # A quoted number or boolean in a file is a string, refused as [filter] refuses
        # one; pydantic would convert it (flags, which are strings, still are).
        ('[sensor]\nframe_rate_hz = "250"\n', {}, "frame_rate_hz (--rate): must be a number, not"),
        (
            '[sensor]\nconfigure = "off"\n',
            {},
            "sensor.configure (--no-configure): must be true or false, not a",
        ),
        ('[publish]\nhealth_interval_s = "0.5"\n', {}, "health_interval_s: must be a number"),
        ('[publish]\nsndhwm = "10"\n', {}, "publish.sndhwm: must be a number, not a string"),
        ('[source]\nbaud = "115200"\n', {}, "source.baud (--baud): must be a number, not"),
        ("[publish]\nhealth_interval_s = 1e-9\n", {}, "publish.health_interval_s: must be 0.05"),
        ("[publish]\npublish_hz = true\n", {}, "publish_hz (--publish-hz): must be a number"),
        ("", {"publish.publish_hz": "1e-300"}, "publish_hz (--publish-hz): must be 0.01..250"),
        ("[source]\nrate_hz = 999\n", {}, "source.rate_hz: unknown key; the frame rate is"),
        ("", {"source.record": ""}, "source.record (--record): String should have at least"),
        ("", {"source.kind": "replay", "source.path": ""}, "source.path (--replay): String"),
        (
            "",
            {"source.device": "foo://bar"},
            "source.device (--device): URL scheme 'foo': pyserial has no handler",
        ),
        ("[filter]\nlux_init = -100\n", {}, "lux_init must be 0 or more, got -100"),
        # A URL whose handler exists but whose host, port or options cannot parse fails
        # every open: refused at start, not retried every 2 s for ever.
        ("", {"source.device": "socket://"}, "URL does not parse: expected socket://HOST:PORT"),
        ("", {"source.device": "socket://127.0.0.1:99999"}, "URL does not parse: expected"),
        ("", {"source.device": "rfc2217://h:99999"}, "does not parse: expected a string in"),
        ("", {"source.device": "alt:///dev/null?class=Nope"}, "unknown class: 'Nope'"),
        ("", {"source.device": "spy://socket://"}, "URL does not parse: expected socket://"),
        ("[filter]\namp_min = 70000\n", {}, "amp_min must be at most 32768 (an amp above"),
        ("", {"source.speed": "1e-9"}, "source.speed (--speed): must be a factor from 0.01"),
        ("[filter]\nstep_confirm = 1000000000\n", {}, "step_confirm must be at most 100000"),
        ("[filter]\nnoise_slow_frames = 99999999999\n", {}, "noise_slow_frames must be at most"),
        ("[source]\naddress = 0x99\n", {}, "from 0x08 to 0x77 (M05 p.13), got 0x99"),
        ("", {"source.address": "3"}, "source.address (--address): must be an I2C address from"),
        (
            "[filter]\nnoise_frames = 300\n",
            {},
            "noise_slow_frames (250) must be at least noise_frames (300)",
        ),
        ("[filter]\namp_ref = 1" + "0" * 400 + "\n", {}, "amp_ref: must be a finite number"),
    ],
)
def test_errors_name_the_field(tmp_path: Path, text: str, overrides: dict, needle: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(f if text else None, overrides)  # flags alone: no file
    assert needle in str(info.value)


def test_flags_are_strings_text_keeps_its_quotes_and_good_urls_load(tmp_path: Path) -> None:
    """Command-line flags reach the config as strings and are converted; in a file, the
    keys whose values are text take quotes as before: an I2C address, a replay's
    ``speed = "max"``."""
    cfg = load_config(None, {"sensor.frame_rate_hz": "250", "source.baud": "230400"})
    assert (cfg.sensor.frame_rate_hz, cfg.source.baud) == (250, 230400)
    f = tmp_path / "quoted.toml"
    f.write_text(
        '[source]\nkind = "replay"\npath = "a.lunarec"\nspeed = "max"\naddress = "0x11"\n'
        '[sensor]\nname = "front"\n'
    )
    cfg = load_config(f)
    assert cfg.source.speed is None and cfg.source.address == 0x11
    for url in ("socket://127.0.0.1:7000", "loop://", "spy:///dev/ttyAMA0", "rfc2217://h:80"):
        assert load_config(None, {"source.device": url}).source.device == url


def test_the_i2c_rate_is_the_sensor_rate_and_a_bad_one_is_named_once() -> None:
    """``source.rate_hz`` is a copy of ``sensor.frame_rate_hz`` for the I2C source to
    pace itself by; set by hand it went unchecked (999 Hz crashed the daemon's loop)."""
    assert load_config(None, {"sensor.frame_rate_hz": "250"}).source.rate_hz == 250
    assert load_config(None).source.rate_hz == load_config(None).sensor.frame_rate_hz
    with pytest.raises(ConfigError) as info:
        load_config(None, {"source.kind": "i2c", "source.bus": "sim", "sensor.frame_rate_hz": "a"})
    assert "sensor.frame_rate_hz (--rate)" in str(info.value)
    assert "rate_hz" not in str(info.value).replace("sensor.frame_rate_hz", "")


def test_output_format_is_cm_or_mm_and_cm_only_over_i2c() -> None:
    """[sensor] output_format picks the unit the parser reads and start-up sets; the
    I2C distance registers are centimetres, so mm there is refused, naming the field."""
    from lunad.protocol.frame import OutputFormat

    assert load_config(None).sensor.frame_format is OutputFormat.CM
    mm = load_config(None, {"sensor.output_format": "mm"})
    assert mm.sensor.frame_format is OutputFormat.MM
    with pytest.raises(ConfigError) as info:
        load_config(None, {"sensor.output_format": "inch"})
    assert "sensor.output_format (--output-format)" in str(info.value)
    with pytest.raises(ConfigError) as info:
        load_config(None, {"source.kind": "i2c", "source.bus": "sim", "sensor.output_format": "mm"})
    assert "sensor.output_format (--output-format): must be cm over I2C" in str(info.value)


def test_a_replay_cannot_record_into_itself(tmp_path: Path) -> None:
    """Recording into the file being replayed fed the replay its own output: 5 kB grew
    to 4.5 MB in 7 s and never ended. Any spelling of the same file is refused."""
    rec = tmp_path / "field.lunarec"
    rec.write_bytes(b"")
    (tmp_path / "link.lunarec").symlink_to(rec)
    for record in (str(rec), str(tmp_path / "." / rec.name), str(tmp_path / "link.lunarec")):
        with pytest.raises(ConfigError, match=r"\(--record\) is the recording being replayed"):
            load_config(
                None, {"source.kind": "replay", "source.path": str(rec), "source.record": record}
            )
    other = {"source.kind": "replay", "source.path": str(rec), "source.record": str(rec) + ".2"}
    assert load_config(None, other).source.record == str(rec) + ".2"


def test_missing_file() -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_config("/nonexistent/lunad.toml")


@pytest.mark.parametrize(
    "args",
    [
        ["--baud", "12"],
        ["--rate", "abc"],
        ["--config", "/nonexistent.toml"],
        ["--publish", "nonsense"],
        ["--publish", "tcp://127.0.0.1:*"],  # a port the kernel picks: nobody could find it
        ["--publish", "inproc://lunad"],  # reachable only from inside the daemon
        ["--bogus-flag"],
        ["--bus", "sim"],  # with the --device every case here gives: two sources
        ["--replay", ""],
        ["--record", ""],
    ],
)
def test_serve_exits_78_with_one_clear_message(args: list[str], tmp_path: Path) -> None:
    r = subprocess.run(
        [*LUNAD, "serve", "--device", str(tmp_path / "none"), *args],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 78, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.strip() and r.stdout == ""
    assert not list(tmp_path.iterdir())  # nothing was opened or created


def test_example_config_loads_and_lists_every_filter_key() -> None:
    import dataclasses

    from lunad.filters import FilterConfig

    path = Path(__file__).parent.parent / "systemd" / "lunad.toml.example"
    cfg, default = load_config(path), load_config(None)
    assert cfg.filter.to_filter_config() == FilterConfig()  # the example shows the defaults
    # the service's endpoint is the ipc socket robot code in group lunad reads (docs/
    # security.md); a manual `lunad serve` defaults to loopback TCP
    assert cfg.publish.endpoint == "ipc:///run/lunad/front.sock"
    ex: dict[str, Any] = {"filter": True, "publish": {"endpoint"}}
    assert cfg.model_dump(exclude=ex) == default.model_dump(exclude=ex)
    text = path.read_text()
    missing = [f.name for f in dataclasses.fields(FilterConfig) if f"\n{f.name} =" not in text]
    assert not missing, f"example config lacks filter keys {missing}"


@pytest.mark.parametrize(
    "device", ["/dev/serial0", "socket://127.0.0.1:7000", "LOOP://", "spy:///dev/ttyAMA0"]
)
def test_a_device_is_a_path_or_a_url_pyserial_opens(device: str) -> None:
    """``foo://bar`` was retried every 2 s for ever ("protocol 'foo' not known")."""
    assert load_config(None, {"source.device": device}).source.device == device


@pytest.mark.parametrize(
    ("device", "why"),
    [
        ("/dev/a://b", "a device path cannot contain '://'"),
        ("Foo://bar", "URL scheme 'foo': pyserial has no handler for it"),
    ],
)
def test_a_device_url_that_cannot_open_says_why(device: str, why: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(None, {"source.device": device})
    assert f"source.device (--device): {why}; give a device path" in str(info.value)
