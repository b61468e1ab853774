"""The bench's verdict and output: the targets, the ratios to the floor, the table."""

from __future__ import annotations

from typing import Any

TARGETS = {
    "bulk_fps_min": 2_000_000,
    "cpu_ratio_max": 1.25,
    "p99_us_max": 1000.0,
    "p99_ratio_max": 1.5,
    "idle_wakeups_per_health_max": 2.0,
    "rss_mib_max": 60.0,
    "hz_cpu_ratio_max": 0.5,
    "startup_s_max": 1.5,
}


def verdict(
    bulk: Any, serve: dict[str, Any]
) -> tuple[dict[str, float | None], dict[str, list[float | None]], dict[str, bool]]:
    """The figures against ``TARGETS``: lunad's ratios to the floor (of the medians, and
    round by round) and which targets were met. ``serve``: ``bench_serve``'s summaries."""
    lunad, floor, low = serve["lunad"], serve["floor"], serve["lunad_hz"]
    ratios = {
        "cpu": ratio(lunad.cpu_us_per_frame, floor.cpu_us_per_frame),
        "p99": ratio(lunad.lat_p99_us, floor.lat_p99_us),
        "hz_cpu": ratio(low.cpu_us_per_frame, lunad.cpu_us_per_frame),
    }
    per_round = {"cpu": round_ratios(lunad, floor), "hz_cpu": round_ratios(low, lunad)}

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
    return ratios, per_round, met


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
            f"  --publish-hz {hz} / lunad at full rate, CPU",
            _x(ratios["hz_cpu"]),
            f"<= 0.5x: {ok('hz_cpu_ratio')}",
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
