"""Bad command-line input to demo and sim: one line naming the flag, the project's exit
code, and nothing started (no virtual sensor, no daemon)."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

from lunad.daemon.errors import EX_CONFIG


def test_demo_rejects_every_below_one(helpers: Any) -> None:
    """``--every 0`` used to reach watch()'s ``readings % every`` and crash mid-demo."""
    r = subprocess.run(
        [*helpers.lunad, "demo", "--every", "0", "--duration", "3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr == "lunad demo: --every must be at least 1\n"
    assert r.stdout == ""  # nothing started: no virtual sensor line, no daemon


def test_sim_truth_out_in_a_missing_directory(tmp_path: Path, helpers: Any) -> None:
    out = tmp_path / "nodir" / "truth.csv"
    link = tmp_path / "tfluna"
    r = subprocess.run(
        [*helpers.lunad, "sim", "--truth-out", str(out), "--duration", "1", "--link", str(link)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == EX_CONFIG, r.stderr
    assert r.stderr == f"lunad sim: --truth-out: cannot write {out}: No such file or directory\n"
    assert r.stdout == "" and not link.exists()  # the virtual sensor never started
