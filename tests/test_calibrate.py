"""`lunad calibrate` through the real pty: amp_ref measured and written into the config."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.cmd_calibrate import compute, write_amp_ref
from lunad.daemon.config import load_config
from lunad.sim.physics import AMP_REF, RealisticSensor, Truth
from lunad.sim.pty_device import PtyDevice


def test_compute_uses_median_of_usable_readings() -> None:
    readings = [(2.0, 1800)] * 30 + [(0.0, 50)] * 10 + [(2.0, 40000)] * 5 + [(9.9, 1700)]
    cal = compute(readings, 0.9, 0.0)
    assert cal.median_amp == 1800 and cal.amp_ref == pytest.approx(2000)
    assert cal.used == 31 and cal.rejected == 15
    assert compute(readings, 0.9, 60.0).amp_ref == pytest.approx(4000)
    with pytest.raises(ValueError, match="usable"):
        compute([(0.0, 10)] * 100, 0.9, 0.0)
    with pytest.raises(ValueError, match="R cos"):
        compute(readings, 0.9, 95.0)


def test_write_keeps_comments_and_other_keys(tmp_path: Path) -> None:
    f = tmp_path / "a.toml"
    f.write_text(
        '# mine\n[sensor]\nname = "x"\n\n[filter]\namp_ref = 2000.0  # old\ns_min = 0.05\n'
    )
    write_amp_ref(f, 1234.56)
    text = f.read_text()
    assert "# mine" in text and "s_min = 0.05" in text and "# old" in text
    assert load_config(f).filter.to_filter_config().amp_ref == pytest.approx(1234.6)
    g = tmp_path / "b.toml"
    g.write_text('[sensor]\nname = "y"\n')
    write_amp_ref(g, 999.0)
    assert load_config(g).filter.to_filter_config().amp_ref == 999.0
    assert load_config(g).sensor.name == "y"


def test_calibrate_on_the_virtual_sensor(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    dev = device(
        rate_hz=250,
        output_enabled=False,
        model=RealisticSensor(),
        truth=Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=100.0),
    )
    cfg = tmp_path / "front.toml"
    cfg.write_text(f'[source]\ndevice = "{dev.path}"\n')
    r = subprocess.run(
        [
            *helpers.lunad,
            "calibrate",
            "--config",
            str(cfg),
            "--reflectivity",
            "0.9",
            "--distance",
            "2.0",
            "--seconds",
            "1",
            "--write",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 0, r.stderr
    amp_ref = load_config(cfg).filter.to_filter_config().amp_ref
    assert amp_ref == pytest.approx(AMP_REF, rel=0.03)  # the simulator's truth, recovered
    assert "warning" not in r.stderr
    assert f'source]\ndevice = "{dev.path}"' in cfg.read_text()


def test_calibrate_warns_when_the_distance_disagrees(
    device: Callable[..., PtyDevice], helpers: Any
) -> None:
    dev = device(
        rate_hz=250,
        output_enabled=False,
        truth=Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=0.0),
    )
    r = subprocess.run(
        [
            *helpers.lunad,
            "calibrate",
            "--device",
            dev.path,
            "--reflectivity",
            "0.9",
            "--distance",
            "3.0",
            "--seconds",
            "0.5",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 0 and "warning: the sensor reads 2.0" in r.stderr


def test_write_without_config_is_a_usage_error(helpers: Any) -> None:
    r = subprocess.run(
        [*helpers.lunad, "calibrate", "--reflectivity", "0.9", "--distance", "1", "--write"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 78 and "--write needs --config" in r.stderr
