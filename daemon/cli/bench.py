"""``lunad bench``: performance figures you can quote."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lunad.daemon.cli.signals import Interrupts

DESCRIPTION = """\
Measure lunad on this machine and print the figures.

  bulk decode     numpy decode of a recorded stream (frames/s), checked frame for
                  frame against the streaming parser
  pipeline        parse + filter + encode of one frame, pure Python, no I/O (us);
                  and one --publish-hz message (its frames parsed and filtered, the last
                  encoded) back to back and after a publish period asleep, as the
                  low-power loop runs it: what cold caches cost here
  serve           `lunad serve` at 250 Hz against the virtual sensor, and the same
                  with --publish-hz 50: CPU per frame (/proc/<pid>/stat, all
                  threads), latency from the frame's last byte written to a
                  subscriber's receipt (p50, p99), idle CPU and wake-ups with a
                  silent sensor (schedstat, all threads; no polling: it wakes only
                  for the health message), peak RSS, start-up to the first
                  message. A floor reference (a
                  minimal read-checksum-publish loop, lunad.daemon.tools.bench) runs in
                  the same rounds, alternating; lunad / floor is the headline.

The machine should be otherwise quiet; the serve figures are medians over --rounds.

--filter-against REV runs only one comparison instead: RangeFilter.step of this
checkout's filters/ (the work tree, uncommitted edits included) against filters/ of
git revision REV, with today's sim and protocol around both. Both run on the same
frames (room_sweep, sun_ramp, static, wall_drive, obstacles in both worlds, seed 0),
each in its own process, alternating for --rounds rounds (default 5), best of 7
passes each: ns per frame per round and the median of today / old, judged against
<= 1.2x; and Python bytecodes per frame, which the host's load does not move. It
needs git and lunad installed from a git checkout (pip install -e).

Exit codes: 0 when every run worked (a missed target is reported, not an error); 1
when a serve run or a --filter-against child failed; 2 for a bad option; 69 when
--filter-against has no git or no git checkout to read; 78 for a --filter-against
revision that names no commit with filters/; 128 + the signal's number (130 for
Ctrl-C, 143 for SIGTERM) when stopped early, with every process it started stopped.
"""

EPILOG = """\
examples:
  lunad bench                         # full run, about 3 minutes
  lunad bench --quick                 # short windows, one round (smoke test)
  lunad bench --format json > bench.json
  lunad bench --rounds 5 --duration 20
  lunad bench --pin                   # process under test alone on the last CPU
  lunad bench --filter-against ab60136
                                      # today's filter against the one at ab60136
  lunad bench --filter-against HEAD~1 --rounds 3 --format json
  python -m lunad.daemon.tools.bench --device /dev/serial0 --publish tcp://127.0.0.1:7790
                                      # the floor loop alone
"""


def add_parser(sub: Any) -> None:
    """Register ``bench``."""
    p = sub.add_parser(
        "bench",
        help="measure throughput, CPU, latency and memory",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="short windows and one round")
    p.add_argument("--format", choices=("table", "json"), default="table", help="output format")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="steady window of each serve run, seconds (default 12; --quick 2)",
    )
    p.add_argument(
        "--rounds",
        type=int,
        metavar="N",
        help="serve rounds, or --filter-against rounds, alternating (default 3, "
        "--filter-against 5; --quick 1)",
    )
    p.add_argument(
        "--publish-hz",
        type=float,
        default=50.0,
        metavar="N",
        help="low-power rate, 1..250 (default 50)",
    )
    p.add_argument(
        "--pin",
        action="store_true",
        help="run the process under test on the last CPU and the sensor and subscriber on "
        "the others: steadier ratios on a shared machine (needs 2 CPUs or more)",
    )
    p.add_argument(
        "--filter-against",
        metavar="REV",
        help="only compare RangeFilter.step with the filter at git revision REV "
        "(a hash, tag, HEAD~1): ns and bytecodes per frame, target <= 1.2x",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run every benchmark and print the figures; 0 when every run worked."""
    from lunad.daemon.cli.signals import Interrupts
    from lunad.daemon.tools import bench

    quick = bool(args.quick)
    if args.filter_against is not None:
        return _run_filter(args, quick)
    duration = args.duration if args.duration is not None else (2.0 if quick else 12.0)
    rounds = args.rounds if args.rounds is not None else (1 if quick else 3)
    if duration <= 0 or rounds < 1:
        print("lunad bench: --duration must be > 0 and --rounds >= 1", file=sys.stderr)
        return 2
    if not 1 <= args.publish_hz <= bench.SENSOR_HZ:  # the pipeline sleeps 1/N a message
        print(f"lunad bench: --publish-hz must be 1..{bench.SENSOR_HZ}", file=sys.stderr)
        return 2
    interrupts = Interrupts(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    try:
        return _run(args, quick, duration, rounds, interrupts)
    except KeyboardInterrupt:  # every run's finally has stopped its processes by now
        return interrupts.exit_code("lunad bench")


def _run(
    args: argparse.Namespace, quick: bool, duration: float, rounds: int, interrupts: Interrupts
) -> int:
    """Every benchmark, then the figures; 0 when every run worked."""
    import dataclasses
    import json
    import logging

    from lunad.daemon.tools import bench

    log = logging.getLogger("lunad.bench")

    log.info("bulk decode")
    bulk = bench.bench_bulk(200_000 if quick else 2_000_000, repeats=3 if quick else 5)
    log.info("pipeline")
    pipe = bench.bench_pipeline(
        5_000 if quick else 50_000, publish_hz=args.publish_hz, messages=50 if quick else 200
    )
    log.info("serve: %d round(s) of %.0f s windows", rounds, duration)
    serve = bench.bench_serve(
        rounds=rounds,
        duration_s=duration,
        warmup_s=1.0 if quick else 2.0,
        idle_s=1.0 if quick else 3.0,
        publish_hz=args.publish_hz,
        progress=log.info,
        pin=bool(args.pin),
        hold=interrupts.held,
    )
    lunad, floor, low = serve["lunad"], serve["floor"], serve["lunad_hz"]
    ratios, per_round, met = bench.verdict(bulk, serve)
    failed_runs = [
        r for s in serve.values() for r in s.runs if r.exit_code not in (0, None) or not r.frames
    ]
    if args.format == "json":
        doc = {
            "bulk": dataclasses.asdict(bulk),
            "pipeline": dataclasses.asdict(pipe),
            "serve": {k: dataclasses.asdict(v) for k, v in serve.items()},
            "ratios": ratios,
            "round_ratios": per_round,
            "targets": bench.TARGETS,
            "met": met,
            "settings": {"quick": quick, "duration_s": duration, "rounds": rounds},
        }
        print(json.dumps(doc, indent=2))
    else:
        print(
            bench.render_table(
                bulk, pipe, lunad, floor, low, ratios, per_round, met, rounds, duration
            )
        )
    for r in failed_runs:
        log.error("%s run exited %s:\n%s", r.variant, r.exit_code, r.log_tail)
    return 1 if failed_runs else 0


def _run_filter(args: argparse.Namespace, quick: bool) -> int:
    """``--filter-against REV``: this one comparison, printed; 0 when it ran (a missed
    target is reported, not an error)."""
    import dataclasses
    import json
    import logging

    from lunad.daemon.cli.signals import Interrupts
    from lunad.daemon.errors import EX_CONFIG, EX_UNAVAILABLE
    from lunad.daemon.tools.bench import filter_cost

    prog = "lunad bench"
    if args.duration is not None or args.pin:
        print(
            f"{prog}: --duration and --pin are for the serve runs, not --filter-against",
            file=sys.stderr,
        )
        return 2
    rounds = args.rounds if args.rounds is not None else (1 if quick else filter_cost.ROUNDS)
    if rounds < 1:
        print(f"{prog}: --rounds must be >= 1", file=sys.stderr)
        return 2
    interrupts = Interrupts(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    log = logging.getLogger("lunad.bench")
    try:
        cost = filter_cost.compare(args.filter_against, rounds=rounds, progress=log.info)
    except KeyboardInterrupt:  # subprocess.run has killed its child; the files are gone
        return interrupts.exit_code(prog)
    except filter_cost.GitUnavailable as exc:
        print(f"{prog}: --filter-against: {exc}", file=sys.stderr)
        return EX_UNAVAILABLE
    except filter_cost.UnknownRevision as exc:
        print(f"{prog}: --filter-against: {exc}", file=sys.stderr)
        return EX_CONFIG
    except filter_cost.FilterCostError as exc:
        print(f"{prog}: --filter-against: {exc}", file=sys.stderr)
        return 1
    if args.format == "json":
        doc = {
            **dataclasses.asdict(cost),
            "bytecode_ratio": cost.bytecode_ratio,
            "target_ratio_max": filter_cost.RATIO_MAX,
            "met": cost.met,
        }
        print(json.dumps(doc, indent=2))
    else:
        print(filter_cost.format(cost))
    return 0
