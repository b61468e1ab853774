"""``lunad bench``: performance figures you can quote."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lunad.daemon.cli import Interrupts

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
                  minimal read-checksum-publish loop, lunad.daemon.bench) runs in
                  the same rounds, alternating; lunad / floor is the headline.

The machine should be otherwise quiet; the serve figures are medians over --rounds.

Exit codes: 0 when every run worked (a missed target is reported, not an error); 1
when a serve run failed; 2 for a bad option; 128 + the signal's number (130 for
Ctrl-C, 143 for SIGTERM) when stopped early, with every process it started stopped.
"""

EPILOG = """\
examples:
  lunad bench                         # full run, about 3 minutes
  lunad bench --quick                 # short windows, one round (smoke test)
  lunad bench --format json > bench.json
  lunad bench --rounds 5 --duration 20
  lunad bench --pin                   # process under test alone on the last CPU
  python -m lunad.daemon.bench --device /dev/serial0 --publish tcp://127.0.0.1:7790
                                      # the floor loop alone
"""

TARGETS = {
    "bulk_fps_min": 2_000_000,
    "cpu_ratio_max": 1.25,
    "p99_us_max": 1000.0,
    "p99_ratio_max": 1.5,
    "idle_wakeups_per_health_max": 2.0,
    "rss_mib_max": 60.0,
    "hz_cpu_ratio_max": 0.4,
    "startup_s_max": 1.5,
}


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
        "--rounds", type=int, metavar="N", help="serve rounds, alternating (default 3; --quick 1)"
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run every benchmark and print the figures; 0 when every run worked."""
    from lunad.daemon import bench
    from lunad.daemon.cli import Interrupts

    quick = bool(args.quick)
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

    from lunad.daemon import bench

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
    ratios = {
        "cpu": ratio(lunad.cpu_us_per_frame, floor.cpu_us_per_frame),
        "p99": ratio(lunad.lat_p99_us, floor.lat_p99_us),
        "hz_cpu": ratio(low.cpu_us_per_frame, floor.cpu_us_per_frame),
    }
    per_round = {"cpu": round_ratios(lunad, floor), "hz_cpu": round_ratios(low, floor)}

    def within(key: str, limit: float) -> bool:
        r = ratios[key]
        return r is not None and r <= limit

    met = {
        "bulk_fps": bulk.bulk_fps >= TARGETS["bulk_fps_min"] and bulk.same_as_streaming,
        "cpu_ratio": within("cpu", TARGETS["cpu_ratio_max"]),
        "p99": lunad.lat_p99_us <= TARGETS["p99_us_max"]
        and within("p99", TARGETS["p99_ratio_max"]),
        "idle_cpu": idle_without_polling(lunad) and idle_without_polling(low),
        "rss": max(lunad.rss_mib, low.rss_mib) < TARGETS["rss_mib_max"],
        "hz_cpu_ratio": within("hz_cpu", TARGETS["hz_cpu_ratio_max"]),
        "startup": lunad.startup_s <= TARGETS["startup_s_max"],
    }
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
            "targets": TARGETS,
            "met": met,
            "settings": {"quick": quick, "duration_s": duration, "rounds": rounds},
        }
        print(json.dumps(doc, indent=2))
    else:
        print(render_table(bulk, pipe, lunad, floor, low, ratios, per_round, met, rounds, duration))
    for r in failed_runs:
        log.error("%s run exited %s:\n%s", r.variant, r.exit_code, r.log_tail)
    return 1 if failed_runs else 0


def idle_wakeups_allowed() -> float:
    """Wake-ups a second that a silent lunad may take without polling: its health
    message each ``health_interval_s`` (the default, which the bench runs with) wakes
    the loop that sends it and ZeroMQ's I/O thread that passes it on."""
    from lunad.daemon.config import PublishSection

    interval_s = float(PublishSection.model_fields["health_interval_s"].default)
    return TARGETS["idle_wakeups_per_health_max"] / interval_s


def idle_without_polling(run: Any) -> bool:
    """The target "0 % idle CPU (no polling)" as checked: with the sensor silent the
    process wakes only for its health messages (``idle_wakeups_allowed``). Where the
    kernel counts no wake-ups (no schedstat), its clock ticks must not move at all."""
    wakeups = run.idle_wakeups_per_s
    if wakeups != wakeups:  # NaN
        return bool(run.idle_cpu_pct <= 0.0)
    return bool(wakeups <= idle_wakeups_allowed())


def ratio(a: float, b: float) -> float | None:
    """``a / b``, or None when the floor measured nothing (0 CPU ticks in a short
    window on a loaded machine): no ratio rather than a crash or an infinity."""
    return a / b if b > 0 else None


def round_ratios(a: Any, b: Any) -> list[float | None]:
    """CPU per frame of ``a`` over ``b``'s, round by round (``ServeSummary.runs``).

    The rounds alternate, so each pair ran a minute apart at most: their spread shows
    how far the host moved during the bench, which the ratio of medians hides.
    """
    pairs = zip(a.runs, b.runs, strict=True)
    return [ratio(x.cpu_us_per_frame, y.cpu_us_per_frame) for x, y in pairs]


def _x(r: float | None) -> str:
    return f"{r:.2f}x" if r is not None else "n/a (floor measured 0)"


def render_table(
    bulk: Any,
    pipe: Any,
    lunad: Any,
    floor: Any,
    low: Any,
    ratios: dict[str, float | None],
    per_round: dict[str, list[float | None]],
    met: dict[str, bool],
    rounds: int,
    duration: float,
) -> str:
    """The figures as a plain-text table (one line per figure)."""
    hz = f"{low.publish_hz:g}"

    def ok(key: str) -> str:
        return "met" if met[key] else "MISSED"

    def spread(key: str) -> list[tuple[str, str, str]]:
        rs = per_round[key]
        if len(rs) < 2:
            return []
        each = " ".join(f"{r:.2f}" if r is not None else "n/a" for r in rs)
        return [("    round by round", each, "the spread is the host's")]

    rows: list[tuple[str, str, str]] = [
        (
            "bulk decode (numpy)",
            f"{bulk.bulk_fps / 1e6:.2f} M frames/s",
            f">= 2 M: {ok('bulk_fps')}",
        ),
        ("  same frames as streaming parser", "yes" if bulk.same_as_streaming else "NO", ""),
        ("  streaming parser, whole stream", f"{bulk.streaming_fps / 1e3:.0f} k frames/s", ""),
        ("pipeline parse+filter+encode", f"{pipe.total_us:.1f} us/frame", ""),
        (
            "  parse / filter / encode",
            f"{pipe.parse_us:.1f} / {pipe.filter_us:.1f} / {pipe.encode_us:.1f} us",
            "",
        ),
        (
            f"  one --publish-hz {hz} message ({pipe.message_frames} frames)",
            f"{pipe.message_warm_us:.0f} / {pipe.message_cold_us:.0f} us",
            f"back to back / after {pipe.message_gap_s * 1e3:g} ms asleep",
        ),
        (
            "serve 250 Hz CPU, lunad",
            f"{lunad.cpu_us_per_frame:.0f} us/frame",
            f"{lunad.cpu_pct:.1f} % of a core",
        ),
        (
            "serve 250 Hz CPU, floor",
            f"{floor.cpu_us_per_frame:.0f} us/frame",
            f"{floor.cpu_pct:.1f} % of a core",
        ),
        ("  lunad / floor CPU", _x(ratios["cpu"]), f"<= 1.25x: {ok('cpu_ratio')}"),
        *spread("cpu"),
        ("latency p50, lunad / floor", f"{lunad.lat_p50_us:.0f} / {floor.lat_p50_us:.0f} us", ""),
        (
            "latency p99, lunad / floor",
            f"{lunad.lat_p99_us:.0f} / {floor.lat_p99_us:.0f} us",
            f"<= 1 ms and <= 1.5x ({_x(ratios['p99'])}): {ok('p99')}",
        ),
        (
            "idle CPU (silent sensor), lunad / floor",
            f"{lunad.idle_cpu_pct:.3f} / {floor.idle_cpu_pct:.3f} %",
            f"0 % (no polling): {ok('idle_cpu')}",
        ),
        (
            "  wake-ups a second, lunad / floor",
            f"{lunad.idle_wakeups_per_s:.1f} / {floor.idle_wakeups_per_s:.1f}",
            f"at most {idle_wakeups_allowed():g}: for the health message",
        ),
        (
            "peak RSS, lunad / floor",
            f"{lunad.rss_mib:.1f} / {floor.rss_mib:.1f} MiB",
            f"< 60 MiB: {ok('rss')}",
        ),
        (
            "start-up to first message, lunad / floor",
            f"{lunad.startup_s:.2f} / {floor.startup_s:.2f} s",
            f"<= 1.5 s: {ok('startup')}",
        ),
        (
            f"--publish-hz {hz} CPU",
            f"{low.cpu_us_per_frame:.0f} us/frame",
            f"{low.cpu_pct:.1f} % of a core",
        ),
        (
            f"  --publish-hz {hz} / floor CPU",
            _x(ratios["hz_cpu"]),
            f"<= 0.4x: {ok('hz_cpu_ratio')}",
        ),
        *spread("hz_cpu"),
        (
            f"  --publish-hz {hz} latency p50 / p99",
            f"{low.lat_p50_us:.0f} / {low.lat_p99_us:.0f} us",
            "of the frame it sends; no target",
        ),
        (
            f"  --publish-hz {hz} idle CPU, wake-ups, peak RSS",
            f"{low.idle_cpu_pct:.3f} %, {low.idle_wakeups_per_s:.1f}/s, {low.rss_mib:.1f} MiB",
            "",
        ),
    ]
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    head = (
        f"lunad bench: serve figures are medians of {rounds} round(s), {duration:g} s windows, "
        "250 Hz sensor; CPU is per sensor frame"
    )
    lines = [head, ""]
    lines += [f"{a:<{w0}}  {b:<{w1}}  {c}".rstrip() for a, b, c in rows]
    if floor.lat_p99_us > TARGETS["p99_us_max"]:
        lines += [
            "",
            f"note: the floor's own p99 latency is {floor.lat_p99_us / 1000:.1f} ms, so this host "
            "is busy: latency and CPU",
            "ratios then say more about the host than about lunad (docs/performance.md). Run",
            "again when it is quiet, or with --pin.",
        ]
    return "\n".join(lines)
