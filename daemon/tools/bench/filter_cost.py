"""Bench figure 4: the filter's cost against another revision's filter.

The target is "``RangeFilter.step`` within 1.2x of the filter at revision REV". Both
filters are timed on the same frames, each in its own process, so that neither pays
for the other's imports, caches or garbage. ``filters/`` of REV is extracted
(``git archive``) into a temporary ``lunad/filters`` next to links to this checkout's
``daemon``, ``protocol`` and ``sim``, so the old filter runs with today's code around
it; today's ``filters/`` (the work tree, uncommitted edits included) is copied the same
way into a second directory, so both are imported through the same kind of path.

The frames: every run of ``SCENARIOS`` in both ``WORLDS`` (``lunad.sim.evaluate``,
seed 0), drawn once in this process and pickled for the children. A timing child runs a
fresh ``RangeFilter`` over each run's frames, ``passes`` times, and prints the best pass
in nanoseconds per frame; the rounds alternate old and new, and the figure is the median
of the rounds' new / old ratios: a round's pair ran seconds apart, so the host's load
moves both. The second figure, Python bytecodes per frame (``sys.settrace`` opcode
events inside ``step``), does not depend on the host at all; it depends on the
interpreter's version, which the report names.

Run as ``python -m lunad.daemon.tools.bench.filter_cost time|count FRAMES N``, this
module is the child. It imports only the standard library at the top, as every bench
module does.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

RATIO_MAX = 1.2
"""The target: today's ``step`` costs at most 1.2x the old one's, per frame."""
SCENARIOS = ("room_sweep", "sun_ramp", "static", "wall_drive", "obstacles")
WORLDS = ("paper", "shot")
PASSES = 7
"""Passes over all the frames in each timing child; the best is kept (the least
disturbed by the host)."""
ROUNDS = 5
TRACE_FRAMES = 1500
"""Frames of each run whose bytecodes are counted (tracing makes a step about 30x slower)."""
PACKAGES = ("daemon", "protocol", "sim")
"""This checkout's packages, linked next to each ``filters/`` under test."""
CHILD = "lunad.daemon.tools.bench.filter_cost"
"""This module's name, as the children run it (``python -m``)."""


class FilterCostError(Exception):
    """The comparison cannot be made; the message says why."""


class GitUnavailable(FilterCostError):
    """No git, or lunad is not imported from a git work tree."""


class UnknownRevision(FilterCostError):
    """The revision names no commit, or the commit has no ``filters/``."""


class ChildFailed(FilterCostError):
    """A timing or counting child exited with an error (an old filter that does not
    import with today's code, say)."""


@dataclass(frozen=True)
class FilterCost:
    """Today's ``RangeFilter.step`` against the one at ``revision``.

    Times are nanoseconds per frame, the best of ``passes`` passes over ``frames``
    frames, one figure per round; ratios are today's over the old one's.
    """

    revision: str
    """As given (``HEAD``, a tag, a short hash)."""
    commit: str
    """The full hash it names."""
    dirty: bool
    """Today's ``filters/`` has uncommitted changes (they are measured)."""
    runs: int
    frames: int
    passes: int
    old_ns: tuple[float, ...]
    new_ns: tuple[float, ...]
    ratios: tuple[float, ...]
    ratio: float
    """Median of ``ratios``: the figure the target is judged on."""
    traced_frames: int
    old_bytecodes: float
    """Python bytecodes executed per frame inside ``step``, over ``traced_frames``."""
    new_bytecodes: float
    python: str

    @property
    def bytecode_ratio(self) -> float:
        """Today's bytecodes a frame over the old filter's."""
        return self.new_bytecodes / self.old_bytecodes if self.old_bytecodes else float("nan")

    @property
    def met(self) -> bool:
        """The median ratio is within ``RATIO_MAX``."""
        return self.ratio <= RATIO_MAX


def checkout_root() -> Path:
    """The git work tree lunad is imported from: the parent of ``lunad.filters``'
    directory, which must be that work tree's ``filters/`` (an editable install).

    Raises:
        GitUnavailable: no git, or lunad is not imported from a git work tree.
    """
    import lunad.filters

    filters = Path(lunad.filters.__file__).resolve().parent
    root = filters.parent
    if not _is_work_tree(root):
        raise GitUnavailable(
            f"lunad.filters is imported from {filters}, which is not the filters/ of a git "
            "work tree: comparing against a revision needs lunad installed from a git "
            "checkout (pip install -e)"
        )
    return root


def resolve(root: Path, revision: str) -> str:
    """The full hash of the commit ``revision`` names in ``root``.

    Raises:
        UnknownRevision: it names no commit, or that commit has no ``filters/``.
    """
    if revision.startswith("-"):  # never an option to git
        raise UnknownRevision(f"unknown revision {revision!r}")
    found = _git(root, "rev-parse", "--verify", "--quiet", f"{revision}^{{commit}}")
    if found.returncode != 0:
        raise UnknownRevision(f"unknown revision {revision!r}: no such commit in {root}")
    commit = found.stdout.strip()
    tree = _git(root, "ls-tree", "--name-only", commit, "filters/range_filter.py")
    if not tree.stdout.strip():
        raise UnknownRevision(
            f"revision {revision!r} ({commit[:12]}) has no filters/range_filter.py"
        )
    return commit


def extract(root: Path, commit: str, dest: Path) -> Path:
    """``filters/`` of ``commit`` as ``dest/lunad/filters``, with links to ``root``'s
    other packages; returns ``dest`` (the PYTHONPATH of its children)."""
    pkg = _package_dir(root, dest)
    with subprocess.Popen(
        ["git", "-C", str(root), "archive", "--format=tar", commit, "filters"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    ) as git:
        assert git.stdout is not None
        tar = subprocess.run(
            ["tar", "-x", "-C", str(pkg)], stdin=git.stdout, capture_output=True, check=False
        )
        git.stdout.close()
        git_err = git.stderr.read() if git.stderr is not None else b""
    if git.returncode != 0 or tar.returncode != 0:
        raise FilterCostError(
            f"cannot extract filters/ of {commit[:12]}: "
            + (git_err or tar.stderr).decode(errors="replace").strip()
        )
    return dest


def copy_today(root: Path, dest: Path) -> Path:
    """``root``'s ``filters/`` as it is on disk now, laid out as ``extract`` does."""
    pkg = _package_dir(root, dest)
    shutil.copytree(root / "filters", pkg / "filters", ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def frame_set(
    max_frames: int | None = None,
) -> list[tuple[list[float | None], list[int], list[int]]]:
    """(raw_m, amp, t_ns) of every scenario run, the first ``max_frames`` frames of each
    when given: distances in metres (None where the sensor gave none), times in ns."""
    from lunad.sim.evaluate import simulate
    from lunad.sim.scenario import load_scenario

    runs = []
    for name in SCENARIOS:
        scenario = load_scenario(name)
        for world in WORLDS:
            run = simulate(scenario, world, 1.0, 0)
            end = max_frames if max_frames is not None else len(run.raw_m)
            runs.append((list(run.raw_m[:end]), list(run.amp[:end]), list(run.t_ns[:end])))
    return runs


def compare(
    revision: str,
    rounds: int = ROUNDS,
    passes: int = PASSES,
    max_frames: int | None = None,
    trace_frames: int = TRACE_FRAMES,
    progress: Callable[[str], object] | None = None,
    root: Path | None = None,
) -> FilterCost:
    """Time and count today's filter against ``revision``'s (module docstring).

    ``max_frames``: only the first frames of each run (a quick check). ``progress``:
    called with a line per child. ``root``: the top of a git work tree holding
    ``filters/``, ``daemon/``, ``protocol/`` and ``sim/``, instead of ``checkout_root()``.

    Raises:
        GitUnavailable, UnknownRevision: as ``checkout_root`` and ``resolve``.
        ChildFailed: a child exited with an error.
        FilterCostError: ``filters/`` could not be extracted.
    """
    import pickle
    import platform
    import tempfile

    from lunad.daemon.tools.bench.measure import median

    if rounds < 1 or passes < 1 or trace_frames < 1:
        raise ValueError("rounds, passes and trace_frames must be >= 1")
    if shutil.which("git") is None:
        raise GitUnavailable("git is not on PATH: it is needed to read another revision")
    if root is None:
        root = checkout_root()
    else:
        root = root.resolve()
        if not _is_work_tree(root):
            raise GitUnavailable(f"{root} is not the top of a git work tree")
    commit = resolve(root, revision)
    dirty = bool(_git(root, "status", "--porcelain", "--", "filters").stdout.strip())
    runs = frame_set(max_frames)
    frames = sum(len(r[0]) for r in runs)
    with tempfile.TemporaryDirectory(prefix="lunad-filter-cost-") as work:
        frames_path = Path(work) / "frames.pickle"
        frames_path.write_bytes(pickle.dumps(runs, protocol=pickle.HIGHEST_PROTOCOL))
        old = extract(root, commit, Path(work) / "old")
        new = copy_today(root, Path(work) / "new")

        def child(mode: str, where: Path, n: int) -> float:
            return _child(mode, where, frames_path, n)

        old_bc = child("count", old, trace_frames)
        new_bc = child("count", new, trace_frames)
        if progress is not None:
            progress(f"bytecodes a frame: old {old_bc:.1f}, today {new_bc:.1f}")
        old_ns: list[float] = []
        new_ns: list[float] = []
        for rnd in range(rounds):
            old_ns.append(child("time", old, passes))
            new_ns.append(child("time", new, passes))
            if progress is not None:
                progress(
                    f"round {rnd + 1}/{rounds}: old {old_ns[-1]:.0f} ns/frame, "
                    f"today {new_ns[-1]:.0f} ns/frame"
                )
    ratios = tuple(n / o for n, o in zip(new_ns, old_ns, strict=True))
    return FilterCost(
        revision=revision,
        commit=commit,
        dirty=dirty,
        runs=len(runs),
        frames=frames,
        passes=passes,
        old_ns=tuple(old_ns),
        new_ns=tuple(new_ns),
        ratios=ratios,
        ratio=median(list(ratios)),
        traced_frames=sum(min(len(r[0]), trace_frames) for r in runs),
        old_bytecodes=old_bc,
        new_bytecodes=new_bc,
        python=platform.python_version(),
    )


def format(cost: FilterCost) -> str:
    """The figures as a few lines of text, the verdict last."""
    today = "work tree, uncommitted changes included" if cost.dirty else "work tree"
    rounds = len(cost.ratios)
    lines = [
        f"lunad bench --filter-against {cost.revision}: RangeFilter.step, "
        f"{cost.commit[:12]} (old) against today ({today})",
        f"frames: {cost.frames} of {cost.runs} runs ({', '.join(SCENARIOS)}; "
        f"worlds {', '.join(WORLDS)}; seed 0), best of {cost.passes} passes, "
        f"{rounds} alternating round(s)",
        "",
        "round  old ns/frame  today ns/frame  today/old",
    ]
    for k, (o, n, r) in enumerate(zip(cost.old_ns, cost.new_ns, cost.ratios, strict=True)):
        lines.append(f"{k + 1:>5}  {o:>12.0f}  {n:>14.0f}  {r:>8.2f}x")
    verdict = "met" if cost.met else "MISSED"
    lines += [
        "",
        f"bytecodes a frame (Python {cost.python}, first {cost.traced_frames} frames): "
        f"old {cost.old_bytecodes:.1f}, today {cost.new_bytecodes:.1f} "
        f"({cost.bytecode_ratio:.2f}x)",
        f"today / old, median of rounds: {cost.ratio:.3f}x   <= {RATIO_MAX:g}x: {verdict}",
    ]
    return "\n".join(lines)


def _git(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["git", "-C", str(root), *args], capture_output=True, text=True, check=False
    )


def _is_work_tree(root: Path) -> bool:
    top = _git(root, "rev-parse", "--show-toplevel")
    return top.returncode == 0 and Path(top.stdout.strip()).resolve() == root


def _package_dir(root: Path, dest: Path) -> Path:
    pkg = dest / "lunad"
    pkg.mkdir(parents=True)
    for name in PACKAGES:
        (pkg / name).symlink_to(root / name, target_is_directory=True)
    return pkg


def _child(mode: str, where: Path, frames_path: Path, n: int) -> float:
    """Run this module as a child with ``where`` as its only PYTHONPATH; its figure."""
    env = {**os.environ, "PYTHONPATH": str(where), "PYTHONHASHSEED": "0"}
    env.pop("PYTHONSTARTUP", None)
    done = subprocess.run(
        [sys.executable, "-m", CHILD, mode, str(frames_path), str(n)],
        cwd=where,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise ChildFailed(
            f"the {mode} child for {where.name} exited {done.returncode}:\n{done.stderr.strip()}"
        )
    out = json.loads(done.stdout)
    expected = where / "lunad" / "filters"
    # The editable install's import hook must not have won over PYTHONPATH:
    if Path(out["file"]).resolve().parent != expected.resolve():
        raise ChildFailed(f"the {mode} child imported {out['file']}, not the one in {expected}")
    return float(out["value"])


def _load(frames_path: str) -> list[list[tuple[Any, int, int]]]:
    import pickle

    with open(frames_path, "rb") as f:
        runs = pickle.load(f)
    return [list(zip(raw, amp, t, strict=True)) for raw, amp, t in runs]


def _time(frames_path: str, passes: int) -> float:
    """Best of ``passes`` passes, nanoseconds per frame; a fresh filter per run."""
    import time

    from lunad.filters.range_filter import RangeFilter

    runs = _load(frames_path)
    n = sum(len(r) for r in runs)
    best = float("inf")
    for _ in range(passes):
        total = 0
        for frames in runs:
            step = RangeFilter().step
            t0 = time.perf_counter_ns()
            for z, amp, t in frames:
                step(z, amp, t)
            total += time.perf_counter_ns() - t0
        best = min(best, total / max(1, n))
    return best


def _count(frames_path: str, limit: int) -> float:
    """Bytecodes executed inside ``step`` per frame, over the first ``limit`` frames of
    each run (every function it calls included; C functions count as their call)."""
    from types import FrameType

    from lunad.filters.range_filter import RangeFilter

    runs = [frames[:limit] for frames in _load(frames_path)]
    count = 0

    def local(_frame: FrameType, event: str, _arg: Any) -> Any:
        nonlocal count
        if event == "opcode":
            count += 1
        return local

    def on_call(frame: FrameType, _event: str, _arg: Any) -> Any:
        frame.f_trace_lines = False
        frame.f_trace_opcodes = True
        return local

    for frames in runs:
        step = RangeFilter().step
        sys.settrace(on_call)
        try:
            for z, amp, t in frames:
                step(z, amp, t)
        finally:
            sys.settrace(None)
    n = sum(len(r) for r in runs)
    return count / max(1, n)


def _child_main(argv: list[str]) -> int:
    """``time|count FRAMES N``: print the figure and the filter's file as JSON."""
    from lunad.filters import range_filter

    mode, frames_path, n = argv[0], argv[1], int(argv[2])
    value = _time(frames_path, n) if mode == "time" else _count(frames_path, n)
    print(json.dumps({"value": value, "file": range_filter.__file__}))
    return 0


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1:]))
