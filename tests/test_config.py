"""Config: TOML + flags, and every mistake named by field with exit code 78."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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
    ],
)
def test_errors_name_the_field(tmp_path: Path, text: str, overrides: dict, needle: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(f, overrides)
    assert needle in str(info.value)


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
        ["--bogus-flag"],
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
    assert cfg.model_dump(exclude={"filter"}) == default.model_dump(exclude={"filter"})
    text = path.read_text()
    missing = [f.name for f in dataclasses.fields(FilterConfig) if f"\n{f.name} =" not in text]
    assert not missing, f"example config lacks filter keys {missing}"
