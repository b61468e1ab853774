"""`lunad calibrate` through the real pty: amp_ref, sigma0 and k measured and written into
the config."""

from __future__ import annotations

import errno
import os
import random
import re
import signal
import stat
import subprocess
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.cli.calibrate import LUX_MAX, compute, write_filter_values
from lunad.daemon.config import load_config
from lunad.filters import FilterConfig
from lunad.sim import scenario
from lunad.sim.physics import (
    AMP_REF,
    REALISTIC_K_M_PER_LUX,
    REALISTIC_SIGMA0_M,
    RealisticSensor,
    Truth,
)
from lunad.sim.pty_device import PtyDevice


def write_amp_ref_argv(helpers: Any, cfg: Path, seconds: str) -> list[str]:
    """``lunad calibrate --write`` into ``cfg`` for a 0.9 target at 2 m."""
    return [
        *helpers.lunad, "calibrate", "--config", str(cfg), "--reflectivity", "0.9",
        "--distance", "2.0", "--seconds", seconds, "--write",
    ]  # fmt: skip


def test_compute_uses_median_of_usable_readings() -> None:
    readings = [(2.0, 1800)] * 30 + [(0.0, 50)] * 10 + [(2.0, 40000)] * 5 + [(9.9, 1700)]
    cal = compute(readings, 0.9, 0.0, 2.0)
    assert cal.median_amp == 1800 and cal.amp_ref == pytest.approx(2000)
    assert cal.used == 31 and cal.rejected == 15
    assert compute(readings, 0.9, 60.0, 2.0).amp_ref == pytest.approx(4000)
    with pytest.raises(ValueError, match="usable"):
        compute([(0.0, 10)] * 100, 0.9, 0.0, 2.0)
    with pytest.raises(ValueError, match="R cos"):
        compute(readings, 0.9, 95.0, 2.0)


def test_amp_ref_is_for_a_white_target_at_2_m_wherever_it_was_measured() -> None:
    """S = R cos(angle) (2 m / d)^2: a grey card at 3 m and a white one at 1 m give the
    amp_ref of a white one at 2 m (the simulator's amp falls with d^2, as S does)."""
    grey_far = compute([(3.0, 267)] * 50, 0.3, 0.0, 3.0)
    assert grey_far.amp_ref == pytest.approx(2000, rel=0.01)
    assert grey_far.strength == pytest.approx(0.3 * 4 / 9)
    assert compute([(1.0, 7200)] * 50, 0.9, 0.0, 1.0).amp_ref == pytest.approx(2000)


def still_target(
    c_m: float, strength: float, n: int = 5000, seed: int = 0
) -> list[tuple[float, int]]:
    """(distance_m, amp) readings of a still target at 3 m with noise c / S, whole cm."""
    rng = random.Random(seed)
    amp = round(2000 * strength)
    return [(round(3.0 + rng.gauss(0.0, c_m / strength), 2), amp) for _ in range(n)]


def test_compute_measures_sigma0_in_the_dark_and_k_under_light() -> None:
    sigma0, k = 0.004, 2.5e-7
    dark = compute(still_target(sigma0, 0.15), 0.15, 0.0, 2.0, lux=0.0)
    assert dark.sigma0 is not None and dark.k is None and dark.not_measured is None
    assert dark.sigma0.value == pytest.approx(sigma0, rel=0.05) and dark.sigma0.err < 1e-4
    lit = still_target(sigma0 + k * 30_000, 0.15, seed=1)
    fitted = compute(lit, 0.15, 0.0, 2.0, lux=30_000.0, fit_k=True)
    assert fitted.k is not None and fitted.sigma0 is None
    assert fitted.k.value == pytest.approx(k, rel=0.1) and fitted.k.err < 1e-8
    # sigma0 = c - k L with the configured k gives the same sigma0 under that light
    lit_sigma0 = compute(lit, 0.15, 0.0, 2.0, lux=30_000.0).sigma0
    assert lit_sigma0 is not None and lit_sigma0.value == pytest.approx(sigma0, rel=0.1)


def test_compute_says_why_a_noise_figure_is_not_measured() -> None:
    strong = compute(still_target(0.004, 4.0), 1.0, 0.0, 1.0)
    assert strong.sigma0 is None and strong.not_measured is not None
    assert strong.not_measured.startswith(
        "sigma0_m not measured: the noise is below the 1 cm step here ("
    )
    assert (
        "calibrate sigma0 on a darker or farther target (S about 0.3-0.5: this one at 2.8-3.7 m)"
        in strong.not_measured
    )
    assert strong.amp_ref == pytest.approx(2000)  # amp_ref is measured all the same
    quiet = compute(still_target(0.0008, 0.2), 0.2, 0.0, 2.0)  # quieter than the datasheet
    assert "(this one's S is 0.2 already: farther still, or darker)" in (quiet.not_measured or "")
    # a lux figure that explains all of the noise: no sigma0 of about 0 is stored
    bright = compute(still_target(0.004, 0.15), 0.15, 0.0, 2.0, lux=16_000.0)
    assert bright.sigma0 is None and "explains the noise" in (bright.not_measured or "")
    # no more noise under the light than sigma0 alone: no k
    unlit = compute(still_target(0.004, 0.15), 0.15, 0.0, 2.0, lux=30_000.0, fit_k=True)
    assert unlit.k is None and "k_m_per_lux not measured" in (unlit.not_measured or "")
    with pytest.raises(ValueError, match="lux"):
        compute(still_target(0.004, 0.15), 0.15, 0.0, 2.0, fit_k=True)
    configured = FilterConfig(sigma0_m=0.002)
    more = compute(
        still_target(0.004, 0.15), 0.15, 0.0, 2.0, lux=8000.0, fit_k=True, filter_cfg=configured
    )
    assert more.k is not None and more.k.value == pytest.approx(2.5e-7, rel=0.1)


def test_write_edits_only_its_keys_in_place(tmp_path: Path) -> None:
    """A key already there keeps its place and comment; a new one goes after the
    table's last setting, not under the next table's comment."""
    f = tmp_path / "a.toml"
    before = [
        "# front sensor",
        "[filter]",
        "amp_ref = 2000.0              # amp for strength S = 1",
        "sigma0_m = 0.004              # metres at zero ambient light and S = 1",
        "s_min = 0.05",
        "",
        "# where it publishes",
        "[publish]",
        "sndhwm = 1000",
    ]
    f.write_text("\n".join(before) + "\n")
    write_filter_values(f, {"amp_ref": 1998.04, "sigma0_m": 0.0041234, "k_m_per_lux": 2.61e-7})
    after = f.read_text().splitlines()
    assert after == [
        "# front sensor",
        "[filter]",
        "amp_ref = 1998.0              # amp for strength S = 1",
        "sigma0_m = 0.00412            # metres at zero ambient light and S = 1",
        "s_min = 0.05",
        "k_m_per_lux = 2.61e-07",
        "",
        "# where it publishes",
        "[publish]",
        "sndhwm = 1000",
    ]
    cfg = load_config(f).filter.to_filter_config()
    assert (cfg.sigma0_m, cfg.k_m_per_lux, cfg.s_min) == (0.00412, 2.61e-7, 0.05)


def test_write_keeps_comments_and_other_keys(tmp_path: Path) -> None:
    f = tmp_path / "a.toml"
    f.write_text(
        '# mine\n[sensor]\nname = "x"\n\n[filter]\namp_ref = 2000.0  # old\ns_min = 0.05\n'
    )
    write_filter_values(f, {"amp_ref": 1234.56})
    text = f.read_text()
    assert "# mine" in text and "s_min = 0.05" in text and "# old" in text
    assert load_config(f).filter.to_filter_config().amp_ref == pytest.approx(1234.6)
    g = tmp_path / "b.toml"
    g.write_text('[sensor]\nname = "y"\n')
    write_filter_values(g, {"amp_ref": 999.0})
    assert load_config(g).filter.to_filter_config().amp_ref == 999.0
    assert load_config(g).sensor.name == "y"


@pytest.mark.parametrize("start_empty", [False, True], ids=["config with the device", "empty"])
def test_calibrate_on_the_virtual_sensor(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any, start_empty: bool
) -> None:
    """amp_ref recovered and written; the daemon refuses a config file that sets
    nothing, but calibrate --write may start one from nothing."""
    dev = device(
        rate_hz=250,
        output_enabled=False,
        model=RealisticSensor(),
        truth=Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=100.0),
    )
    cfg = tmp_path / "front.toml"
    cfg.write_text("" if start_empty else f'[source]\ndevice = "{dev.path}"\n')
    r = subprocess.run(
        [*write_amp_ref_argv(helpers, cfg, seconds="1"), "--device", dev.path]
        if start_empty
        else write_amp_ref_argv(helpers, cfg, seconds="1"),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 0, r.stderr
    amp_ref = load_config(cfg).filter.to_filter_config().amp_ref
    assert amp_ref == pytest.approx(AMP_REF, rel=0.03)  # the simulator's truth, recovered
    assert "warning" not in r.stderr
    if not start_empty:
        assert f'source]\ndevice = "{dev.path}"' in cfg.read_text()


def calibrate_argv(
    helpers: Any, dev: PtyDevice, truth: Truth, *flags: str, seconds: str = "2"
) -> list[str]:
    """``lunad calibrate`` on ``dev`` for the target in ``truth``, at 250 Hz: 2 s give
    about 500 readings, sigma0 to about 5 %."""
    return [
        *helpers.lunad, "calibrate", "--device", dev.path, "--rate", "250", "--seconds", seconds,
        "--reflectivity", str(truth.reflectivity), "--distance", str(truth.distance_m), *flags,
    ]  # fmt: skip


def figure(stdout: str, name: str) -> tuple[float, float]:
    """(value, uncertainty) of ``name = value ± err`` in calibrate's output."""
    m = re.search(rf"^{name} = (\S+) ± (\S+)", stdout, re.MULTILINE)
    assert m is not None, stdout
    return float(m.group(1)), float(m.group(2))


GREY_AT_3_M = Truth(distance_m=3.0, reflectivity=0.3, angle_deg=0.0, lux=0.0)
"""S = 0.3 (2 m / 3 m)^2 = 0.133: the reading noise is 3 cm, three steps."""


def test_sigma0_in_the_dark_then_k_under_light_on_the_virtual_sensor(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    """The two runs a user makes, each ``--write`` storing what it measured and leaving
    the file's other lines as they were."""
    cfg = tmp_path / "front.toml"
    before = [
        "# front sensor",
        "[sensor]",
        'name = "front"',
        "",
        "[filter]",
        "amp_ref = 1500.0              # amp for strength S = 1",
        "s_min = 0.05",
        "sigma0_m = 0.004              # metres at zero ambient light and S = 1",
        "",
        "# where it publishes",
        "[publish]",
        "sndhwm = 1000",
    ]
    cfg.write_text("\n".join(before) + "\n")
    dark = device(rate_hz=250, output_enabled=False, model=RealisticSensor(), truth=GREY_AT_3_M)
    r = subprocess.run(
        calibrate_argv(helpers, dark, GREY_AT_3_M, "--config", str(cfg), "--lux", "0", "--write"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert "(4." in r.stdout and "mm; in the dark, --lux 0)" in r.stdout
    assert "wrote [filter] amp_ref, sigma0_m to" in r.stdout and "lux_est" not in r.stdout
    written = load_config(cfg).filter.to_filter_config()
    assert written.sigma0_m == pytest.approx(REALISTIC_SIGMA0_M, rel=0.15)
    assert written.sigma0_m == pytest.approx(figure(r.stdout, "sigma0_m")[0])
    assert written.amp_ref == pytest.approx(AMP_REF, rel=0.03)
    assert written.k_m_per_lux == FilterConfig().k_m_per_lux  # not measured: not written
    dark.close()

    lamp_truth = Truth(distance_m=3.0, reflectivity=0.3, angle_deg=0.0, lux=30_000.0)
    lamp = device(
        rate_hz=250,
        output_enabled=False,
        model=RealisticSensor(),
        truth=lamp_truth,
        link=tmp_path / "tfluna-lamp",
    )
    r = subprocess.run(
        calibrate_argv(
            helpers, lamp, lamp_truth, "--config", str(cfg), "--lux", "30000", "--fit-k", "--write"
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert "wrote [filter] amp_ref, k_m_per_lux to" in r.stdout and "warning" not in r.stderr
    fitted = load_config(cfg).filter.to_filter_config()
    assert fitted.k_m_per_lux == pytest.approx(REALISTIC_K_M_PER_LUX, rel=0.3)
    assert fitted.sigma0_m == written.sigma0_m  # the dark run's, used and kept
    after = cfg.read_text().splitlines()
    changed = [i for i, line in enumerate(before[:8]) if after[i] != line]
    assert changed == [5, 7]  # amp_ref and sigma0_m, in place, comments kept
    assert after[5].endswith("# amp for strength S = 1")
    assert after[7].endswith("# metres at zero ambient light and S = 1")
    assert after[8].startswith("k_m_per_lux = ") and after[9:] == before[8:]


@pytest.mark.parametrize("sigma0_line", ["sigma0_m = 0.004\n", ""], ids=["set", "not set"])
def test_fit_k_warns_only_where_no_sigma0_is_set(
    device: Callable[..., PtyDevice], helpers: Any, tmp_path: Path, sigma0_line: str
) -> None:
    """A dark run that measured sigma0 as 0.004 m (it is written to 3 figures) was taken
    for no run at all, as the test was equality with the default: the --fit-k step
    then warned that sigma0 had not been measured. What counts is that the file sets
    it."""
    cfg = tmp_path / "front.toml"
    cfg.write_text(f"[filter]\namp_ref = 2000.0\n{sigma0_line}")
    lamp_truth = Truth(distance_m=3.0, reflectivity=0.3, angle_deg=0.0, lux=30_000.0)
    lamp = device(rate_hz=250, output_enabled=False, model=RealisticSensor(), truth=lamp_truth)
    r = subprocess.run(
        calibrate_argv(
            helpers, lamp, lamp_truth, "--config", str(cfg), "--lux", "30000", "--fit-k"
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    warned = "sigma0_m is the datasheet's 0.004, not measured" in r.stderr
    assert warned == (not sigma0_line), r.stderr


def test_a_noisier_sensor_reads_a_larger_sigma0(
    device: Callable[..., PtyDevice], helpers: Any
) -> None:
    """The simulator's noise_scale 2 doubles sigma0: 8 mm."""
    dev = device(rate_hz=250, output_enabled=False, model=RealisticSensor(2.0), truth=GREY_AT_3_M)
    r = subprocess.run(
        calibrate_argv(helpers, dev, GREY_AT_3_M), capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0, r.stderr
    sigma0, err = figure(r.stdout, "sigma0_m")
    assert sigma0 == pytest.approx(2 * REALISTIC_SIGMA0_M, rel=0.15) and 0 < err < 0.001
    assert "--lux not given: the target is taken as dark" in r.stdout


def test_a_strong_close_target_gives_amp_ref_but_no_sigma0(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    """A white card at 1 m (S = 3.6, noise 1 mm): the readings repeat one centimetre.
    sigma0 is refused, amp_ref is measured and written; asked for with --lux, exit 1."""
    truth = Truth(distance_m=1.0, reflectivity=0.9, angle_deg=0.0, lux=0.0)
    dev = device(rate_hz=250, output_enabled=False, model=RealisticSensor(), truth=truth)
    cfg = tmp_path / "front.toml"
    cfg.write_text("[filter]\namp_ref = 1500.0\n")
    r = subprocess.run(
        calibrate_argv(helpers, dev, truth, "--config", str(cfg), "--write"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert "sigma0_m not measured: the noise is below the 1 cm step here" in r.stdout
    assert "calibrate sigma0 on a darker or farther target (S about 0.3-0.5" in r.stdout
    assert "sigma0_m stays 0.004, the datasheet fit" in r.stdout and "lux_est" in r.stdout
    assert "wrote [filter] amp_ref to" in r.stdout
    assert load_config(cfg).filter.to_filter_config().amp_ref == pytest.approx(AMP_REF, rel=0.03)
    assert "sigma0" not in cfg.read_text()
    r = subprocess.run(
        calibrate_argv(helpers, dev, truth, "--lux", "0", seconds="0.5"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 1 and "sigma0_m not measured" in r.stdout, r.stderr


def test_a_distance_that_disagrees_fails_and_writes_nothing(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    """A target at 2 m calibrated as if at 3 m would write an amp_ref 2.25x too small:
    the run says so, exits 1 and leaves the config file as it was."""
    truth = Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=0.0)
    dev = device(rate_hz=250, output_enabled=False, truth=truth)
    cfg = tmp_path / "front.toml"
    before = f'[source]\ndevice = "{dev.path}"\n\n[filter]\namp_ref = 1234.0\n'
    cfg.write_text(before)
    wrong = Truth(distance_m=3.0, reflectivity=0.9, angle_deg=0.0, lux=0.0)
    argv = calibrate_argv(helpers, dev, wrong, "--config", str(cfg), "--write", seconds="0.5")
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    assert r.returncode == 1, r.stderr
    assert "the sensor reads 2.0" in r.stderr and "Nothing written." in r.stderr
    assert "amp_ref" in r.stdout  # still reported, for the user to see
    assert cfg.read_text() == before


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
    write_filter_values(f, {"amp_ref": 1500.0})
    cfg = load_config(f)
    assert cfg.filter.to_filter_config().amp_ref == 1500.0
    assert f.read_text().count("amp_ref") == 1 and header in f.read_text()


def test_write_tells_other_tables_and_arrays_from_filter(tmp_path: Path) -> None:
    """[filter.sub], [[array]] and a nested array's rows do not open or close [filter]."""
    f = tmp_path / "a.toml"
    f.write_text(
        "[filter]\nrows = [\n  [1, 2],\n  [3, 4],\n]\n\n[[probe]]\nx = 1\n\n[filter.sub]\ny = 2\n"
    )
    write_filter_values(f, {"amp_ref": 1500.0})
    data = tomllib.loads(f.read_text())
    assert data["filter"]["amp_ref"] == 1500.0 and data["filter"]["rows"] == [[1, 2], [3, 4]]
    assert data["filter"]["sub"] == {"y": 2} and data["probe"] == [{"x": 1}]


def test_write_refuses_a_layout_it_cannot_edit(tmp_path: Path) -> None:
    """[[filter]] is an array of tables, not [filter]: refuse and leave the file alone."""
    f = tmp_path / "a.toml"
    before = "[[filter]]\namp_ref = 2000.0\n"
    f.write_text(before)
    with pytest.raises(ValueError, match="by hand"):
        write_filter_values(f, {"amp_ref": 1500.0})
    assert f.read_text() == before and os.listdir(tmp_path) == ["a.toml"]


def test_write_keeps_a_files_line_ends(tmp_path: Path) -> None:
    """A config file written on Windows (CRLF) came back with LF line ends, every line
    changed in a diff."""
    f = tmp_path / "crlf.toml"
    f.write_bytes(b'[sensor]\r\nname = "x"\r\n\r\n[filter]\r\namp_ref = 2000.0\r\n')
    write_filter_values(f, {"amp_ref": 1500.0, "sigma0_m": 0.004})
    assert f.read_bytes() == (
        b'[sensor]\r\nname = "x"\r\n\r\n[filter]\r\namp_ref = 1500.0\r\nsigma0_m = 0.004\r\n'
    )


def test_write_where_no_file_can_be_made_names_the_config(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a read-only card the error named the temporary file beside the config
    (``.c.toml.1v46ecgx``), a name the user never gave. A test cannot mount a read-only
    card, and root writes in a read-only folder: the kernel's answer is given here."""
    f = tmp_path / "c.toml"
    f.write_text("[filter]\namp_ref = 2000.0\n")

    def read_only(dir: str, prefix: str) -> tuple[int, str]:
        raise OSError(errno.EROFS, "Read-only file system", f"{dir}/{prefix}1v46ecgx")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    with pytest.raises(OSError) as info:
        write_filter_values(f, {"amp_ref": 1500.0})
    assert str(info.value) == f"[Errno 30] cannot write {f}: Read-only file system"
    assert f.read_text() == "[filter]\namp_ref = 2000.0\n"


def test_write_keeps_the_file_mode(tmp_path: Path) -> None:
    """The daemon's user must still read the file: 0644 stays 0644, 0640 stays 0640."""
    for mode in (0o644, 0o640):
        f = tmp_path / f"{mode:o}.toml"
        f.write_text("[filter]\namp_ref = 2000.0\n")
        f.chmod(mode)
        write_filter_values(f, {"amp_ref": 1500.0})
        assert stat.S_IMODE(f.stat().st_mode) == mode
    old_umask = os.umask(0o022)
    try:
        write_filter_values(tmp_path / "new.toml", {"amp_ref": 1500.0})
    finally:
        os.umask(old_umask)
    assert stat.S_IMODE((tmp_path / "new.toml").stat().st_mode) == 0o644


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can give a file to another owner")
def test_write_as_root_keeps_owner_and_group(tmp_path: Path) -> None:
    f = tmp_path / "a.toml"
    f.write_text("[filter]\namp_ref = 2000.0\n")
    os.chown(f, 4321, 8765)
    write_filter_values(f, {"amp_ref": 1500.0})
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


ANGLE_LINE = (
    "--angle must be from 0 to 45 degrees (every figure is divided by cos(angle), which "
    "steeper angles take towards 0)"
)
LUX_LINE = (
    "--lux must be from 0 to 200000 (lux at the target; the brightest sunlight is about 120000)"
)


@pytest.mark.parametrize(
    ("flags", "line"),
    [
        (["--reflectivity", "1.5"], "--reflectivity must be above 0 and at most 1, got 1.5"),
        (["--reflectivity", "0"], "--reflectivity must be above 0 and at most 1, got 0.0"),
        (["--reflectivity", "nan"], "--reflectivity must be above 0 and at most 1, got nan"),
        (["--distance", "0"], "--distance must be positive and finite (metres), got 0.0"),
        (["--distance", "-2"], "--distance must be positive and finite (metres), got -2.0"),
        (["--distance", "inf"], "--distance must be positive and finite (metres), got inf"),
        (["--angle", "90"], f"{ANGLE_LINE}, got 90.0"),
        (["--angle", "-10"], f"{ANGLE_LINE}, got -10.0"),
        (["--angle", "45.1"], f"{ANGLE_LINE}, got 45.1"),
        (["--angle", "89.9999999"], f"{ANGLE_LINE}, got 89.9999999"),
        (["--angle", "nan"], f"{ANGLE_LINE}, got nan"),
        (["--seconds", "0"], "--seconds must be positive and finite, got 0.0"),
        (["--seconds", "nan"], "--seconds must be positive and finite, got nan"),
        (["--lux", "-1"], f"{LUX_LINE}, got -1.0"),
        (["--lux", "inf"], f"{LUX_LINE}, got inf"),
        (["--lux", "nan"], f"{LUX_LINE}, got nan"),
        (["--lux", "200001"], f"{LUX_LINE}, got 200001.0"),
        (["--lux", "30000000", "--fit-k"], f"{LUX_LINE}, got 30000000.0"),
        (
            ["--fit-k"],
            "--fit-k needs --lux above 0: a lux meter reading at the target (20-40 klux)",
        ),
        (
            ["--fit-k", "--lux", "0"],
            "--fit-k needs --lux above 0: a lux meter reading at the target (20-40 klux)",
        ),
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


def test_the_lux_cap_is_the_simulators() -> None:
    """A --lux the simulator cannot show is one calibrate refuses, and the other way."""
    assert scenario.FIELD_LIMITS["lux"] == (0.0, LUX_MAX)


def config_dir(tmp_path: Path) -> Path:
    """A directory for the config file alone (the device fixture links its pty into
    ``tmp_path``), so that a temporary file left beside it shows."""
    etc = tmp_path / "etc"
    etc.mkdir()
    return etc


LAMP_AT_4_M = Truth(distance_m=4.0, reflectivity=0.9, angle_deg=0.0, lux=30_000.0)
CALIBRATED = '[sensor]\nname = "front"\n\n[filter]\namp_ref = 1990.0  # bench\nsigma0_m = 0.0041\n'
"""A calibrated file, as a run leaves it."""


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (["--lux", "30000000", "--fit-k"], "--lux must be from 0 to 200000"),
        (["--angle", "89.9999999"], "--angle must be from 0 to 45 degrees"),
    ],
    ids=["lux with extra zeros", "grazing angle"],
)
def test_a_typo_in_lux_or_angle_leaves_the_config_as_it_was(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any, flags: list[str], named: str
) -> None:
    """``--lux 30000000`` wrote k_m_per_lux = 2.06e-10 and ``--angle 89.9999999``
    amp_ref = 1.1e12, each into the file and then refused by the daemon's start (exit 78
    after the write). Both are refused before the sensor is read; the file is kept to
    the byte and the daemon still takes it."""
    dev = device(rate_hz=250, output_enabled=False, model=RealisticSensor(), truth=LAMP_AT_4_M)
    cfg = config_dir(tmp_path) / "front.toml"
    cfg.write_text(CALIBRATED)
    before = cfg.read_bytes()
    argv = calibrate_argv(
        helpers, dev, LAMP_AT_4_M, "--config", str(cfg), *flags, "--write", seconds="1"
    )
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    assert r.returncode == 78, r.stderr
    assert r.stderr.startswith(f"lunad calibrate: {named}") and r.stdout == ""
    assert cfg.read_bytes() == before and os.listdir(cfg.parent) == ["front.toml"]
    assert load_config(cfg).filter.to_filter_config().amp_ref == 1990.0


@pytest.mark.parametrize("too_small", [1e6, 9e299])
def test_a_figure_the_daemon_would_refuse_is_not_written(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any, too_small: float
) -> None:
    """A reflectivity typed 1e6 times too small gives amp_ref = 1.8e9, above what the
    config takes (1e9): it used to be written, and the file then refused. Now nothing is
    written, and the message names the key, its value and the flag to check. Typed
    1e-300, the amp_ref reported is a figure of four digits, not of 300."""
    truth = Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=0.0)
    dev = device(rate_hz=250, output_enabled=False, model=RealisticSensor(), truth=truth)
    cfg = config_dir(tmp_path) / "front.toml"
    cfg.write_text(CALIBRATED)
    before = cfg.read_bytes()
    typo = Truth(distance_m=2.0, reflectivity=0.9 / too_small, angle_deg=0.0, lux=0.0)
    argv = calibrate_argv(helpers, dev, typo, "--config", str(cfg), "--write", seconds="1")
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    assert r.returncode == 78, r.stderr
    amp_ref, _ = figure(r.stdout, "amp_ref")  # still reported, for the user to see
    assert amp_ref == pytest.approx(AMP_REF * too_small, rel=0.03)
    assert re.search(r"^amp_ref = \S{1,12} ± \S{1,12} ", r.stdout, re.MULTILINE), r.stdout
    assert r.stderr.startswith(
        "lunad calibrate: --write: nothing written: the measured amp_ref = "
    ), r.stderr
    refused = f"would make the daemon refuse {cfg} (FilterConfig.amp_ref must be between"
    assert refused in r.stderr
    assert "is --reflectivity right?" in r.stderr and "wrote" not in r.stdout
    assert cfg.read_bytes() == before and os.listdir(cfg.parent) == ["front.toml"]
    load_config(cfg)


def test_a_file_refused_already_is_said_to_be_and_kept(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    """--device stood in for the file's broken device at the start, but the daemon reads
    the file without it: calibrate used to write and then report the file invalid as if
    its own values were. Now it names the file's fault, keeps the file and gives the
    line to add by hand."""
    truth = Truth(distance_m=2.0, reflectivity=0.9, angle_deg=0.0, lux=0.0)
    dev = device(rate_hz=250, output_enabled=False, model=RealisticSensor(), truth=truth)
    cfg = config_dir(tmp_path) / "front.toml"
    cfg.write_text('[source]\ndevice = "nosuch://x"\n\n[filter]\namp_ref = 1500.0\n')
    before = cfg.read_bytes()
    argv = calibrate_argv(helpers, dev, truth, "--config", str(cfg), "--write", seconds="1")
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    assert r.returncode == 78, r.stderr
    assert r.stderr.startswith(
        f"lunad calibrate: --write: nothing written: {cfg} is refused already, before this "
        f"run's values (invalid configuration ({cfg}): source.device"
    ), r.stderr
    assert "URL scheme 'nosuch'" in r.stderr
    amp_ref, _ = figure(r.stdout, "amp_ref")
    assert f"add `amp_ref = {amp_ref:.1f}` under [filter] by hand" in r.stderr
    assert cfg.read_bytes() == before and os.listdir(cfg.parent) == ["front.toml"]


def test_write_checks_the_new_file_before_it_replaces_the_old(tmp_path: Path) -> None:
    """``check`` sees the complete new file; what it raises leaves the old one in place
    and no temporary file behind."""
    f = tmp_path / "a.toml"
    f.write_text("[filter]\namp_ref = 2000.0\n")
    seen: list[float] = []

    def refuse(new: Path) -> None:
        seen.append(load_config(new).filter.to_filter_config().amp_ref)
        raise ValueError("refused")

    with pytest.raises(ValueError, match="refused"):
        write_filter_values(f, {"amp_ref": 1500.0}, check=refuse)
    assert seen == [1500.0]
    assert f.read_text() == "[filter]\namp_ref = 2000.0\n" and os.listdir(tmp_path) == ["a.toml"]
    write_filter_values(f, {"amp_ref": 1500.0}, check=load_config)
    assert load_config(f).filter.to_filter_config().amp_ref == 1500.0
