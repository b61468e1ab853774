"""The daemon's resources as the soak samples them: RSS, open files, CPU ticks."""

from __future__ import annotations

import os
from dataclasses import dataclass


def vm_rss_kib(pid: int) -> float:
    """Resident set size of ``pid`` (VmRSS), KiB."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return float(line.split()[1])
    return float("nan")


def fd_count(pid: int) -> int:
    """Open file descriptors of ``pid``."""
    return len(os.listdir(f"/proc/{pid}/fd"))


@dataclass
class Sample:
    """One resource sample of the daemon."""

    t_s: float
    rss_kib: float
    fds: int
    cpu_ticks: int
    published: int


def fit_slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of ys over xs (0 with fewer than two points)."""
    n = len(xs)
    if n < 2:
        return 0.0
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    if sxx == 0:
        return 0.0
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
