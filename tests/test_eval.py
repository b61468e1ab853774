"""``lunad eval``: metrics, the independent oracle's verdicts, the sub-command."""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.cli import evaluate as cmd_eval
from lunad.filters import RangeFilter, Zone
from lunad.sim import evaluate as ev
from lunad.sim.scenario import load_scenario


def test_metrics_by_hand() -> None:
    truth = [1.0] * 10 + [2.0] * 10
    est: list[float | None] = [1.0] * 10 + [1.0, 1.0, 1.0, 1.0, 2.01] + [2.0] * 4 + [None]
    sig: list[float | None] = [0.01] * 19 + [None]
    away = ev._away(20, [10], 5)
    res = ev._metrics("x", [True] * 20, est, sig, truth, [10], away)
    assert res.coverage == pytest.approx(19 / 20)
    assert res.step_lag_frames == 4
    # frames 10-12 are excused; frame 13 is 1 m off
    assert res.bad_frames == 1
    assert res.rmse_m == pytest.approx(0.0)
    assert res.two_sigma == pytest.approx(15 / 19)
    assert res.five_sigma == pytest.approx(4 / 19)


def test_shared_rmse_judges_only_frames_both_published() -> None:
    truth = [0.0] * 4
    a: list[float | None] = [0.1, 0.1, None, None]
    b: list[float | None] = [0.2, 0.2, 5.0, 0.0]
    assert ev._shared_rmse(a, b, truth, [True] * 4) == pytest.approx(0.5)


def test_the_oracle_beats_a_filter_it_shares_nothing_with() -> None:
    """The oracle is told the true sigma and tuned in hindsight: on a still target it is
    better than the median and than raw readings, whatever the world."""
    sc = load_scenario("static").with_duration(4.0)
    for world in ev.WORLDS:
        res = ev.evaluate(sc, world, 1.0, 3)
        oracle = res.get("oracle").rmse_m
        median = res.get("median5").rmse_m
        raw = res.get("raw").rmse_m
        assert oracle is not None and median is not None and raw is not None
        assert oracle < median < raw


def test_the_targets_can_fail() -> None:
    res = ev.evaluate(load_scenario("static").with_duration(3.0))
    assert ev.check_targets(res, ev.Targets(oracle_ratio=0.5))
    lagging = ev.ScenarioResult(
        "x",
        "paper",
        0,
        1,
        250.0,
        1,
        1.0,
        2.0,
        1.5,
        tuple(ev.MethodResult(m, 0.01, 1.0, 0.5, 0.02, 3, 9, 0.5, 0.0) for m in ev.METHODS),
        mixed_frames=4,
        mixed_ok=1,
    )
    text = " ".join(ev.check_targets(lagging))
    words_of_each_target = (
        "oracle",
        "median5",
        "2-sigma",
        "5 sigma",
        "0.3 m off",
        "step lag",
        "lux",
        "1 of 4 readings of two surfaces",
    )
    for words in words_of_each_target:
        assert words in text
    assert "the oracle's, read in hindsight: 50.0%" in text
    assert "2-sigma coverage 50.0% outside [90%, 99%] (the oracle's own: 50.0%)" in text
    honest_oracle = dataclasses.replace(
        lagging,
        methods=tuple(
            dataclasses.replace(m, two_sigma=0.95) if m.method == "oracle" else m
            for m in lagging.methods
        ),
    )
    assert "oracle's own" not in " ".join(ev.check_targets(honest_oracle))


def test_the_oracles_lux_reads_a_steady_light_and_says_when_the_readings_cannot() -> None:
    """The lux read in hindsight (all readings since the light changed, the motion and
    the spikes known) is within tolerance on every judged frame of a still target under
    steady light: it can say yes. On cloud_flicker in the shot world, whose noise law
    lunad's constants do not describe, it is within tolerance on about 71 % of its
    frames: no filter with those constants can meet the lux target there, and
    check_targets says so beside lunad's miss."""
    steady = ev.evaluate(load_scenario("static"), "paper", 1.0, 0).get("oracle")
    assert steady.lux_ok == pytest.approx(1.0)
    res = ev.evaluate(load_scenario("cloud_flicker"), "shot", 1.0, 0)
    hind = res.get("oracle").lux_ok
    assert hind is not None and 0.5 < hind < 0.9
    lux_misses = [m for m in ev.check_targets(res) if "lux" in m]
    assert lux_misses and "read in hindsight" in lux_misses[0]


@pytest.mark.parametrize("world", ev.WORLDS)
def test_readings_at_an_edge_mix_both_surfaces_and_are_never_published_ok(world: str) -> None:
    """The two readings after each distance step see both surfaces (sim/edges.py): their
    distance lies between the two, the truth stays the new surface, and lunad publishes
    none of them ``ok``."""
    scenario = load_scenario("alternating").with_duration(3.0)
    run = ev.simulate(scenario, world, 1.0, 0)
    steps = scenario.step_frames()
    mixed = [i for i, m in enumerate(run.mixed) if m]
    assert mixed and set(mixed) <= {f + k for f in steps for k in range(2)}
    for i in mixed:
        step = max(f for f in steps if f <= i)
        old, new = run.truth[step - 1].distance_m, run.truth[i].distance_m
        z = run.raw_m[i]
        assert z is not None
        assert min(old, new) + 0.05 < z < max(old, new) - 0.05  # of neither surface
    res = ev.evaluate_run(scenario, run, world)
    assert res.mixed_frames == len(mixed)
    assert res.mixed_ok == 0


def test_a_mixed_truth_weighs_each_surface_by_the_light_it_returns() -> None:
    from lunad.sim.edges import mixed_truth
    from lunad.sim.physics import RealisticSensor, Truth

    sensor = RealisticSensor()
    near, far = Truth(1.0, 0.9, 0.0, 300.0), Truth(5.0, 0.9, 0.0, 300.0)
    half = mixed_truth(sensor.amp_of, near, far, 0.5)
    # the near surface returns 25x the light of the far one: the mix sits near it
    assert half.distance_m == pytest.approx((25 * 1.0 + 5.0) / 26)
    assert sensor.amp_of(half) == pytest.approx(0.5 * (sensor.amp_of(near) + sensor.amp_of(far)))
    assert half.lux == far.lux
    assert mixed_truth(sensor.amp_of, near, far, 0.0).distance_m == pytest.approx(5.0)


def test_lunad_follows_a_step_and_keeps_its_sigma_honest_on_still_scenes() -> None:
    """What lunad meets today on the obstacle steps in both worlds (docs/filter.md has
    the full table, and the targets it still misses)."""
    for world in ev.WORLDS:
        res = ev.evaluate(load_scenario("obstacles"), world, 1.0, 1)
        mine = res.get("lunad")
        assert res.vs_oracle is not None and res.vs_oracle <= 1.3
        assert res.vs_median5 is not None and res.vs_median5 < 1.0
        assert mine.step_lag_frames is not None and mine.step_lag_frames <= 3
        assert mine.bad_frames == 0
        assert mine.two_sigma is not None and mine.two_sigma >= 0.90
        assert mine.five_sigma is not None and mine.five_sigma < 0.005


@pytest.mark.parametrize("seed", [1592, 1596, 1619, 1625])
def test_a_track_that_coasted_past_a_far_corner_publishes_no_figure_off_its_reading(
    seed: int,
) -> None:
    """room_sweep in the paper world: past a far corner the beam reads nothing for a
    few frames, or every other reading is an outlier, while the range turns at 6-13
    m/s; the track goes on the old way, and the first reading back is accepted 20-30
    cm from it, under a sigma of 4-20 cm for an error of 0.3-0.5 m. Such a frame was
    published ``degraded``: one bad output at each of these seeds. In the unreliable
    zone, an estimate over 20 cm from the reading that follows frames the track did
    not take is now a dropout (``outlier``), as an outlier frame's is; the steps are
    followed as fast."""
    scenario = load_scenario("room_sweep")
    run = ev.simulate(scenario, "paper", 1.0, seed)
    flt = RangeFilter()
    far = 2.0 * flt.config.sigma_unreliable_m
    before = None
    for z, amp, t in zip(run.raw_m, run.amp, run.t_ns, strict=True):
        e = flt.step(z, amp, t)
        back = before is not None and before.range_m is None  # after a dropout
        if back and e.range_m is not None and z is not None and e.zone is Zone.UNRELIABLE:
            assert abs(e.range_m - z) <= far
        before = e
    mine = ev.evaluate_run(scenario, run, "paper").get("lunad")
    assert mine.bad_frames == 0
    assert mine.step_lag_frames is not None and mine.step_lag_frames <= 3


@pytest.mark.parametrize("seed", [1905, 1909, 1911, 1918])
def test_a_jump_of_light_does_not_restart_a_still_track_on_two_noisy_readings(
    seed: int,
) -> None:
    """cloud_flicker in the shot world: 5.9 s in, the light jumps and the noise of a
    grey card at 3 m rises from 6.6 to 23 cm within a frame, while the reading variance
    is still the old noise's. Two of the first readings beyond the gate, on one side,
    restarted the track 0.3-0.4 m off and it chased the noise (1-5 bad outputs at each
    of these seeds). Their amp is the card's own: a still track now waits for a third
    agreeing reading of the same amp (SAME_AMP_SHARE)."""
    scenario = load_scenario("cloud_flicker")
    run = ev.simulate(scenario, "shot", 1.0, seed)
    assert ev.evaluate_run(scenario, run, "shot").get("lunad").bad_frames == 0


def test_a_target_already_moving_when_lunad_starts_is_followed() -> None:
    """The first track's run at the noise's boot's end takes a nearly still target
    (BOOT_SPEED_SIGMA_M_S: a dozen readings under heavy noise cannot tell a speed). A
    robot already driving at a sunlit wall at 1.5 m/s when lunad starts
    (tests/data/scenes/drive_moving.toml, 17-24 cm of noise at 6 m) is still followed:
    the manoeuvre test finds the motion. Seeds 1900-1905, both worlds: lunad's RMSE is
    1.05x the oracle's (median of 12 runs; 0.88-1.28x), below median5's on every run,
    and no estimate is 0.3 m off; with a prior of 0.1 m/s the median was 1.73x."""
    scenario = load_scenario(Path(__file__).parent / "data" / "scenes" / "drive_moving.toml")
    ratios: list[float] = []
    for world in ev.WORLDS:
        for seed in range(1900, 1906):
            res = ev.evaluate(scenario, world, 1.0, seed)
            assert res.vs_oracle is not None and res.vs_median5 is not None
            assert res.vs_median5 < 1.0
            assert res.get("lunad").bad_frames == 0
            ratios.append(res.vs_oracle)
    ratios.sort()
    assert (ratios[5] + ratios[6]) / 2 <= 1.2


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="lunad")
    cmd_eval.add_parser(parser.add_subparsers())
    args = parser.parse_args(["eval", *argv])
    return args.func(args)


def test_cli_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_cli(["--scenario", "static", "--duration", "2", "--format", "json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [s["world"] for s in doc["scenarios"]] == list(ev.WORLDS)
    assert [m["method"] for m in doc["scenarios"][0]["methods"]] == list(ev.METHODS)
    assert "missed" in doc["targets"]


def test_cli_seeds_and_world(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--scenario", "static", "--duration", "1", "--format", "json", "--world", "shot"]
    assert run_cli([*argv, "--seed", "1", "--seed", "2"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [(s["world"], s["seed"]) for s in doc["scenarios"]] == [("shot", 1), ("shot", 2)]


def test_cli_table_with_a_user_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "door.toml"
    path.write_text(
        "[initial]\ndistance_m = 1.5\n[[step]]\nt_s = 1.0\ndistance_m = 3.0\n"
        "[[keyframe]]\nt_s = 2.0\nlux = 0.0\n",
        encoding="utf-8",
    )
    assert run_cli(["--scenario", str(path), "--seed", "2"]) == 0
    out = capsys.readouterr().out
    assert "== door / paper" in out and "oracle" in out and "us per frame" in out


def test_cli_bad_scenario_is_a_config_error() -> None:
    assert run_cli(["--scenario", "nowhere"]) == cmd_eval.EXIT_CONFIG


def test_cli_bounds_a_run_by_the_memory_it_holds(tmp_path: Path) -> None:
    """A run holds every frame in memory: ``--duration 1e308`` crashed on an infinite
    frame count and an hour-long scenario grew past 500 MB; both are refused up front."""
    for duration in ("1e308", "601"):
        with pytest.raises(SystemExit) as usage:
            run_cli(["--scenario", "static", "--duration", duration])
        assert usage.value.code == 2
    long = tmp_path / "long.toml"
    long.write_text("duration_s = 3600.0\n")
    assert run_cli(["--scenario", str(long)]) == cmd_eval.EXIT_CONFIG


def test_cli_rejects_bad_numbers() -> None:
    with pytest.raises(SystemExit):
        run_cli(["--noise-scale", "-1"])
    with pytest.raises(SystemExit):
        run_cli(["--seed", "-1"])


def test_cli_check_exit_code(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ev, "check_targets", lambda res, tg: ["missed"])
    assert run_cli(["--scenario", "static", "--duration", "1", "--check"]) == 1
    assert run_cli(["--scenario", "static", "--duration", "1"]) == 0


def test_cli_true_noise_is_said_and_tells_lunad_the_noise(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``--true-noise`` is a diagnostic, and the report says so; told the noise, lunad
    loses less to the oracle where the light jumps (cloud_flicker in the paper world,
    seed 7: 2.48x the oracle learning the noise, 1.19x told it)."""
    argv = ["--scenario", "static", "--duration", "1", "--world", "paper"]
    assert run_cli([*argv, "--true-noise", "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["true_noise"] is True
    assert run_cli([*argv, "--true-noise"]) == 0
    assert "told each reading's true sigma" in capsys.readouterr().out
    assert run_cli(argv) == 0
    assert "true sigma" not in capsys.readouterr().out
    assert run_cli([*argv, "--true-noise", "--check"]) == cmd_eval.EXIT_USAGE
    scenario = load_scenario("cloud_flicker")
    run = ev.simulate(scenario, "paper", 1.0, 7)
    learnt = ev.evaluate_run(scenario, run, "paper", 7).vs_oracle
    told = ev.evaluate_run(scenario, run, "paper", 7, true_noise=True).vs_oracle
    assert learnt is not None and told is not None
    assert told < learnt - 0.5


def test_cli_seed_ranges(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--scenario", "static", "--duration", "0.5", "--format", "json", "--world", "paper"]
    assert run_cli([*argv, "--seed", "3-5", "--seed", "1", "--seed", "4"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [s["seed"] for s in doc["scenarios"]] == [3, 4, 5, 1]
    for bad in ("5-3", "-1", "a-b", "1-", "0-10000"):
        with pytest.raises(SystemExit):
            run_cli(["--seed", bad])


def test_worker_processes_give_the_same_results() -> None:
    """``--jobs``: each run is drawn from its own seed, so real worker processes give
    the results one process does, in the same order."""
    scenarios = [load_scenario(n).with_duration(1.0) for n in ("static", "obstacles")]
    alone = ev.evaluate_all(scenarios, ev.WORLDS, (0, 1))
    shared = ev.evaluate_all(scenarios, ev.WORLDS, (0, 1), jobs=2)
    assert shared.scenarios == alone.scenarios
    assert [(r.scenario, r.world, r.seed) for r in shared.scenarios][:3] == [
        ("static", "paper", 0),
        ("static", "paper", 1),
        ("static", "shot", 0),
    ]


def test_cli_judges_other_filter_settings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """``--set`` and ``--config`` judge lunad's filter with other [filter] settings, and
    the report says which; a wrong name or value is a config error that names it."""
    argv = ["--scenario", "static", "--duration", "2", "--world", "paper", "--format", "json"]
    assert run_cli(argv) == 0
    default = json.loads(capsys.readouterr().out)
    assert default["filter_settings"] == []
    assert run_cli([*argv, "--set", "sigma_floor_m=0.05", "--set", "step_confirm=3"]) == 0
    wide = json.loads(capsys.readouterr().out)
    assert wide["filter_settings"] == [["step_confirm", 3], ["sigma_floor_m", 0.05]]
    lunad = next(m for m in wide["scenarios"][0]["methods"] if m["method"] == "lunad")
    assert lunad["two_sigma"] == 1.0  # a 5 cm floor under a sigma of millimetres
    path = tmp_path / "lunad.toml"
    path.write_text("[filter]\nsigma_floor_m = 0.05\n", encoding="utf-8")
    assert run_cli([*argv, "--config", str(path), "--set", "step_confirm=3"]) == 0
    from_file = json.loads(capsys.readouterr().out)
    timed = "step_cost_us"  # the machine's, run to run
    assert {k: v for k, v in from_file.items() if k != timed} == {
        k: v for k, v in wide.items() if k != timed
    }
    assert run_cli([*argv[:-2], "--set", "gate_sigmas=4.5"]) == 0
    assert "lunad's filter: gate_sigmas=4.5" in capsys.readouterr().out
    assert run_cli([*argv[:-2], "--set", "filter.gate_sigmas=4.5"]) == 0
    assert "lunad's filter: gate_sigmas=4.5" in capsys.readouterr().out
    assert run_cli(["--set", "nope=1"]) == cmd_eval.EXIT_CONFIG
    assert "filter.nope: unknown key" in caplog.text
    assert run_cli(["--set", "gate_sigmas=-1"]) == cmd_eval.EXIT_CONFIG
    assert "gate_sigmas must be positive" in caplog.text
    for bad in ("gate_sigmas", "=4", "gate_sigmas=abc"):
        with pytest.raises(SystemExit):
            run_cli(["--set", bad])


def test_the_summary_tallies_every_miss(capsys: pytest.CaptureFixture[str]) -> None:
    """``--summary``: the targets missed by kind and by scenario and world, each one
    counted once, and the runs where the oracle misses too."""
    scenarios = [load_scenario(n).with_duration(3.0) for n in ("cloud_flicker", "static")]
    report = ev.evaluate_all(scenarios, ev.WORLDS, (0, 1))
    misses = [m for r in report.scenarios for m in ev.target_misses(r)]
    assert misses, "cloud_flicker's first 3 s miss lux targets"
    assert [m.text for m in misses] == [t for r in report.scenarios for t in ev.check_targets(r)]
    text = ev.format_summary(report)
    assert f"targets missed: {len(misses)}," in text
    assert f"({sum(m.oracle_too for m in misses)} of them where the oracle misses too)" in text
    tally, _, table = text.partition("targets missed by scenario and world")
    by_kind = [line for line in tally.splitlines() if line.startswith("  ")]
    assert sum(int(line[29:36]) for line in by_kind) == len(misses)
    head, *rows = [line.split() for line in table.splitlines()[1:]]
    assert [(row[0], row[1]) for row in rows] == [
        (name, world) for name in ("cloud_flicker", "static") for world in ev.WORLDS
    ]
    assert all(row[2] == "2" for row in rows), "two seeds a scenario and world"
    column = {name: i for i, name in enumerate(head)}
    assert sum(int(row[column["missed"]]) for row in rows) == len(misses)
    assert sum(int(row[column["oracle_too"]]) for row in rows) == sum(m.oracle_too for m in misses)
    for kind in {m.kind for m in misses}:
        counted = sum(int(row[column[kind]]) for row in rows)
        assert counted == sum(m.kind == kind for m in misses), kind
    for row in rows:
        kinds = sum(int(row[column[k]]) for k in ev.MISS_KINDS if k in column)
        assert kinds == int(row[column["missed"]])
    argv = ["--scenario", "static", "--duration", "1", "--summary"]
    assert run_cli(argv) == 0
    assert "2 runs (1 scenarios x 2 worlds x 1 seeds)" in capsys.readouterr().out
    assert run_cli([*argv, "--format", "json"]) == cmd_eval.EXIT_USAGE


def test_a_sigterm_stops_eval_and_its_workers(helpers: Any) -> None:
    """SIGTERM ended ``lunad eval --jobs 2`` by its default action and left its two
    workers waiting for ever, holding its stdout: a pipe reading it never ended."""
    p = subprocess.Popen(
        [*helpers.lunad, "eval", "--seed", "0-40", "--jobs", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        kids: list[int] = []
        while len(kids) < 2 and time.monotonic() < deadline:
            assert p.poll() is None
            kids = [
                int(k)
                for task in Path(f"/proc/{p.pid}/task").iterdir()
                for k in (task / "children").read_text().split()
            ]
            time.sleep(0.05)
        assert len(kids) >= 2, "eval started no workers within 60 s"
        time.sleep(0.5)  # the workers are judging runs
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)  # ends: nothing holds its pipes
    finally:
        p.kill()
    assert p.returncode == 143, err
    assert "lunad eval: stopped by SIGTERM" in err
    assert not any(Path(f"/proc/{k}").exists() for k in kids)
