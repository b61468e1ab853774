"""``lunad sim``: a virtual TF-Luna on a pseudo-terminal."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lunad.sim.physics import Truth

DESCRIPTION = """\
Play a virtual TF-Luna on a pseudo-terminal, behind a stable symlink that lunad
serve (or any serial program) opens like a real port. Frames are paced in real
time; commands (version, frame rate incl. trigger mode, trigger, output on/off,
cm/mm format, save, restore, reset) are answered as the sensor does. Readings
follow a sensor model: `realistic` (default: amp falls with distance squared,
datasheet repeatability, ambient light, saturation, rare multipath spikes) or
`paper` (the paper's equations 1-3 literally). Both apply the sensor's own rules
(amp < 100 reports 0, 1 cm steps). A scenario makes the truth change over time;
for 8 ms after each jump in distance the beam sees both surfaces, and the readings
mix them (an edge: --truth-out still logs the surface at the beam's centre).
"""

EPILOG = """\
examples:
  lunad sim                                    # white target at 2 m, dark, 100 Hz
  lunad sim --rate 250 --lux 30000 --reflectivity 0.3 --angle 40
  lunad sim --garbage-rate 0.05 --corrupt-rate 0.02   # a dirty line
  lunad sim --link /tmp/tfluna --duration 10 --truth-out truth.csv
  lunad sim --scenario sun_ramp --truth-out truth.csv   # built-in scenario, then it stops
  lunad sim --scenario my_test.toml --loop              # your own scenario file, repeated
  lunad sim --profile paper --lux 2000                  # the paper's equations literally

built-in scenarios: `lunad eval --list` names and describes the 12 (static, approach,
obstacles, sun_ramp, room_sweep, ...); sim/scenario.py shows the file format.
"""


def add_parser(sub: Any) -> None:
    """Register ``sim``."""
    p = sub.add_parser(
        "sim",
        help="virtual TF-Luna on a pty",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--link",
        metavar="PATH",
        help="symlink to the pty (default $XDG_RUNTIME_DIR/lunad/tfluna-sim, or"
        " /tmp/lunad-UID/tfluna-sim without it)",
    )
    p.add_argument(
        "--rate", type=int, metavar="HZ", help="frame rate (default 100, or the scenario's)"
    )
    p.add_argument("--profile", choices=("realistic", "paper"), default="realistic")
    p.add_argument(
        "--noise-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="realistic profile: multiply its noise constants (a different sensor)",
    )
    p.add_argument("--scenario", metavar="NAME|FILE", help="time-varying truth; stops at its end")
    p.add_argument("--loop", action="store_true", help="repeat the scenario instead of stopping")
    p.add_argument("--distance", type=float, metavar="M", help="true distance, m (default 2)")
    p.add_argument(
        "--reflectivity",
        type=float,
        metavar="R",
        help="0..1, up to 10 for a retroreflector (default 0.9)",
    )
    p.add_argument("--angle", type=float, metavar="DEG", help="incidence angle (default 0)")
    p.add_argument("--lux", type=float, metavar="L", help="ambient light, lux (default 0)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--garbage-rate",
        type=float,
        default=0.0,
        metavar="P",
        help="chance per frame of a burst of random bytes",
    )
    p.add_argument(
        "--corrupt-rate",
        type=float,
        default=0.0,
        metavar="P",
        help="chance per frame of a wrong checksum",
    )
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--truth-out", metavar="FILE", help="write truth and reading per frame (CSV)")
    p.set_defaults(func=run)


TRUTH_FLAGS = {
    "distance": "distance_m",
    "reflectivity": "reflectivity",
    "angle": "angle_deg",
    "lux": "lux",
}
"""Each truth flag and the scenario field whose range (``FIELD_LIMITS``) it shares."""
TRUTH_DEFAULTS = {"distance": 2.0, "reflectivity": 0.9, "angle": 0.0, "lux": 0.0}
"""The still target without ``--scenario`` (dark: lux 0)."""


def _bad_number_flag(args: argparse.Namespace) -> str | None:
    """The error line for the first numeric flag out of its range, or None.

    A NaN or infinite truth reached the device thread and killed it (the sim then
    ran mute and exited 0), so every number is checked here, before anything starts.
    """
    from lunad.sim.physics import NOISE_SCALE_MAX
    from lunad.sim.scenario import FIELD_LIMITS

    for flag, key in TRUTH_FLAGS.items():
        value = getattr(args, flag)
        if value is None:
            continue
        if args.scenario:  # the scenario's truth would override the flag without a word
            return f"--{flag}: --scenario sets the truth; give one or the other"
        lo, hi = FIELD_LIMITS[key]
        if not lo <= value <= hi:
            return f"--{flag} must be within {lo:g}..{hi:g}, got {value}"
    for name in ("garbage_rate", "corrupt_rate"):
        if not 0.0 <= getattr(args, name) <= 1.0:
            return f"--{name.replace('_', '-')} must be in 0..1"
    if not 0 < args.noise_scale <= NOISE_SCALE_MAX:  # NaN fails too
        return (
            f"--noise-scale must be above 0 and at most {NOISE_SCALE_MAX:g}, got {args.noise_scale}"
        )
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration >= 0):
        return f"--duration must be a finite number of seconds >= 0, got {args.duration}"
    return None


def _link_in_use(link: Path) -> str | None:
    """The pty ``link`` points at while that pty is open, else None.

    A sim's pty lives while the sim holds it, so a link to one that exists is another
    sim's (or a program's that took the number over after a sim was killed): replacing
    it took the link from a running sim, whose readers then lost it when this one ended.
    """
    try:
        target = os.readlink(link)
    except OSError:  # no link there (or not a link: start() refuses that)
        return None
    return target if target.startswith("/dev/pts/") and os.path.exists(target) else None


def run(args: argparse.Namespace) -> int:
    """Stream until SIGINT/SIGTERM or ``--duration``.

    Returns 0, 2 for a bad option (one line on stderr), EX_CONFIG for an unwritable
    ``--truth-out``, 1 when the virtual sensor's thread died.
    """
    from lunad.daemon.errors import EX_CONFIG
    from lunad.protocol.commands import FRAME_RATES_HZ
    from lunad.sim.physics import PaperSensor, RealisticSensor, Truth
    from lunad.sim.pty_device import TRUTH_OUT_HEADER, DeviceError, PtyDevice

    scenario = None
    if args.scenario:
        from lunad.sim.scenario import ScenarioError, load_scenario

        try:
            scenario = load_scenario(args.scenario)
        except ScenarioError as exc:
            print(f"lunad sim: --scenario: {exc}", file=sys.stderr)
            return 2
    rate = args.rate if args.rate is not None else round(scenario.rate_hz) if scenario else 100
    if rate not in FRAME_RATES_HZ:
        print(f"lunad sim: --rate must be 0 or 500/n Hz (1..250), got {rate}", file=sys.stderr)
        return 2
    bad = _bad_number_flag(args)
    if bad is not None:
        print(f"lunad sim: {bad}", file=sys.stderr)
        return 2
    model = RealisticSensor(args.noise_scale) if args.profile == "realistic" else PaperSensor()
    truth: Truth | Callable[[float], Truth]
    view = None
    duration = args.duration
    if scenario is not None:
        from lunad.sim.edges import edge_view

        length = scenario.duration_s
        truth = (lambda t: scenario.truth_at(t % length)) if args.loop else scenario.truth_at
        view = edge_view(
            scenario.step_times_s,
            scenario.truth_at,
            model.amp_of,
            length if args.loop else None,
        )
        if duration is None and not args.loop:
            duration = length
    else:
        given = {
            f: d if getattr(args, f) is None else getattr(args, f)
            for f, d in TRUTH_DEFAULTS.items()
        }
        truth = Truth(given["distance"], given["reflectivity"], given["angle"], given["lux"])
    done = threading.Event()
    # SIGHUP too (its terminal closed, an SSH session ended): killed by it, the sim left
    # its link to a pty number the next pty takes, and a daemon opening the link then
    # read another program's terminal, or another sim.
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda *_: done.set())
    startup = getattr(args, "startup_signals", None)
    if startup is not None and startup.stopped("lunad sim"):
        return 0  # before a pty and its link are made
    try:
        out = open(args.truth_out, "w", encoding="utf-8") if args.truth_out else None
    except OSError as exc:
        print(
            f"lunad sim: --truth-out: cannot write {args.truth_out}: {exc.strerror}",
            file=sys.stderr,
        )
        return EX_CONFIG
    try:
        if out is not None:
            out.write(TRUTH_OUT_HEADER + "\n")
        dev = PtyDevice(
            truth,
            model=model,
            rate_hz=rate,
            link=args.link,
            seed=args.seed,
            garbage_rate=args.garbage_rate,
            corrupt_rate=args.corrupt_rate,
            truth_out=out,
            on_error=lambda _exc: done.set(),
            view=view,
        )
        held = _link_in_use(dev.link)
        if held is not None:
            print(
                f"lunad sim: --link: {dev.link} points at {held}, a pty still open (another "
                "lunad sim?); stop that one, give another --link, or remove the link",
                file=sys.stderr,
            )
            return 2
        try:
            dev.start()
        except (OSError, ValueError) as exc:
            reason = getattr(exc, "strerror", None) or exc
            print(f"lunad sim: --link: cannot make {dev.path}: {reason}", file=sys.stderr)
            return 2
        try:
            with contextlib.closing(dev):
                print(
                    f"virtual TF-Luna on {dev.path} -> {dev.slave_name}, {rate} Hz, "
                    f"{args.profile} profile{f', scenario {scenario.name}' if scenario else ''}; "
                    "Ctrl-C to stop",
                    flush=True,
                )
                done.wait(duration)
        except DeviceError as exc:
            print(f"lunad sim: {exc}", file=sys.stderr)
            return 1
        print(
            f"sent {dev.frames_sent} good frames, {dev.frames_corrupted} corrupted, "
            f"{dev.garbage_bytes} garbage bytes, {dev.frames_unread} dropped unread, "
            f"{dev.commands_received} commands",
            flush=True,
        )
    finally:
        if out is not None:
            out.close()
    return 0
