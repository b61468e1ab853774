"""``lunad bench --filter-against REV``: the filter's cost against another revision's.

End to end (git archive, the children, the report) against ``HEAD``, with one round,
one pass and a few hundred frames a run so that it takes a few seconds. No timing is
asserted: same code must give the same bytecode count, which the host cannot move.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any, TypedDict

import pytest

from lunad.daemon.cli import bench as cmd_bench
from lunad.daemon.errors import EX_CONFIG, EX_UNAVAILABLE
from lunad.daemon.tools.bench import filter_cost

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="needs git")


class _Quick(TypedDict):
    passes: int
    max_frames: int
    trace_frames: int


QUICK: _Quick = {"passes": 1, "max_frames": 300, "trace_frames": 100}
"""Small enough for a few seconds a comparison."""


def _quick_cli(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(filter_cost, "compare", functools.partial(filter_cost.compare, **QUICK))


def _run(*argv: str, capsys: Any) -> tuple[int, str, str]:
    parser = argparse.ArgumentParser(prog="lunad")
    cmd_bench.add_parser(parser.add_subparsers())
    args = parser.parse_args(["bench", *argv])
    code = args.func(args)
    out, err = capsys.readouterr()
    return code, out, err


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@example.invalid", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A git work tree laid out as the checkout: a first commit without filters/, a
    second with a copy of today's filters/ (so HEAD is the work tree, whatever anyone
    is editing in the real one), and links to today's daemon, protocol and sim."""
    root = filter_cost.checkout_root()
    work = tmp_path / "repo"
    work.mkdir()
    _git(work, "init", "-q")
    (work / "README").write_text("no filter yet\n")
    _git(work, "add", "README")
    _git(work, "commit", "-q", "-m", "before the filter")
    shutil.copytree(
        root / "filters", work / "filters", ignore=shutil.ignore_patterns("__pycache__")
    )
    _git(work, "add", "filters")
    _git(work, "commit", "-q", "-m", "the filter")
    for name in filter_cost.PACKAGES:
        (work / name).symlink_to(root / name, target_is_directory=True)
    return work


def test_head_of_the_checkout_through_the_cli(capsys: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    _quick_cli(monkeypatch)
    code, out, _ = _run("--filter-against", "HEAD", "--rounds", "1", capsys=capsys)
    assert code == 0
    head = _git(filter_cost.checkout_root(), "rev-parse", "HEAD")
    lines = out.splitlines()
    assert lines[0].startswith(f"lunad bench --filter-against HEAD: RangeFilter.step, {head[:12]}")
    assert lines[1].startswith("frames: 3000 of 10 runs (room_sweep, sun_ramp, static,")
    assert "best of 1 passes, 1 alternating round(s)" in lines[1]
    assert lines[3].split() == ["round", "old", "ns/frame", "today", "ns/frame", "today/old"]
    assert re.fullmatch(r"\s+1\s+\d+\s+\d+\s+\d+\.\d\dx", lines[4])
    counts = re.fullmatch(
        r"bytecodes a frame \(Python [\d.]+\w*, first 1000 frames\): "
        r"old (\d+\.\d), today (\d+\.\d) \(\d+\.\d\dx\)",
        lines[6],
    )
    assert counts is not None, lines[6]
    old, new = (float(x) for x in counts.groups())
    assert old > 0 and new > 0
    if "uncommitted changes" not in lines[0]:  # someone may be editing filters/ right now
        assert old == new
    assert re.fullmatch(
        r"today / old, median of rounds: \d+\.\d{3}x   <= 1\.2x: (met|MISSED)", lines[7]
    )
    assert len(lines) == 8


def test_json_has_every_figure(capsys: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    _quick_cli(monkeypatch)
    code, out, _ = _run("--filter-against", "HEAD", "--quick", "--format", "json", capsys=capsys)
    assert code == 0
    doc = json.loads(out)
    assert doc["revision"] == "HEAD" and len(doc["commit"]) == 40
    assert (doc["runs"], doc["frames"], doc["passes"], doc["traced_frames"]) == (10, 3000, 1, 1000)
    assert len(doc["old_ns"]) == len(doc["new_ns"]) == len(doc["ratios"]) == 1  # --quick
    assert min(doc["old_ns"] + doc["new_ns"]) > 0
    assert doc["ratio"] == doc["ratios"][0]
    assert doc["target_ratio_max"] == 1.2 and doc["met"] == (doc["ratio"] <= 1.2)
    assert doc["old_bytecodes"] > 0 and doc["new_bytecodes"] > 0


def test_same_code_costs_the_same_bytecodes(repo: Path) -> None:
    cost = filter_cost.compare("HEAD", rounds=1, root=repo, **QUICK)
    assert cost.commit == _git(repo, "rev-parse", "HEAD")
    assert not cost.dirty
    assert cost.old_bytecodes > 0
    assert cost.old_bytecodes == cost.new_bytecodes
    assert cost.bytecode_ratio == 1.0
    text = filter_cost.format(cost)
    assert "(old) against today (work tree)\n" in text
    assert "(1.00x)" in text


def test_unknown_revision_is_named(capsys: Any) -> None:
    with pytest.raises(filter_cost.UnknownRevision, match="'no-such-rev-4f2a'"):
        filter_cost.compare("no-such-rev-4f2a", rounds=1, **QUICK)
    code, out, err = _run("--filter-against", "no-such-rev-4f2a", capsys=capsys)
    assert code == EX_CONFIG
    assert out == ""
    assert err.startswith("lunad bench: --filter-against: unknown revision 'no-such-rev-4f2a'")


def test_revision_without_the_filter_is_named(repo: Path) -> None:
    with pytest.raises(filter_cost.UnknownRevision, match=r"'HEAD~1'.*has no filters/range_filter"):
        filter_cost.compare("HEAD~1", root=repo)


def test_not_a_work_tree(tmp_path: Path) -> None:
    with pytest.raises(filter_cost.GitUnavailable, match="not the top of a git work tree"):
        filter_cost.compare("HEAD", root=tmp_path)


def test_no_git_is_unavailable(capsys: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(filter_cost.shutil, "which", lambda _name: None)
    code, out, err = _run("--filter-against", "HEAD", capsys=capsys)
    assert code == EX_UNAVAILABLE and out == ""
    assert "git is not on PATH" in err


def test_serve_options_are_refused(capsys: Any) -> None:
    code, out, err = _run("--filter-against", "HEAD", "--pin", capsys=capsys)
    assert code == 2 and out == ""
    assert "--pin" in err
