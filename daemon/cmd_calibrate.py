"""``lunad calibrate``: measure amp_ref on a target of known reflectivity.

The paper recommends pre-calibrating on targets of known reflectivity (section VI,
recommendation 2). Strength is S = amp / amp_ref with S = R cos(theta) (paper eq. 1)
at the calibration distance, so one target of known R at a known angle gives
amp_ref = median(amp) / (R cos(theta)). The median makes the figure robust to the odd
multipath spike; readings the sensor itself flags (amp < 100, amp > 32768) are left out.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lunad.daemon.source_args import add_source_args, source_overrides

DESCRIPTION = """\
Measure amp_ref, the amp that means strength S = 1, on a target of known
reflectivity (a white matte card is about 0.9) at a known distance and angle, and
write it into the config file's [filter] section (comments are kept).

Put the target square to the beam (or give --angle), fill the 2 degree beam with it
(at 2 m the spot is 7 cm wide), and keep the scene still while it measures.
Ctrl-C aborts: nothing is written.
"""

EPILOG = """\
examples:
  lunad calibrate --device /dev/serial0 --reflectivity 0.9 --distance 2.0
  lunad calibrate --config /etc/lunad/front.toml --reflectivity 0.9 --distance 1.5 --write
  lunad calibrate --bus 1 --reflectivity 0.5 --distance 1.0 --angle 20 --seconds 10
"""

AMP_MIN_VALID = 100  # below: the sensor reports no distance (M05 p.16)
AMP_AMBIENT = 32768  # above: ambient overexposure (M05 p.14)
DISTANCE_TOLERANCE = 0.1  # relative disagreement with --distance that earns a warning
MIN_READINGS = 20
FILTER_TABLE: dict[str, Any] = {"filter": {}}  # what _table_header gives for [filter]


@dataclass(frozen=True, slots=True)
class Calibration:
    """What one calibration measured.

    Attributes:
        amp_ref: amp for S = 1 at this distance.
        median_amp: median amp of the usable readings.
        median_distance_m: median distance the sensor reported, metres.
        used: readings used; rejected: readings the sensor flagged (weak or overexposed).
    """

    amp_ref: float
    median_amp: float
    median_distance_m: float
    used: int
    rejected: int


def compute(
    readings: list[tuple[float, int]], reflectivity: float, angle_deg: float
) -> Calibration:
    """amp_ref from (distance_m, amp) readings of a target with known R and angle.

    Raises:
        ValueError: R cos(theta) is not positive, or fewer than MIN_READINGS usable readings.
    """
    s = reflectivity * math.cos(math.radians(angle_deg))
    if not 0 < s <= 1:
        raise ValueError(f"R cos(angle) must be in (0, 1], got {s:.3f}")
    good = [(d, a) for d, a in readings if AMP_MIN_VALID <= a <= AMP_AMBIENT and d > 0]
    if len(good) < MIN_READINGS:
        raise ValueError(
            f"only {len(good)} usable readings of {len(readings)} (need {MIN_READINGS}): "
            "is the target in the beam and the sensor streaming?"
        )
    amp = statistics.median(a for _, a in good)
    dist = statistics.median(d for d, _ in good)
    return Calibration(amp / s, amp, dist, len(good), len(readings) - len(good))


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


def write_amp_ref(path: Path, amp_ref: float) -> None:
    """Set ``[filter] amp_ref`` in a TOML file, keeping everything else; atomic replace.

    The new file keeps the old one's permission bits, and its owner and group when we
    run as root: the daemon reads it as its own user (``User=lunad`` in the unit), and a
    temporary file is created 0600 and owned by us. A new file gets 0666 less the umask,
    as ``open()`` would give it.

    A symlinked ``path`` (``/etc/lunad/front.toml`` pointing into a config repository) is
    followed: the file it points to is replaced, in its own directory, and the link
    stays. Replacing ``path`` itself would swap the link for a copy and leave the
    config the link named, the one that is maintained, with the old amp_ref.

    Raises:
        ValueError: the edit would not leave a file where ``[filter] amp_ref`` reads back
            as ``amp_ref`` (a layout this line-based edit does not follow); the file is
            left as it was.
        OSError: the file cannot be read or replaced.
    """
    target = path.resolve()
    old = target.stat() if target.exists() else None
    text = target.read_text(encoding="utf-8") if old is not None else ""
    line = f"amp_ref = {amp_ref:.1f}"
    lines = text.splitlines()
    section: dict[str, Any] | None = None
    for i, raw in enumerate(lines):
        stripped = raw.strip()
        if (header := _table_header(raw)) is not None:
            if section == FILTER_TABLE:
                lines.insert(i, line)
                break
            section = header
        elif section == FILTER_TABLE and re.match(r"amp_ref\s*=", stripped):
            comment = raw[raw.index("#") :] if "#" in raw else ""
            lines[i] = f"{line:29} {comment}".rstrip() if comment else line
            break
    else:
        if section == FILTER_TABLE:
            lines.append(line)
        else:
            lines += ["", "[filter]", line]
    new_text = "\n".join(lines) + "\n"
    try:
        written = tomllib.loads(new_text)["filter"]["amp_ref"]
    except (tomllib.TOMLDecodeError, KeyError, TypeError):
        written = None
    if written != float(f"{amp_ref:.1f}"):
        raise ValueError(
            f"cannot place amp_ref in {path} safely; add `amp_ref = {amp_ref:.1f}` "
            "under [filter] by hand"
        )
    if old is not None:
        mode = stat.S_IMODE(old.st_mode)
    else:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            if old is not None and os.geteuid() == 0:
                os.fchown(f.fileno(), old.st_uid, old.st_gid)
            os.fchmod(f.fileno(), mode)
            f.write(new_text)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _flag_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the measurement flags, naming the flag, or None.

    Checked before the sensor opens: a value no calibration can use would otherwise be
    found only after ``--seconds`` of measuring (R cos(angle) outside (0, 1]), or not
    at all (a distance of 0 or below, which only the mismatch warning reads).
    """
    if not 0 < args.reflectivity <= 1:
        return f"--reflectivity must be above 0 and at most 1, got {args.reflectivity}"
    if not 0 <= args.angle < 90:
        return f"--angle must be at least 0 and below 90 degrees, got {args.angle}"
    if not 0 < args.distance < math.inf:
        return f"--distance must be positive and finite (metres), got {args.distance}"
    if not 0 < args.seconds < math.inf:
        return f"--seconds must be positive and finite, got {args.seconds}"
    return None


def add_parser(sub: Any) -> None:
    """Register ``calibrate``."""
    p = sub.add_parser(
        "calibrate",
        help="measure amp_ref on a target of known reflectivity",
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
        "--angle", type=float, default=0.0, metavar="DEG", help="incidence angle, 0 to below 90"
    )
    p.add_argument(
        "--seconds", type=float, default=5.0, metavar="S", help="how long to measure (default 5)"
    )
    p.add_argument("--write", action="store_true", help="write amp_ref into --config FILE")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Measure, report, and with ``--write`` update the config file.

    SIGINT (Ctrl-C) or SIGTERM during the measurement aborts it: nothing is reported
    or written and the exit code is 128 + the signal. A cut-short run would otherwise
    be used as if complete, and a reading taken while someone walks up to stop it is
    not a calibration.
    """
    from lunad.daemon.config import load_config
    from lunad.daemon.errors import EX_CONFIG, ConfigError, SourceLostError, SourceOpenError
    from lunad.daemon.source import open_source
    from lunad.protocol import Frame, FrameParser, commands

    if (problem := _flag_problem(args)) is not None:
        print(f"lunad calibrate: {problem}", file=sys.stderr)
        return EX_CONFIG
    if args.write and not args.config:
        print("lunad calibrate: --write needs --config FILE", file=sys.stderr)
        return EX_CONFIG
    try:
        cfg = load_config(args.config, source_overrides(args))
    except ConfigError as exc:
        print(f"lunad calibrate: {exc}", file=sys.stderr)
        return EX_CONFIG
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
        return 1
    parser = FrameParser()
    readings: list[tuple[float, int]] = []
    with src:
        if cfg.sensor.configure:
            src.write(commands.startup(cfg.sensor.frame_rate_hz))
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
        cal = compute(readings, args.reflectivity, args.angle)
    except ValueError as exc:
        print(f"lunad calibrate: {exc}", file=sys.stderr)
        return 1
    print(
        f"{cal.used} readings used, {cal.rejected} flagged by the sensor; median amp "
        f"{cal.median_amp:.0f}, median distance {cal.median_distance_m:.3f} m\n"
        f"amp_ref = {cal.amp_ref:.1f}   (S = 1 at {args.distance:g} m)"
    )
    if abs(cal.median_distance_m - args.distance) > DISTANCE_TOLERANCE * args.distance + 0.05:
        print(
            f"warning: the sensor reads {cal.median_distance_m:.3f} m, not {args.distance:g} m: "
            "is the target where you say, and does it fill the beam?",
            file=sys.stderr,
        )
    if args.write:
        try:
            write_amp_ref(Path(args.config), cal.amp_ref)
        except (OSError, ValueError) as exc:
            print(f"lunad calibrate: --write: {exc}", file=sys.stderr)
            return EX_CONFIG
        try:
            load_config(args.config)
        except ConfigError as exc:  # the file was broken before; say so plainly
            print(
                f"lunad calibrate: wrote amp_ref, but the file is invalid: {exc}", file=sys.stderr
            )
            return EX_CONFIG
        print(f"wrote [filter] amp_ref to {args.config}; `systemctl reload lunad@NAME` applies it")
    return 0
