"""``lunad bench``: the smoke test of ``--quick`` (about 20 s), and the floor's command bytes.

The full benchmark is not a test; run ``lunad bench`` (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from typing import Any

import pytest

from lunad.daemon.cli import bench as cmd_bench
from lunad.daemon.tools import bench
from lunad.daemon.tools.bench import report
from lunad.protocol import commands


def _run(*argv: str, capsys: Any) -> tuple[int, str]:
    parser = argparse.ArgumentParser(prog="lunad")
    cmd_bench.add_parser(parser.add_subparsers())
    args = parser.parse_args(["bench", *argv])
    code = args.func(args)
    return code, capsys.readouterr().out


def test_floor_sends_the_encoders_output_on_command() -> None:
    assert bench.OUTPUT_ON == commands.set_output_enabled(True)


def test_quick_json_has_every_figure(capsys: Any) -> None:
    code, out = _run("--quick", "--duration", "1", "--format", "json", capsys=capsys)
    assert code == 0
    doc = json.loads(out)
    assert doc["bulk"]["same_as_streaming"] is True
    assert doc["bulk"]["bulk_fps"] > 0
    assert doc["pipeline"]["total_us"] > 0 and doc["pipeline"]["filter_us"] > 0
    assert doc["pipeline"]["message_frames"] == 5  # 250 Hz / --publish-hz 50
    assert doc["pipeline"]["message_warm_us"] > 0 and doc["pipeline"]["message_cold_us"] > 0
    for key in ("lunad", "floor", "lunad_hz"):
        s = doc["serve"][key]
        for figure in (
            "cpu_us_per_frame",
            "lat_p50_us",
            "lat_p99_us",
            "idle_cpu_pct",
            "idle_wakeups_per_s",
            "rss_mib",
            "startup_s",
        ):
            assert s[figure] == s[figure], f"{key}.{figure} is NaN"  # NaN != NaN
        assert all(r["received"] > 0 and r["exit_code"] == 0 for r in s["runs"])
    assert set(doc["ratios"]) == {"cpu", "p99", "hz_cpu"}
    assert {k: len(v) for k, v in doc["round_ratios"].items()} == {"cpu": 1, "hz_cpu": 1}
    assert set(doc["met"]) >= {"bulk_fps", "cpu_ratio", "p99", "idle_cpu", "rss", "startup"}


def test_table_renders_every_line() -> None:
    b = bench.BulkResult(10, 90, 3e6, 2e5, True)
    p = bench.PipelineResult(10, 1.0, 2.0, 3.0, 6.0, 5, 0.02, 40.0, 160.0)

    def summary(variant: str, hz: float | None, p99_us: float = 600.0) -> bench.ServeSummary:
        return bench.ServeSummary(variant, hz, 1, 100.0, 2.5, 300.0, p99_us, 0.04, 1.0, 50.0, 0.5)

    def render(floor_p99_us: float, per_round: dict[str, list[float | None]] | None = None) -> str:
        return bench.render_table(
            b,
            p,
            summary("lunad", None),
            summary("floor", None, floor_p99_us),
            summary("lunad", 50.0),
            {"cpu": 1.0, "p99": 1.0, "hz_cpu": 1.0},
            per_round or {"cpu": [1.0], "hz_cpu": [1.0]},
            dict.fromkeys(
                ("bulk_fps", "cpu_ratio", "p99", "idle_cpu", "rss", "hz_cpu_ratio", "startup"),
                True,
            ),
            1,
            2.0,
        )

    text = render(600.0)
    for word in (
        "bulk decode",
        "pipeline",
        "CPU",
        "p50",
        "p99",
        "idle",
        "RSS",
        "start-up",
        "--publish-hz 50",
        "message (5 frames)",
        "40 / 160 us",
        "after 20 ms asleep",
        "0.040 / 0.040 %",
        "wake-ups a second, lunad / floor",
        "1.0 / 1.0",
        "at most 2: for the health message",
    ):
        assert word in text
    assert "MISSED" not in text
    assert "busy" not in text
    assert "round by round" not in text  # one round: nothing to spread
    rounds = render(600.0, {"cpu": [1.1, 0.9, 1.0], "hz_cpu": [0.38, None, 0.52]})
    assert rounds.count("round by round") == 2
    assert "1.10 0.90 1.00" in rounds and "0.38 n/a 0.52" in rounds
    busy = render(21_800.0)  # a loaded host: the floor itself misses 1 ms
    assert "floor's own p99 latency is 21.8 ms, so this host is busy" in busy


@pytest.mark.parametrize("argv", [["--help"]])
def test_floor_help_runs(argv: list[str]) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "lunad.daemon.tools.bench", *argv],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 0 and "--device" in out.stdout


def test_no_ratio_when_the_floor_measured_nothing() -> None:
    """A short window on a loaded machine can give the floor 0 CPU ticks: no crash."""
    assert bench.ratio(3.0, 1.5) == 2.0
    assert bench.ratio(3.0, 0.0) is None
    assert report._x(None).startswith("n/a")


def test_task_totals_count_every_threads_cpu_and_sleeps() -> None:
    """``_task_totals`` on this process: a thread's 30 sleeps and its busy loop show up."""
    import threading
    import time

    before = bench.task_totals(os.getpid())
    if before is None:
        pytest.skip("this kernel has no /proc/<pid>/task/*/schedstat")

    worked, leave = threading.Event(), threading.Event()

    def work() -> None:
        for _ in range(30):
            time.sleep(0.001)
        t_end = time.thread_time_ns() + 20_000_000
        while time.thread_time_ns() < t_end:
            pass
        worked.set()
        leave.wait()

    t = threading.Thread(target=work)
    t.start()
    worked.wait()  # this thread sleeps once or twice meanwhile, the worker 30 times
    during = bench.task_totals(os.getpid())
    leave.set()
    t.join()
    assert during is not None
    assert during[1] - before[1] >= 30
    assert during[0] - before[0] >= 20_000_000  # the worker's 20 ms of CPU


def test_idle_target_counts_wake_ups_beyond_the_health_message() -> None:
    """No polling: a wake-up a second for health passes, ten a second fail; without
    schedstat (NaN) the clock ticks must not move."""
    allowed = bench.idle_wakeups_allowed()
    assert allowed == 2.0  # the default health interval, 1 s: the loop and ZeroMQ's I/O thread

    def run(wakeups: float, cpu_pct: float = 0.04) -> Any:
        return argparse.Namespace(idle_wakeups_per_s=wakeups, idle_cpu_pct=cpu_pct)

    assert bench.idle_without_polling(run(1.0))
    assert not bench.idle_without_polling(run(10.0))
    assert bench.idle_without_polling(run(float("nan"), 0.0))
    assert not bench.idle_without_polling(run(float("nan"), 0.33))


def test_round_ratios_pair_the_rounds_in_order() -> None:
    def runs(*cpu: float) -> Any:
        return argparse.Namespace(runs=[argparse.Namespace(cpu_us_per_frame=c) for c in cpu])

    assert bench.round_ratios(runs(60.0, 90.0), runs(120.0, 150.0)) == [0.5, 0.6]
    assert bench.round_ratios(runs(60.0), runs(0.0)) == [None]


def test_cpu_split_gives_the_process_under_test_a_cpu_of_its_own() -> None:
    from lunad.daemon.tools.bench import cpu_split

    cpus = os.sched_getaffinity(0)
    split = cpu_split()
    if len(cpus) < 2:
        assert split is None
        return
    assert split is not None
    ours, theirs = split
    assert theirs == {max(cpus)} and ours | theirs == cpus and not ours & theirs


@pytest.mark.parametrize(
    ("argv", "complaint"),
    [
        (["--duration", "0"], "--duration must be > 0"),
        (["--rounds", "0"], "--rounds >= 1"),
        (["--publish-hz", "0"], "--publish-hz must be 1..250"),
        (["--publish-hz", "0.05"], "--publish-hz must be 1..250"),  # it slept 1000 s
        (["--publish-hz", "nan"], "--publish-hz must be 1..250"),
    ],
)
def test_bad_settings_exit_2_before_measuring(argv: list[str], complaint: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "lunad.daemon.cli", "bench", *argv],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and complaint in out.stderr
    assert "bulk decode" not in out.stderr + out.stdout  # nothing ran


def test_publish_hz_is_judged_against_lunad_at_full_rate() -> None:
    """Low-power mode filters every frame, so its target is half of lunad's own CPU at
    full rate (docs/performance.md), not a fraction of the floor loop, which filters none."""
    b = bench.BulkResult(10, 90, 3e6, 2e5, True)

    def summary(variant: str, hz: float | None, cpu_us: float) -> bench.ServeSummary:
        return bench.ServeSummary(variant, hz, 1, cpu_us, 2.5, 300.0, 600.0, 0.04, 1.0, 50.0, 0.5)

    def judged(low_cpu_us: float) -> tuple[float | None, bool]:
        serve = {
            "lunad": summary("lunad", None, 100.0),
            "floor": summary("floor", None, 70.0),
            "lunad_hz": summary("lunad", 50.0, low_cpu_us),
        }
        ratios, _, met = bench.verdict(b, serve)
        return ratios["hz_cpu"], met["hz_cpu_ratio"]

    assert judged(45.0) == (0.45, True)  # 0.64x the floor: the old target said missed
    assert judged(57.0) == (0.57, False)
