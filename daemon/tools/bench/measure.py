"""What the bench reads of a process from ``/proc``, and the statistics it reports.

CPU from ``/proc/<pid>/stat`` (utime + stime of all threads; the kernel keeps that total
exact and reports it in clock ticks); idle CPU and wake-ups from each thread's
``schedstat`` and ``status`` (nanoseconds, where the clock ticks are 10 ms coarse); peak
RSS (``VmHWM``). ``lunad soak`` samples the daemon's CPU with ``cpu_ticks`` too.
"""

from __future__ import annotations

import os


def cpu_ticks(pid: int) -> int:
    """utime + stime of every thread of ``pid``, in clock ticks."""
    with open(f"/proc/{pid}/stat", "rb") as f:
        stat = f.read()
    rest = stat[stat.rindex(b")") + 2 :].split()
    return int(rest[11]) + int(rest[12])  # fields 14 and 15 of proc(5)


def task_totals(pid: int) -> tuple[int, int] | None:
    """(nanoseconds on a CPU, voluntary context switches), summed over the threads of
    ``pid`` (``/proc/<pid>/task/*/schedstat`` and ``status``); None where the kernel
    has no schedstat (``CONFIG_SCHED_INFO``).

    For the idle window: a silent lunad wakes once a second for its health message,
    about 0.4 ms each, and ``/proc/<pid>/stat`` counts in 10 ms ticks, so a 3 s window
    read 0 or 1 tick (0.00 or 0.33 %) by where the ticks fell. A thread that ends
    while this reads it is left out.
    """
    if not os.path.exists("/proc/self/schedstat"):
        return None
    ns = switches = 0
    task = f"/proc/{pid}/task"
    for tid in os.listdir(task):
        try:
            with open(f"{task}/{tid}/schedstat", "rb") as f:
                ns += int(f.read().split()[0])
            with open(f"{task}/{tid}/status", "rb") as f:
                for line in f:
                    if line.startswith(b"voluntary_ctxt_switches:"):
                        switches += int(line.split()[1])
                        break
        except FileNotFoundError:
            continue
    return ns, switches


def vm_hwm_mib(pid: int) -> float:
    """Peak resident set size of ``pid`` (``VmHWM``), MiB."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def percentile(values: list[int], q: float) -> float:
    """The ``q`` quantile of ``values``, the nearest one by rank (NaN when empty)."""
    if not values:
        return float("nan")
    s = sorted(values)
    k = min(len(s) - 1, max(0, round(q * (len(s) - 1))))
    return float(s[k])


def cpu_split() -> tuple[set[int], set[int]] | None:
    """(CPUs for the bench and its receiver, the CPU for the process under test), or
    None with fewer than two CPUs to run on."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        return None
    return set(cpus[:-1]), {cpus[-1]}


def median(xs: list[float]) -> float:
    """The median of ``xs`` leaving NaNs out (NaN when nothing is left)."""
    import statistics

    xs = [x for x in xs if x == x]
    return statistics.median(xs) if xs else float("nan")
