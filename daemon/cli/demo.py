"""``lunad demo``: the virtual sensor, the daemon and a live view, together."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lunad.daemon.cli.arg_types import int_at_least, positive_float
from lunad.daemon.errors import EXIT_USAGE

if TYPE_CHECKING:
    from lunad.daemon.cli.signals import Interrupts
    from lunad.sim.scenario import Scenario

DESCRIPTION = """\
Run the whole path for a few seconds with no hardware: a virtual TF-Luna on a pty
(with a little garbage on the line), `lunad serve` as a real subprocess reading it,
and `lunad watch` printing what a robot would receive. Then stop the daemon with
SIGTERM, as systemd would, and compare frames sent with frames published.

Exit codes: 0 when the daemon published every good frame the sensor sent and stopped
cleanly; 1 when it did not, or the virtual sensor failed; 2 for a bad option; 128 +
the signal's number (130 for Ctrl-C, 143 for SIGTERM) when stopped early, after the
daemon and the virtual sensor are stopped and the temporary folder removed.
"""

MIN_DURATION_S = 2.0
"""Shorter, and the demo stops the daemon while it still starts (about 0.2 s on a PC,
1-1.3 s on a Pi Zero 2, docs/performance.md) and holds its first readings back until
their noise is measured (docs/messages.md)."""

EPILOG = """\
examples:
  lunad demo
  lunad demo --duration 20 --rate 250 --scenario sun_ramp
"""


def add_parser(sub: Any) -> None:
    """Register ``demo``."""
    p = sub.add_parser(
        "demo",
        help="sim + daemon + watch for a few seconds",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--duration",
        type=positive_float,
        default=8.0,
        metavar="S",
        help=f"seconds, at least {MIN_DURATION_S:g} (default 8)",
    )
    p.add_argument(
        "--rate",
        type=int,
        default=100,
        metavar="HZ",
        help="frame rate, 500/n Hz: 250, 166, 125, 100, ..., 1 (default 100)",
    )
    p.add_argument(
        "--scenario",
        default="obstacles",
        metavar="NAME|FILE",
        help="what the sensor sees, looped (default: obstacles stepping in and out)",
    )
    p.add_argument(
        "--every", type=int_at_least(1), default=20, metavar="N", help="print every Nth reading"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo; 0 when the daemon published every frame the sensor sent."""
    from lunad.daemon.cli.signals import Interrupts
    from lunad.protocol.commands import FRAME_RATES_HZ
    from lunad.sim.scenario import ScenarioError, load_scenario

    if args.rate == 0 or args.rate not in FRAME_RATES_HZ:  # the daemon would refuse it
        print(
            f"lunad demo: --rate must be 500/n Hz (250, 166, 125, 100, ..., 1), got {args.rate}",
            file=sys.stderr,
        )
        return EXIT_USAGE
    if args.duration < MIN_DURATION_S:
        print(
            f"lunad demo: --duration must be at least {MIN_DURATION_S:g} s (the daemon starts"
            f" and measures the noise first), got {args.duration:g}",
            file=sys.stderr,
        )
        return EXIT_USAGE
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        print(f"lunad demo: --scenario: {exc}", file=sys.stderr)
        return EXIT_USAGE

    interrupts = Interrupts(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    try:
        return _run(args, scenario, interrupts)
    except KeyboardInterrupt:  # before the watcher started, or while stopping
        return interrupts.exit_code("lunad demo")


def _run(args: argparse.Namespace, scenario: Scenario, interrupts: Interrupts) -> int:
    """Sensor, daemon and watcher, until ``--duration`` or a signal.

    The sensor and the daemon start under ``interrupts.held()``, so that a signal
    arriving while either starts waits for the ``finally`` that stops it.
    """
    from lunad.daemon.cli.watch import watch
    from lunad.sim.edges import edge_view
    from lunad.sim.physics import RealisticSensor
    from lunad.sim.pty_device import DeviceError, PtyDevice

    with tempfile.TemporaryDirectory(prefix="lunad-demo-") as tmp:
        link = Path(tmp) / "tfluna"
        endpoint = f"ipc://{tmp}/lunad.sock"
        model = RealisticSensor()
        length = scenario.duration_s
        dev = PtyDevice(
            lambda t: scenario.truth_at(t % length),
            model=model,
            view=edge_view(scenario.step_times_s, scenario.truth_at, model.amp_of, length),
            rate_hz=args.rate,
            link=link,
            seed=1,
            garbage_rate=0.02,
            output_enabled=False,
        )
        try:
            try:
                with interrupts.held():
                    dev.start()
                print(
                    f"virtual TF-Luna on {dev.path}: scenario {scenario.name} "
                    f"({scenario.description}), {args.rate} Hz, garbage before 2 % of frames"
                )
                cmd = [
                    sys.executable,
                    "-m",
                    "lunad.daemon.cli",
                    "serve",
                    "--device",
                    str(link),
                    "--publish",
                    endpoint,
                    "--name",
                    "demo",
                    "--rate",
                    str(args.rate),
                ]
                print("starting: lunad " + " ".join(cmd[3:]), flush=True)
                daemon: subprocess.Popen[bytes] | None = None
                quiet = threading.Timer(max(0.5, args.duration - 0.5), dev.pause, (3600.0,))
                quiet.daemon = True  # an interrupted demo must not wait for it
                try:
                    with interrupts.held():
                        daemon = subprocess.Popen(cmd, env={**os.environ, "PYTHONUNBUFFERED": "1"})
                    quiet.start()
                    seen = watch(endpoint, sys.stdout, every=args.every, duration=args.duration)
                finally:
                    quiet.cancel()
                    t0 = time.monotonic()
                    code, by_itself = (None, False) if daemon is None else stop_daemon(daemon)
                stop_s = time.monotonic() - t0
                sent = dev.frames_sent
                junk = dev.garbage_bytes
            finally:
                dev.close()
        except DeviceError as exc:  # its thread died: the figures below would mean nothing
            print(f"lunad demo: {exc}", file=sys.stderr)
            return 1
        if interrupts.got:  # the watcher took the Ctrl-C: frames were still coming
            return interrupts.exit_code("lunad demo")
        published = 0 if seen.last_seq is None else seen.last_seq + 1
        print(
            f"\nThe virtual sensor sent {sent} good frames and {junk} garbage bytes.\n"
            f"The daemon published {published} readings (seq 0..{published - 1}); the watcher,"
            f" which joined late, received {seen.readings} with {seen.lost} lost.\n"
            + (
                f"The daemon exited by itself, with code {code}, before the demo's end."
                if by_itself
                else f"The daemon exited with code {code} {stop_s:.2f} s after SIGTERM."
            )
        )
    return 0 if code == 0 and published == sent else 1


def stop_daemon(daemon: subprocess.Popen[bytes]) -> tuple[int, bool]:
    """SIGTERM, as systemd stops it; killed after 5 s. Returns its exit code, and
    whether it had exited by itself before (its log on stderr says why)."""
    code = daemon.poll()
    if code is not None:
        return code, True
    daemon.send_signal(signal.SIGTERM)
    try:
        return daemon.wait(timeout=5), False
    except subprocess.TimeoutExpired:
        daemon.kill()
        return daemon.wait(), False
