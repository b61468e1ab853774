"""`lunad calibrate` through the real pty: amp_ref measured and written into the config."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.cmd_calibrate import compute, write_amp_ref
from lunad.daemon.config import load_config
from lunad.sim.physics import AMP_REF, RealisticSensor, Truth
from lunad.sim.pty_device import PtyDevice


def write_amp_ref_argv(helpers: Any, cfg: Path, seconds: str) -> list[str]:
    """``lunad calibrate --write`` into ``cfg`` for a 0.9 target at 2 m."""
    return [
        *helpers.lunad, "calibrate", "--config", str(cfg), "--reflectivity", "0.9",
        "--distance", "2.0", "--seconds", seconds, "--write",
    ]  # fmt: skip


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
        write_amp_ref_argv(helpers, cfg, seconds="1"),
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


@pytest.mark.parametrize(
    "header",
    [
        "[filter]  # tuned on the bench",
        "[ filter ]  # inner spaces",
        '  ["filter"]\t# quoted key',
        "[filter]#x",
    ],
)
def test_write_finds_a_filter_header_toml_allows(tmp_path: Path, header: str) -> None:
    """A header with a comment or inner spaces is still [filter]: no second table."""
    f = tmp_path / "a.toml"
    f.write_text(f'[sensor]\nname = "x"\n\n{header}\namp_ref = 2000.0\ns_min = 0.05\n')
    write_amp_ref(f, 1500.0)
    cfg = load_config(f)
    assert cfg.filter.to_filter_config().amp_ref == 1500.0
    assert f.read_text().count("amp_ref") == 1 and header in f.read_text()


def test_write_tells_other_tables_and_arrays_from_filter(tmp_path: Path) -> None:
    """[filter.sub], [[array]] and a nested array's rows do not open or close [filter]."""
    f = tmp_path / "a.toml"
    f.write_text(
        "[filter]\nrows = [\n  [1, 2],\n  [3, 4],\n]\n\n[[probe]]\nx = 1\n\n[filter.sub]\ny = 2\n"
    )
    write_amp_ref(f, 1500.0)
    data = tomllib.loads(f.read_text())
    assert data["filter"]["amp_ref"] == 1500.0 and data["filter"]["rows"] == [[1, 2], [3, 4]]
    assert data["filter"]["sub"] == {"y": 2} and data["probe"] == [{"x": 1}]


def test_write_refuses_a_layout_it_cannot_edit(tmp_path: Path) -> None:
    """[[filter]] is an array of tables, not [filter]: refuse and leave the file alone."""
    f = tmp_path / "a.toml"
    before = "[[filter]]\namp_ref = 2000.0\n"
    f.write_text(before)
    with pytest.raises(ValueError, match="by hand"):
        write_amp_ref(f, 1500.0)
    assert f.read_text() == before and os.listdir(tmp_path) == ["a.toml"]


def test_write_keeps_the_file_mode(tmp_path: Path) -> None:
    """The daemon's user must still read the file: 0644 stays 0644, 0640 stays 0640."""
    for mode in (0o644, 0o640):
        f = tmp_path / f"{mode:o}.toml"
        f.write_text("[filter]\namp_ref = 2000.0\n")
        f.chmod(mode)
        write_amp_ref(f, 1500.0)
        assert stat.S_IMODE(f.stat().st_mode) == mode
    old_umask = os.umask(0o022)
    try:
        write_amp_ref(tmp_path / "new.toml", 1500.0)
    finally:
        os.umask(old_umask)
    assert stat.S_IMODE((tmp_path / "new.toml").stat().st_mode) == 0o644


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can give a file to another owner")
def test_write_as_root_keeps_owner_and_group(tmp_path: Path) -> None:
    f = tmp_path / "a.toml"
    f.write_text("[filter]\namp_ref = 2000.0\n")
    os.chown(f, 4321, 8765)
    write_amp_ref(f, 1500.0)
    st = f.stat()
    assert (st.st_uid, st.st_gid) == (4321, 8765)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_aborts_and_writes_nothing(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any, sig: signal.Signals
) -> None:
    """Ctrl-C mid-measurement is not 'use what you have': no result, file untouched."""
    dev = device(rate_hz=250, output_enabled=False)
    cfg = tmp_path / "front.toml"
    before = f'[source]\ndevice = "{dev.path}"\n\n[filter]\namp_ref = 1234.0\n'
    cfg.write_text(before)
    proc = subprocess.Popen(
        write_amp_ref_argv(helpers, cfg, seconds="60"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + helpers.startup_s
        while dev.frames_sent < 250:  # streaming starts when calibrate configures the sensor
            assert time.monotonic() < deadline, "calibrate never started the sensor"
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            time.sleep(0.05)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + sig, err
    assert f"lunad calibrate: {sig.name}: measurement aborted, nothing written" in err
    assert "amp_ref" not in out and cfg.read_text() == before


def test_write_follows_a_symlinked_config(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    """``--write`` through a link used to replace the link with a copy, leaving the file
    it named, the maintained one, with the old amp_ref."""
    dev = device(
        rate_hz=250,
        output_enabled=False,
        model=RealisticSensor(),
        truth=Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=100.0),
    )
    (tmp_path / "repo").mkdir()
    (tmp_path / "etc").mkdir()
    real = tmp_path / "repo" / "front.toml"
    real.write_text(f'[source]\ndevice = "{dev.path}"\n\n[filter]\namp_ref = 1234.0\n')
    real.chmod(0o640)
    link = tmp_path / "etc" / "front.toml"
    link.symlink_to(Path("..") / "repo" / "front.toml")
    r = subprocess.run(
        write_amp_ref_argv(helpers, link, seconds="1"), capture_output=True, text=True, timeout=30
    )
    assert r.returncode == 0, r.stderr
    assert link.is_symlink() and link.resolve() == real.resolve()
    amp_ref = load_config(real).filter.to_filter_config().amp_ref
    assert amp_ref == pytest.approx(AMP_REF, rel=0.03)
    assert stat.S_IMODE(real.stat().st_mode) == 0o640
    assert os.listdir(tmp_path / "etc") == ["front.toml"]
    assert os.listdir(tmp_path / "repo") == ["front.toml"]


@pytest.mark.parametrize(
    ("flags", "line"),
    [
        (["--reflectivity", "1.5"], "--reflectivity must be above 0 and at most 1, got 1.5"),
        (["--reflectivity", "0"], "--reflectivity must be above 0 and at most 1, got 0.0"),
        (["--reflectivity", "nan"], "--reflectivity must be above 0 and at most 1, got nan"),
        (["--distance", "0"], "--distance must be positive and finite (metres), got 0.0"),
        (["--distance", "-2"], "--distance must be positive and finite (metres), got -2.0"),
        (["--distance", "inf"], "--distance must be positive and finite (metres), got inf"),
        (["--angle", "90"], "--angle must be at least 0 and below 90 degrees, got 90.0"),
        (["--angle", "-10"], "--angle must be at least 0 and below 90 degrees, got -10.0"),
        (["--seconds", "0"], "--seconds must be positive and finite, got 0.0"),
        (["--seconds", "nan"], "--seconds must be positive and finite, got nan"),
    ],
)
def test_bad_measurement_flags_are_refused_before_the_sensor_opens(
    tmp_path: Path, helpers: Any, flags: list[str], line: str
) -> None:
    """``--reflectivity 1.5`` used to be refused only after ``--seconds`` of measuring
    (exit 1), and ``--distance 0`` or ``-2`` was taken. No sensor here: the flags are
    checked before one is opened, so the missing device is never reached."""
    argv = [
        *helpers.lunad, "calibrate", "--device", str(tmp_path / "no-sensor"),
        "--reflectivity", "0.9", "--distance", "2", "--seconds", "60", *flags,
    ]  # fmt: skip
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    assert r.returncode == 78, r.stderr
    assert r.stderr == f"lunad calibrate: {line}\n" and r.stdout == ""
