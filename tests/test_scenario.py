"""Scenario files, built-ins and the truth CSV helper (sim/scenario.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lunad.sim.physics import Truth
from lunad.sim.scenario import (
    TRUTH_CSV_HEADER,
    ScenarioError,
    builtin_scenarios,
    load_scenario,
    parse_scenario,
    truth_csv_row,
)

REQUIRED = {"static", "approach", "obstacles", "sun_ramp", "incidence_sweep", "beyond_range"}

EXAMPLE = """
description = "test"
rate_hz = 100
[initial]
distance_m = 4.0
lux = 100.0
[[keyframe]]
t_s = 2.0
distance_m = 2.0
[[keyframe]]
t_s = 3.0
lux = 500.0
interp = "hold"
[[step]]
t_s = 4.0
distance_m = 1.0
reflectivity = 0.3
"""


def test_builtins_are_shipped_and_load() -> None:
    names = set(builtin_scenarios())
    assert REQUIRED <= names
    for name in names:
        sc = load_scenario(name)
        assert sc.rate_hz == 250
        assert sc.duration_s > 0
        assert sc.description
        assert isinstance(sc.truth_at(0.0), Truth)


def test_obstacles_has_steps_and_sun_ramp_reaches_overexposure() -> None:
    assert len(load_scenario("obstacles").step_times_s) >= 4
    sun = load_scenario("sun_ramp")
    assert sun.truth_at(sun.duration_s).lux > 70_000


def test_linear_hold_and_step_semantics() -> None:
    sc = parse_scenario(EXAMPLE)
    assert sc.rate_hz == 100
    assert sc.duration_s == 4.0
    assert sc.truth_at(1.0).distance_m == pytest.approx(3.0)
    assert sc.truth_at(2.5).distance_m == pytest.approx(2.0)
    assert sc.truth_at(2.99).lux == 100.0
    assert sc.truth_at(3.0).lux == 500.0
    assert sc.truth_at(3.99).distance_m == pytest.approx(2.0)
    assert sc.truth_at(4.0).distance_m == 1.0
    assert sc.truth_at(4.0).reflectivity == 0.3
    assert sc.truth_at(99.0).distance_m == 1.0, "held after the end"
    assert sc.step_times_s == (), "a step at the very end is cut by the duration"


def test_step_times_and_frames() -> None:
    sc = parse_scenario(EXAMPLE.replace("rate_hz = 100", "rate_hz = 100\nduration_s = 6.0"))
    assert sc.step_times_s == (4.0,)
    assert sc.step_frames() == (400,)
    assert sc.n_frames == 600
    assert sc.with_duration(3.0).step_times_s == ()


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("rate_hz = 0", "rate_hz"),
        ("speed = 3", "speed"),
        ("[initial]\ndistance = 2.0", "distance"),
        ("[initial]\nangle_deg = 120.0", "angle_deg"),
        ("[[keyframe]]\nt_s = 1.0\ndistance_m = 'far'", "distance_m"),
        ("[[keyframe]]\ndistance_m = 1.0", "t_s"),
        ("[[keyframe]]\nt_s = 1.0\ndistance_m = 1.0\ninterp = 'cubic'", "interp"),
        ("[[keyframe]]\nt_s = 2.0\nlux = 1.0\n[[keyframe]]\nt_s = 1.0\nlux = 2.0", "time order"),
        ("[[step]]\nt_s = 1.0", "names no field"),
        ("duration_s = 1e308", r"duration_s must be above 0 and at most 86400 s"),
        ("[[keyframe]]\nt_s = 1e300\nlux = 3.0", r"t_s must be 0\.\.86400 s"),
        ("this is not toml", "TOML"),
        ("keyframe = [1, 2]", r"\[\[keyframe\]\] #1: must be a table"),
        ('step = ["t_s"]', r"\[\[step\]\] #1: must be a table"),
        ("rate_hz = 200", "rate_hz must be a frame rate the sensor runs at, 500/n Hz"),
        ("rate_hz = 100.5", "rate_hz must be a frame rate"),
        ("rate_hz = 1000", "rate_hz must be a frame rate"),
    ],
)
def test_bad_files_name_the_problem(text: str, field: str) -> None:
    with pytest.raises(ScenarioError, match=field):
        parse_scenario(text)


def test_load_from_path_and_unknown_name(tmp_path: Path) -> None:
    path = tmp_path / "hall.toml"
    path.write_text(EXAMPLE, encoding="utf-8")
    sc = load_scenario(path)
    assert sc.name == "hall"
    with pytest.raises(ScenarioError, match="static"):
        load_scenario("no_such_scenario")
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "missing.toml")


def test_truth_csv_row_matches_header() -> None:
    row = truth_csv_row(1.5, Truth(2.25, 0.5, 10.0, 300.0))
    cols = row.split(",")
    assert len(cols) == len(TRUTH_CSV_HEADER.split(","))
    assert [float(c) for c in cols] == [1.5, 2.25, 0.5, 10.0, 300.0]


@given(
    st.lists(
        st.tuples(st.floats(0.01, 5.0), st.floats(0.2, 8.0), st.booleans()),
        min_size=1,
        max_size=8,
    ),
    st.floats(0.0, 30.0),
)
def test_truth_stays_within_its_keyframes(
    points: list[tuple[float, float, bool]], t_query: float
) -> None:
    lines = ["[initial]", "distance_m = 1.0"]
    t = 0.0
    values = [1.0]
    for dt, value, hold in points:
        t += dt
        values.append(value)
        interp = "hold" if hold else "linear"
        lines += ["[[keyframe]]", f"t_s = {t!r}", f"distance_m = {value!r}", f'interp = "{interp}"']
    sc = parse_scenario("\n".join(lines))
    d = sc.truth_at(t_query).distance_m
    assert min(values) - 1e-9 <= d <= max(values) + 1e-9
    assert sc.truth_at(t + 1.0).distance_m == values[-1]


def test_a_file_that_is_not_utf8_is_a_scenario_error(tmp_path: Path) -> None:
    """A Latin-1 file used to escape load_scenario as UnicodeDecodeError (a traceback)."""
    path = tmp_path / "latin1.toml"
    path.write_bytes(b'description = "caf\xe9"\n')
    with pytest.raises(ScenarioError, match=r"not UTF-8 text .*byte 0xe9 at offset 18"):
        load_scenario(path)
