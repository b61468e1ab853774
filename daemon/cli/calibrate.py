"""``lunad calibrate``: amp_ref and the noise constants, on a target of known reflectivity.

The paper recommends pre-calibrating on targets of known reflectivity (section VI,
recommendation 2). A still target of known R at a known angle and distance has the
strength S = R cos(theta) (2 m / d)^2 (paper eq. 1 with the d^2 fall-off,
docs/filter.md), so its readings give amp_ref = median(amp) / S; the median makes the
figure robust to the odd multipath spike, and readings the sensor itself flags
(amp < 100, amp > 32768) are left out. The spread of the same readings gives the noise
at S = 1, c = sigma0 + k L (paper eqs 2-3), hence sigma0 with L from ``--lux`` (0 when
not given: the target is taken as dark) or, with ``--fit-k``, k from the configured
sigma0. The maths, and why the spread is not measured below half the 1 cm output step,
are in ``lunad.filters.calibration``; this module reads the sensor, reports and writes.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import signal
import stat
import statistics
import sys
import tempfile
import threading
import time
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from lunad.daemon.cli.source_args import add_source_args, source_overrides
from lunad.filters.calibration import (
    MIN_DIFFERENCES,
    Figure,
    Spread,
    amp_ref_of,
    k_of,
    noise_at_unit_strength,
    reading_spread,
    sigma0_of,
    target_strength,
)
from lunad.filters.config import SIGMA0_DEFAULT_M, FilterConfig

DESCRIPTION = """\
Measure amp_ref, the amp that means strength S = 1 (a white target square to the
beam at 2 m), on a target of known reflectivity (a white matte card is about 0.9) at
a known distance and angle; and, from the spread of the same readings, the noise
constants of the paper's eq. 2: sigma0_m, the noise at S = 1 in the dark, or with
--fit-k k_m_per_lux, its growth with light. --write puts what was measured into the
config file's [filter] section (comments are kept).

The noise shows only where it exceeds half the 1 cm output step: at S about 0.3-0.5
or less (a white card at 3-4 m, a darker one nearer). A strong, close target gives
amp_ref alone. To fit both constants: in the dark, --lux 0; then with a lux meter
reading at the target under daylight or a lamp, --lux 30000 --fit-k, which uses the
sigma0 the first run wrote. Until sigma0 is measured, lux_est rests on the datasheet's
4 mm and is a coarse indication (dark, indoor, daylight), not a figure.

Put the target square to the beam (or give --angle, at most 45 degrees), fill the
2 degree beam with it (the spot is 3.5 cm wide per metre), and keep the scene still
while it measures. Ctrl-C aborts: nothing is written. Exit 1: the port cannot be
opened or is lost; too few readings; the sensor reads a distance more than 10 % (and
5 cm) off --distance, so the target is not where the figures assume (they are
reported, and --write writes nothing); or the figure --lux or --fit-k asks for could
not be measured (amp_ref is still reported and written). Exit 69: the port is in use
by another process, usually the daemon (`sudo systemctl stop lunad@NAME` first; the
message names the holder). Exit 78: a flag out of its range, or the config file the
daemon would read after --write refuses a figure (one out of range: a wrong
--reflectivity, say), is refused already, or cannot be written (a read-only card);
--write then writes nothing.
"""

EPILOG = """\
examples:
  lunad calibrate --device /dev/serial0 --reflectivity 0.9 --distance 2.0
  lunad calibrate --config /etc/lunad/front.toml --reflectivity 0.9 --distance 1.5 --write
  lunad calibrate --bus 1 --reflectivity 0.5 --distance 1.0 --angle 20 --seconds 10
  # sigma0 and k on a white card at 4 m (S 0.23): in the dark, then at 30 klux
  lunad calibrate --config front.toml --reflectivity 0.9 --distance 4 --lux 0 --write
  lunad calibrate --config front.toml --reflectivity 0.9 --distance 4 --lux 30000 \\
      --fit-k --write
"""

AMP_MIN_VALID = 100  # below: the sensor reports no distance (M05 p.16)
AMP_AMBIENT = 32768  # above: ambient overexposure (M05 p.14)
DISTANCE_TOLERANCE = 0.1
"""A median distance further than this share of --distance (and 5 cm) from it: the
target is not where the figures assume (another surface fills the beam, or a wrong
--distance), so S, and every figure divided by it, is wrong; nothing is written."""
DISTANCE_SLACK_M = 0.05  # ... plus the readings' own centimetres
DISTANCE_EXIT = 1
MIN_READINGS = 20
FILTER_TABLE: dict[str, Any] = {"filter": {}}  # what _table_header gives for [filter]

MIN_FIGURE_SIGMAS = 2.0
"""A noise figure is stored only when it lies this many of its uncertainties above 0
(our choice: closer to 0 it is mostly the readings' scatter, and a k or sigma0 of about
0 would make lux_est swing wildly)."""

NOISE_STRENGTHS = (0.3, 0.5)
"""Strengths at which to calibrate the noise, suggested when it is below the step (our
choice: with the datasheet's sigma0 of 4 mm they give 8-13 mm of noise, well above
the half step the spread needs; filters/calibration.py, SPREAD_MIN_STEPS)."""

DATASHEET_SIGMA0_RANGE_MM = (1.1, 4.8)
"""sigma0 the datasheet's repeatability tables imply, read with paper eq. 3 (sigma0 =
sigma S, S = amp / 2000, the 1 cm step's share taken out): Table 2 (M05 p.9) gives 1.5
to 4.8 mm from amp 100 to 2000, Table 3 (M05 p.10, 90 % target at 2 to 8 m) 1.1 to
3.7 mm. The default 4 mm is the fit to Table 2 from amp 400 up (filters/config.py)."""

NOISE_ASKED_EXIT = 1  # --lux or --fit-k given and its figure not measured

ANGLE_MAX_DEG = 45.0
"""Steepest --angle taken, degrees: the edge of the paper's stable region (section V,
angle < 45 deg). Every figure is divided by S = R cos(theta) (paper eq. 1), so an error
in the angle grows by tan(theta) in them: 1.7 % per degree at 45 deg, 10 % at 80 deg,
and without bound towards 90 deg, where cos(theta) goes to 0 (89.9999999 deg wrote
amp_ref = 1.1e12). Steeper, the paper's measured signal also falls faster than
cos(theta) does (section V: 20 % of normal at 60 deg, cos gives 50 %;
docs/paper-model.md)."""

LUX_MAX = 200_000.0
"""Highest --lux taken, lux: above the brightest direct sunlight (about 120 klux), and
the cap of ``lunad sim``'s light (sim/scenario.py, FIELD_LIMITS). A reading above it is
a typo (an extra zero or three), and k = (c - sigma0) / L would be as many times too
small (30000000 for 30000 wrote k = 2.06e-10, which the daemon refuses)."""

VALUE_HINTS: dict[str, str] = {
    "amp_ref": "is --reflectivity right? amp_ref is the median amp over R cos(angle) "
    "(2 m / d)^2, so a reflectivity 1000 times too small gives an amp_ref 1000 times "
    "too large",
    "sigma0_m": "is --lux right? sigma0 is c - k L",
    "k_m_per_lux": "is --lux right? k is (c - sigma0) / L, so a lux reading 1000 times "
    "too large gives a k 1000 times too small",
}
"""What a measured figure the config refuses most likely comes from, by its key."""


@dataclass(frozen=True, slots=True)
class Calibration:
    """What one calibration measured.

    Attributes:
        amp_ref: amp for S = 1 (a white target square to the beam at 2 m).
        amp_ref_err: its one-sigma uncertainty from the readings' amp scatter (an
            error in the stated reflectivity, angle or distance adds to it).
        strength: S of the target, R cos(theta) (2 m / d)^2.
        median_amp: median amp of the usable readings.
        median_distance_m: median distance the sensor reported, metres.
        used: readings used; rejected: readings the sensor flagged (weak or overexposed).
        spread: the noise of single readings, metres (``lunad.filters.calibration``).
        c: the noise at S = 1, c = sigma0 + k L, metres; None when not measurable.
        sigma0: paper eq. 2's sigma0, metres; None when not measured (always with
            ``fit_k``).
        k: paper eq. 2's k, metres per lux; measured only with ``fit_k``.
        not_measured: why the noise figure this run aims at (sigma0, or k with
            ``fit_k``) was not measured, one sentence; None when it was.
    """

    amp_ref: float
    amp_ref_err: float
    strength: float
    median_amp: float
    median_distance_m: float
    used: int
    rejected: int
    spread: Spread
    c: Figure | None = None
    sigma0: Figure | None = None
    k: Figure | None = None
    not_measured: str | None = None


def _distance_for(strength: float, target_r_cos: float) -> float:
    """Distance in metres at which a target of this R cos(theta) has ``strength``."""
    return 2.0 * math.sqrt(target_r_cos / strength)


def compute(
    readings: list[tuple[float, int]],
    reflectivity: float,
    angle_deg: float,
    distance_m: float,
    *,
    lux: float | None = None,
    fit_k: bool = False,
    filter_cfg: FilterConfig | None = None,
) -> Calibration:
    """amp_ref and the noise constants from (distance_m, amp) readings, in the order
    the sensor sent them, of a still target with known R, angle and distance.

    Args:
        readings: distance 0 where the sensor reported none.
        reflectivity, angle_deg, distance_m: the target, degrees and metres.
        lux: ambient light at the target from a lux meter; None: not given, taken as
            dark (0).
        fit_k: fit k = (c - sigma0) / L with the configured sigma0, instead of
            sigma0 = c - k L with the configured k.
        filter_cfg: the configured sigma0, k and output step (defaults if None).

    Raises:
        ValueError: R cos(theta) is not in (0, 1], ``fit_k`` without light, or fewer
            than MIN_READINGS usable readings.
    """
    cfg = filter_cfg or FilterConfig()
    r_cos = reflectivity * math.cos(math.radians(angle_deg))
    if not 0 < r_cos <= 1:
        raise ValueError(f"R cos(angle) must be in (0, 1], got {r_cos:.3f}")
    light = lux or 0.0
    if fit_k and not light > 0:
        raise ValueError("fitting k needs the light at the target (lux above 0)")
    usable = [AMP_MIN_VALID <= a <= AMP_AMBIENT and d > 0 for d, a in readings]
    good = [r for r, ok in zip(readings, usable, strict=True) if ok]
    if len(good) < MIN_READINGS:
        raise ValueError(
            f"only {len(good)} usable readings of {len(readings)} (need {MIN_READINGS}): "
            "is the target in the beam and the sensor streaming?"
        )
    s = target_strength(reflectivity, angle_deg, distance_m)
    amp_ref = amp_ref_of([a for _, a in good], s)
    spread = reading_spread(
        [d if ok else None for (d, _), ok in zip(readings, usable, strict=True)],
        cfg.resolution_m,
    )
    cal = Calibration(
        amp_ref=amp_ref.value,
        amp_ref_err=amp_ref.err,
        strength=s,
        median_amp=statistics.median(a for _, a in good),
        median_distance_m=statistics.median(d for d, _ in good),
        used=len(good),
        rejected=len(readings) - len(good),
        spread=spread,
    )
    name, verb = ("k_m_per_lux", "fit k") if fit_k else ("sigma0_m", "calibrate sigma0")
    if spread.sd_m is None:
        if spread.below_step:
            low, high = NOISE_STRENGTHS
            if s > high:
                where = (
                    f"S about {low:g}-{high:g}: this one at {_distance_for(high, r_cos):.1f}"
                    f"-{_distance_for(low, r_cos):.1f} m"
                )
            else:  # a sensor quieter than the datasheet's
                where = f"this one's S is {s:.2g} already: farther still, or darker"
            why = (
                f"the noise is below the 1 cm step here ({spread.repeat_share * 100:.0f} % of "
                f"the readings repeat one centimetre); {verb} on a darker or farther target "
                f"({where})"
            )
        else:
            why = (
                f"only {spread.differences} runs of three consecutive usable readings "
                f"(need {MIN_DIFFERENCES}): is the target still, and strong enough?"
            )
        return replace(cal, not_measured=f"{name} not measured: {why}")
    c = noise_at_unit_strength(spread.sd_m, s)
    if fit_k:
        k = k_of(c, light, cfg.sigma0_m)
        if k.value < MIN_FIGURE_SIGMAS * k.err:
            return replace(
                cal,
                c=c,
                not_measured=(
                    f"k_m_per_lux not measured: the noise at S = 1 under {light:g} lux, "
                    f"{c.value * 1e3:.2f} ± {c.err * 1e3:.2f} mm, is not clearly above "
                    f"sigma0 ({cfg.sigma0_m * 1e3:.2f} mm): is the light on the target "
                    "and --lux right? Fit k under more light (20-40 klux)"
                ),
            )
        return replace(cal, c=c, k=k)
    sigma0 = sigma0_of(c, light, cfg.k_m_per_lux)
    if sigma0.value < MIN_FIGURE_SIGMAS * sigma0.err:
        return replace(
            cal,
            c=c,
            not_measured=(
                f"sigma0_m not measured: the light you gave (k L = "
                f"{cfg.k_m_per_lux * light * 1e3:.2f} mm) explains the noise at S = 1 "
                f"({c.value * 1e3:.2f} ± {c.err * 1e3:.2f} mm); check --lux, or "
                "calibrate sigma0 in the dark"
            ),
        )
    return replace(cal, c=c, sigma0=sigma0)


def _table_header(line: str) -> dict[str, Any] | None:
    """The table a header line opens, as TOML reads it, or None for any other line.

    ``[filter]  # bench`` and ``[ filter ]`` give ``{"filter": {}}``; ``[filter.sub]``
    gives ``{"filter": {"sub": {}}}`` and ``[[filter]]`` ``{"filter": [{}]}``, so a caller
    compares with ``{"filter": {}}``. Parsing the line with tomllib gets quoting, inner
    spaces and trailing comments right without a TOML grammar of our own; a line of a
    multi-line array (``[1, 2],``) is not a header and fails to parse.
    """
    if not line.lstrip().startswith("["):
        return None
    try:
        return tomllib.loads(line)
    except tomllib.TOMLDecodeError:
        return None


def _toml_float(key: str, value: float) -> str:
    """How ``key``'s value is written: amp_ref to 0.1, the noise constants to three
    significant figures (their uncertainty is a few per cent); always a TOML float."""
    return f"{value:.1f}" if key == "amp_ref" else repr(float(f"{value:.3g}"))


def write_filter_values(
    path: Path, values: Mapping[str, float], check: Callable[[Path], object] | None = None
) -> None:
    """Set keys under ``[filter]`` in a TOML file, keeping everything else; atomic replace.

    A key already there keeps its line's place and comment; a new one goes after the
    table's last setting (a new ``[filter]`` table at the end if there is none).

    The new file keeps the old one's permission bits, and its owner and group when we
    run as root: the daemon reads it as its own user (``User=lunad`` in the unit), and a
    temporary file is created 0600 and owned by us. A new file gets 0666 less the umask,
    as ``open()`` would give it.

    A symlinked ``path`` (``/etc/lunad/front.toml`` pointing into a config repository) is
    followed: the file it points to is replaced, in its own directory, and the link
    stays. Replacing ``path`` itself would swap the link for a copy and leave the
    config the link named, the one that is maintained, with the old values.

    Args:
        values: ``FilterConfig`` field name -> value, in its unit.
        check: called with the new file, complete but not yet in ``path``'s place (a
            temporary file beside it); what it returns is ignored, what it raises stops
            the write, so a file the
            daemon would refuse never replaces the one it takes.

    Raises:
        ValueError: the edit would not leave a file where every key under ``[filter]``
            reads back as written (a layout this line-based edit does not follow), or
            ``check`` raised it; the file is left as it was.
        OSError: the file cannot be read or replaced.
    """
    target = path.resolve()
    old = target.stat() if target.exists() else None
    text = ""
    if old is not None:
        with open(target, encoding="utf-8", newline="") as f:  # line ends as they are
            text = f.read()
    written = {key: _toml_float(key, value) for key, value in values.items()}
    todo = dict(written)
    eol = "\r\n" if "\r\n" in text else "\n"  # a file written on Windows keeps its ends
    lines = text.splitlines()
    section: dict[str, Any] | None = None
    filter_end: int | None = None  # index after the [filter] table's last setting
    for i, raw in enumerate(lines):
        if (header := _table_header(raw)) is not None:
            section = header
            if section == FILTER_TABLE and filter_end is None:
                filter_end = i + 1
            continue
        stripped = raw.strip()
        if section != FILTER_TABLE or not stripped or stripped.startswith("#"):
            continue
        filter_end = i + 1
        for key in [k for k in todo if re.match(rf"{re.escape(k)}\s*=", stripped)]:
            line = f"{key} = {todo.pop(key)}"
            comment = raw[raw.index("#") :] if "#" in raw else ""
            lines[i] = f"{line:29} {comment}".rstrip() if comment else line
    new = [f"{key} = {value}" for key, value in todo.items()]
    if filter_end is None:
        lines += ["", "[filter]", *new]
    else:
        lines[filter_end:filter_end] = new
    new_text = eol.join(lines) + eol
    try:
        table = tomllib.loads(new_text)["filter"]
        placed = all(table[key] == float(value) for key, value in written.items())
    except (tomllib.TOMLDecodeError, KeyError, TypeError):
        placed = False
    if not placed:
        wanted = ", ".join(f"`{key} = {value}`" for key, value in written.items())
        raise ValueError(
            f"cannot place {', '.join(written)} in {path} safely; add {wanted} "
            "under [filter] by hand"
        )
    if old is not None:
        mode = stat.S_IMODE(old.st_mode)
    else:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    try:
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
    except OSError as exc:  # its message names the temporary file, not the user's
        raise OSError(exc.errno, f"cannot write {target}: {exc.strerror}") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            if old is not None and os.geteuid() == 0:
                os.fchown(f.fileno(), old.st_uid, old.st_gid)
            os.fchmod(f.fileno(), mode)
            f.write(new_text)
        if check is not None:
            check(Path(tmp))
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _refused_values(path: Path, values: Mapping[str, float]) -> str | None:
    """Why writing ``values`` into ``path`` would give a config file the daemon refuses,
    naming the key, the value and its likely cause; None when it would be taken.

    The file is read again as it is now, without this run's source flags, as
    ``lunad serve --config`` reads it; each value is checked as it will read back from
    the file (``_toml_float``) with the file's other [filter] settings, in a
    ``FilterConfig`` built as ``load_config`` builds it. A file that is refused already
    is said to be so: this run's values are not what is wrong with it.
    """
    from lunad.daemon.config import load_config
    from lunad.daemon.errors import ConfigError

    stored: dict[str, Any] = {key: float(_toml_float(key, value)) for key, value in values.items()}
    wanted = ", ".join(f"`{key} = {_toml_float(key, value)}`" for key, value in values.items())
    try:
        current = load_config(path, settings_required=False).filter.to_filter_config()
    except ConfigError as exc:
        return (
            f"{path} is refused already, before this run's values ({exc}); fix that and "
            f"run again, or add {wanted} under [filter] by hand"
        )
    for key in stored:
        try:
            replace(current, **{key: stored[key]})
        except ValueError as exc:
            return (
                f"the measured {key} = {stored[key]:g} would make the daemon refuse {path} "
                f"({exc}); {VALUE_HINTS[key]}"
            )
    try:
        replace(current, **stored)
    except ValueError as exc:
        return f"the measured {', '.join(stored)} would make the daemon refuse {path} ({exc})"
    return None


def _flag_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the measurement flags, naming the flag, or None.

    Checked before the sensor opens: a value no calibration can use would otherwise be
    found only after ``--seconds`` of measuring (R cos(angle) outside (0, 1]), or not
    at all (a distance of 0 or below, which only the mismatch warning reads), and a
    typo in --angle or --lux (89.9999999 degrees, 30000000 lux) gave a figure the
    config then refused.
    """
    if not 0 < args.reflectivity <= 1:
        return f"--reflectivity must be above 0 and at most 1, got {args.reflectivity}"
    if not 0 <= args.angle <= ANGLE_MAX_DEG:
        return (
            f"--angle must be from 0 to {ANGLE_MAX_DEG:g} degrees (every figure is divided "
            f"by cos(angle), which steeper angles take towards 0), got {args.angle}"
        )
    if not 0 < args.distance < math.inf:
        return f"--distance must be positive and finite (metres), got {args.distance}"
    if not 0 < args.seconds < math.inf:
        return f"--seconds must be positive and finite, got {args.seconds}"
    if args.lux is not None and not 0 <= args.lux <= LUX_MAX:
        return (
            f"--lux must be from 0 to {LUX_MAX:g} (lux at the target; the brightest "
            f"sunlight is about 120000), got {args.lux}"
        )
    if args.fit_k and not (args.lux or 0) > 0:
        return "--fit-k needs --lux above 0: a lux meter reading at the target (20-40 klux)"
    return None


def add_parser(sub: Any) -> None:
    """Register ``calibrate``."""
    p = sub.add_parser(
        "calibrate",
        help="measure amp_ref and the noise constants on a target of known reflectivity",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.usage_exit_code = 78
    add_source_args(p)
    p.add_argument(
        "--reflectivity", type=float, required=True, metavar="R", help="above 0, at most 1"
    )
    p.add_argument("--distance", type=float, required=True, metavar="M", help="metres, above 0")
    p.add_argument(
        "--angle",
        type=float,
        default=0.0,
        metavar="DEG",
        help=f"incidence angle, 0 to {ANGLE_MAX_DEG:g} (default 0: square to the beam)",
    )
    p.add_argument(
        "--seconds", type=float, default=5.0, metavar="S", help="how long to measure (default 5)"
    )
    p.add_argument(
        "--lux",
        type=float,
        metavar="L",
        help=f"ambient light at the target from a lux meter, 0 to {LUX_MAX:g} (default:"
        " taken as dark, 0; indoor light of 500 lux adds about 0.1 mm to sigma0)",
    )
    p.add_argument(
        "--fit-k",
        action="store_true",
        help="fit k_m_per_lux, the noise's growth with light, with the configured sigma0"
        " instead of measuring sigma0; needs --lux above 0",
    )
    p.add_argument(
        "--write",
        action="store_true",
        help="write what was measured (amp_ref, and sigma0_m or k_m_per_lux) into --config FILE",
    )
    p.set_defaults(func=run)


def _amp_figure(amp: float) -> str:
    """An amp figure to 0.1 as the config takes it, in four significant figures past a
    million: a reflectivity typed 1e-300 gives an amp_ref of 1e303, which is refused
    but still reported, and should not print as 300 digits."""
    return f"{amp:.1f}" if abs(amp) < 1e6 else f"{amp:.4g}"


def report(
    cal: Calibration, args: argparse.Namespace, cfg: FilterConfig, sigma0_set: bool = False
) -> list[str]:
    """The lines ``run`` prints on stdout for ``cal``: each figure with its uncertainty."""
    sp = cal.spread
    out = [
        f"{cal.used} readings used, {cal.rejected} flagged by the sensor; median amp "
        f"{cal.median_amp:.0f}, median distance {cal.median_distance_m:.3f} m",
        f"amp_ref = {_amp_figure(cal.amp_ref)} ± {_amp_figure(cal.amp_ref_err)}   (S = 1: "
        f"R cos(angle) = 1 at 2 m; this target's S = R cos(angle) (2 m / {args.distance:g} m)^2 = "
        f"{cal.strength:.3g})",
    ]
    if sp.sd_m is not None and cal.c is not None:
        out += [
            f"reading noise {sp.sd_m.value * 1e3:.1f} ± {sp.sd_m.err * 1e3:.1f} mm, the 1 cm "
            f"step's share taken out ({sp.differences} second differences, {sp.dropped} "
            "dropped as spikes)",
            f"noise at S = 1: c = sigma0 + k L = {cal.c.value * 1e3:.2f} ± "
            f"{cal.c.err * 1e3:.2f} mm",
        ]
    if cal.sigma0 is not None:
        if args.lux is None:
            how = (
                "--lux not given: the target is taken as dark; light adds k L = "
                f"{cfg.k_m_per_lux * 1e6:.2g} mm per klux"
            )
        elif args.lux == 0:
            how = "in the dark, --lux 0"
        else:
            how = f"c - k L with k = {cfg.k_m_per_lux:.3g} m/lux and L = {args.lux:g} lux"
        out.append(
            f"sigma0_m = {cal.sigma0.value:.3g} ± {cal.sigma0.err:.2g}   "
            f"({cal.sigma0.value * 1e3:.2f} ± {cal.sigma0.err * 1e3:.2f} mm; {how})"
        )
    if cal.k is not None:
        out.append(
            f"k_m_per_lux = {cal.k.value:.3g} ± {cal.k.err:.2g}   ((c - sigma0) / L with "
            f"sigma0 = {cfg.sigma0_m:.3g} m from the config and L = {args.lux:g} lux; "
            f"{cal.k.value * 1e6:.3g} mm per klux)"
        )
    if cal.not_measured is not None:
        out.append(cal.not_measured)
    if cal.sigma0 is None and not sigma0_set:
        low, high = DATASHEET_SIGMA0_RANGE_MM
        out.append(
            f"sigma0_m stays {SIGMA0_DEFAULT_M:g}, the datasheet fit, not measured on this "
            f"sensor: each mm this sensor's sigma0 differs from it moves lux_est by "
            f"{1e-3 / cfg.k_m_per_lux / 1e3:.0f} klux (1 mm / k), and the datasheet's "
            f"tables allow {low:g}-{high:g} mm, so read lux_est as dark, indoor or "
            "daylight, not as a figure"
        )
    return out


def run(args: argparse.Namespace) -> int:
    """Measure, report, and with ``--write`` update the config file.

    SIGINT (Ctrl-C) or SIGTERM during the measurement aborts it: nothing is reported
    or written and the exit code is 128 + the signal. A cut-short run would otherwise
    be used as if complete, and a reading taken while someone walks up to stop it is
    not a calibration.
    """
    from lunad.daemon.config import load_config
    from lunad.daemon.errors import (
        EX_CONFIG,
        EX_UNAVAILABLE,
        ConfigError,
        SourceLostError,
        SourceOpenError,
    )
    from lunad.daemon.sources.base import open_source
    from lunad.daemon.sources.serial import PortBusyError
    from lunad.protocol import Frame, FrameParser, commands

    if (problem := _flag_problem(args)) is not None:
        print(f"lunad calibrate: {problem}", file=sys.stderr)
        return EX_CONFIG
    if args.write and not args.config:
        print("lunad calibrate: --write needs --config FILE", file=sys.stderr)
        return EX_CONFIG
    try:
        cfg = load_config(args.config, source_overrides(args), settings_required=False)
    except ConfigError as exc:
        print(f"lunad calibrate: {exc}", file=sys.stderr)
        return EX_CONFIG
    filter_cfg = cfg.filter.to_filter_config()
    sigma0_set = cfg.filter.sets("sigma0_m")  # by an earlier run, or by hand
    if args.fit_k and not sigma0_set:
        print(
            f"warning: sigma0_m is the datasheet's {SIGMA0_DEFAULT_M:g}, not measured on this "
            "sensor, and k inherits its error: run `lunad calibrate --lux 0 --write` in "
            "the dark first",
            file=sys.stderr,
        )
    stop = threading.Event()
    stopped_by: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    try:
        src = open_source(cfg.source)
    except SourceOpenError as exc:
        print(f"lunad calibrate: {exc}", file=sys.stderr)
        return EX_UNAVAILABLE if isinstance(exc, PortBusyError) else 1
    parser = FrameParser(cfg.sensor.frame_format)
    readings: list[tuple[float, int]] = []
    with src:
        if cfg.sensor.configure:
            src.write(commands.startup(cfg.sensor.frame_rate_hz, cfg.sensor.frame_format))
        deadline = time.monotonic() + args.seconds
        while not stop.is_set() and (left := deadline - time.monotonic()) > 0:
            try:
                chunk = src.read(min(left, 0.5))
            except SourceLostError as exc:
                print(f"lunad calibrate: lost the sensor: {exc}", file=sys.stderr)
                return 1
            if chunk is None:
                continue
            for item in parser.feed(chunk.data, chunk.t_mono_ns):
                if isinstance(item, Frame):
                    readings.append((item.distance_m or 0.0, item.amp))
    if stopped_by:
        name = signal.Signals(stopped_by[0]).name
        print(f"lunad calibrate: {name}: measurement aborted, nothing written", file=sys.stderr)
        return 128 + stopped_by[0]
    try:
        cal = compute(
            readings,
            args.reflectivity,
            args.angle,
            args.distance,
            lux=args.lux,
            fit_k=args.fit_k,
            filter_cfg=filter_cfg,
        )
    except ValueError as exc:
        print(f"lunad calibrate: {exc}", file=sys.stderr)
        return 1
    print("\n".join(report(cal, args, filter_cfg, sigma0_set)))
    off = abs(cal.median_distance_m - args.distance)
    if off > DISTANCE_TOLERANCE * args.distance + DISTANCE_SLACK_M:
        written = " Nothing written." if args.write else ""
        print(
            f"lunad calibrate: the sensor reads {cal.median_distance_m:.3f} m, not "
            f"{args.distance:g} m.{written} Is the target at {args.distance:g} m, filling "
            "the beam? (The figures above assume so.)",
            file=sys.stderr,
        )
        return DISTANCE_EXIT
    code = 0
    if cal.not_measured is not None and (args.lux is not None or args.fit_k):
        code = NOISE_ASKED_EXIT
    if args.write:
        values = {"amp_ref": cal.amp_ref}
        if cal.sigma0 is not None:
            values["sigma0_m"] = cal.sigma0.value
        if cal.k is not None:
            values["k_m_per_lux"] = cal.k.value
        keys = ", ".join(values)
        path = Path(args.config)
        if (refused := _refused_values(path, values)) is not None:
            print(f"lunad calibrate: --write: nothing written: {refused}", file=sys.stderr)
            return EX_CONFIG

        def loads(new: Path) -> None:
            """The new file as the daemon will read it (the check above covers [filter]
            alone); named as ``path`` in the message, not as the temporary file."""
            try:
                load_config(new)
            except ConfigError as exc:
                said = str(exc).replace(str(new), str(path))
                raise ValueError(f"nothing written: {path} would be refused: {said}") from None

        try:
            write_filter_values(path, values, check=loads)
        except (OSError, ValueError) as exc:
            print(f"lunad calibrate: --write: {exc}", file=sys.stderr)
            return EX_CONFIG
        print(f"wrote [filter] {keys} to {args.config}; `systemctl reload lunad@NAME` applies it")
    return code
