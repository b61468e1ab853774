"""``lunad soak``: the daemon under a seeded schedule of faults, with a PASS/FAIL verdict."""

from __future__ import annotations

import argparse
import fcntl
import signal
import sys
from pathlib import Path
from typing import IO, Any

DESCRIPTION = """\
Run the virtual sensor and `lunad serve` (a real subprocess, as systemd would) for a
long time, subscribe like robot code, and drive a seeded schedule of faults:
garbage bursts, corrupted checksums, cut frames, a silent sensor, unplug/replug at
the same path, 250 Hz then 1 Hz, a baud-rate mismatch, a slow subscriber, a
subscriber that connects and disconnects repeatedly, and SIGHUP reloads.

The schedule is printed first. The report gives frames sent, published and lost,
each fault's recovery time, RSS and open files over time, CPU per frame, and the
verdict. PASS: no valid frame that reached the daemon is missing from the stream
(a slow subscriber's own losses are counted apart), every fault recovered within
5 s, RSS growth under 1 MiB/h after warm-up, no file-descriptor growth, and the
daemon never exited. Exit code 0 only on PASS, 1 on FAIL, 2 on a bad option;
stopped by SIGINT, SIGTERM or SIGHUP, it stops the daemon and the sensor, removes its
temporary folder and exits 128 + the signal's number (130, 143, 129).
"""

EPILOG = """\
examples:
  lunad soak --duration 60s                  # the CI soak
  lunad soak --duration 1h --progress        # a progress line every minute
  lunad soak --duration 24h --seed 7 --keep-logs /var/tmp/soak-7
  lunad soak --duration 10m --format json > soak.json
  lunad soak --duration 60s --rate 250       # the same faults on a 250 Hz stream

Durations: 60s, 10m, 1h, 24h, 1h30m or plain seconds (at least 50 s, at most 168h).
See docs/soak.md for what each fault does and how frames are accounted.
"""


def add_parser(sub: Any) -> None:
    """Register ``soak``."""
    p = sub.add_parser(
        "soak",
        help="long run under injected faults, with a PASS/FAIL verdict",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--duration", default="60s", help="how long: 60s, 10m, 1h, 24h (default 60s)")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the schedule and faults (default 0)"
    )
    p.add_argument("--rate", type=int, default=100, help="sensor frame rate, Hz (default 100)")
    p.add_argument("--progress", action="store_true", help="a progress line every minute")
    p.add_argument("--format", choices=("table", "json"), default="table", help="report format")
    p.add_argument(
        "--keep-logs",
        metavar="DIR",
        help="keep the daemon log, config, report, and recordings of the bytes the sensor "
        "wrote and the daemon read (docs/soak.md)",
    )
    p.set_defaults(func=run)


KEEP_LOGS_LOCK = ".lunad-soak.lock"
"""The file in a ``--keep-logs`` folder a soak holds a lock on while it runs."""


def _check_keep_logs(path: Path) -> IO[str]:
    """Create ``path`` and lock it for this soak now, so that a folder which cannot hold
    the logs, or that another soak writes to, is a bad option before anything starts.
    Two soaks on one folder deleted each other's recordings, and each passed its byte
    check on the other's bytes. Returns the lock's file: keep it open while the soak
    runs (the lock goes with the process).

    Raises:
        OSError: it cannot be created (a file in the way) or written, or another soak
            holds it (``BlockingIOError``).
    """
    path.mkdir(parents=True, exist_ok=True)
    lock = open(path / KEEP_LOGS_LOCK, "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise BlockingIOError(f"{path} is in use by another lunad soak") from None
    except OSError:
        lock.close()
        raise
    return lock


def run(args: argparse.Namespace) -> int:
    """Run the soak and print the report; 0 on PASS, 1 on FAIL, 2 on a bad option,
    128 + the signal's number when one stopped it."""
    import json

    from lunad.daemon.cli.signals import Interrupts
    from lunad.daemon.tools import soak
    from lunad.protocol.commands import FRAME_RATES_HZ

    try:
        duration = soak.parse_duration(str(args.duration))
        schedule = soak.build_schedule(duration, args.seed)
    except ValueError as exc:
        print(f"lunad soak: --duration: {exc}", file=sys.stderr)
        return 2
    if args.rate not in FRAME_RATES_HZ or args.rate < 10:
        print(
            "lunad soak: --rate: must be 500/n Hz and at least 10 (e.g. 100, 250)", file=sys.stderr
        )
        return 2
    keep_logs = getattr(args, "keep_logs", None)
    lock = None  # on the --keep-logs folder, held while the soak runs
    if keep_logs:
        try:
            lock = _check_keep_logs(Path(keep_logs))
        except OSError as exc:
            print(f"lunad soak: --keep-logs: {exc}", file=sys.stderr)
            return 2
    fmt = getattr(args, "format", "table")
    text = soak.format_schedule(schedule, args.seed, duration, args.rate)
    print(text, file=sys.stderr if fmt == "json" else sys.stdout, flush=True)

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    # Each stops it as Ctrl-C does, and every finally stops what it started: by
    # SIGTERM's default action its daemon would run on, with its temporary folder
    interrupts = Interrupts(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    try:
        report = soak.Soak(
            duration,
            seed=args.seed,
            rate_hz=args.rate,
            progress=progress if getattr(args, "progress", False) else None,
            keep_logs=keep_logs,
            schedule=schedule,
            held=interrupts.held,
        ).run()
    except KeyboardInterrupt:
        return interrupts.exit_code("lunad soak")
    finally:
        if lock is not None:
            lock.close()
    if fmt == "json":
        print(json.dumps(report.to_json(), indent=1))
    else:
        print()
        print(soak.format_report(report))
    return 0 if report.passed else 1
