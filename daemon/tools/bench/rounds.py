"""Bench figure 3: ``lunad serve`` end to end, in rounds against the floor.

How this works. ``bench_serve`` runs ``lunad serve`` as a subprocess against the
virtual sensor (``PtyDevice`` in this process) at 250 Hz, and the floor (``floor.py``)
the same way, alternating with lunad round by round. For each run: CPU per frame from
``/proc/<pid>/stat`` (utime + stime of all threads; the kernel keeps that total exact
and reports it in clock ticks) over a steady window after a warm-up, divided by the
frames the sensor wrote in it; latency from the frame's last byte written (the
device's ``on_frame_sent`` hook) to the bench's SUB socket (``receiver.py``) receiving
the message with that ``seq``; idle CPU and wake-ups over a window with the sensor
paused (``task_totals``: nanoseconds, where the clock ticks above are 10 ms coarse);
peak RSS (``VmHWM``); and start-up, from spawn to the first message received.

The harness imports numpy, the simulator and pyzmq inside its functions, so that
``python -m lunad.daemon.tools.bench`` (the floor) loads only os, termios and zmq.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import Any

from lunad.daemon.tools.bench.measure import (
    cpu_split,
    cpu_ticks,
    median,
    percentile,
    task_totals,
    vm_hwm_mib,
)

SENSOR_HZ = 250  # the virtual sensor's frame rate in the serve runs, the TF-Luna's maximum


@dataclass
class ServeRun:
    """One run of a process (lunad or the floor) against the virtual sensor."""

    variant: str
    publish_hz: float | None
    frames: int
    received: int
    cpu_us_per_frame: float
    cpu_pct: float
    lat_p50_us: float
    lat_p99_us: float
    idle_cpu_pct: float
    idle_wakeups_per_s: float
    """Voluntary context switches a second, all threads, with the sensor silent: how
    often the process woke (NaN where the kernel has no schedstat)."""
    rss_mib: float
    startup_s: float
    exit_code: int | None
    log_tail: str = ""


@dataclass
class ServeSummary:
    """Medians over rounds of one variant."""

    variant: str
    publish_hz: float | None
    rounds: int
    cpu_us_per_frame: float
    cpu_pct: float
    lat_p50_us: float
    lat_p99_us: float
    idle_cpu_pct: float
    idle_wakeups_per_s: float
    rss_mib: float
    startup_s: float
    runs: list[ServeRun] = field(default_factory=list)


def serve_command(variant: str, device: str, endpoint: str, publish_hz: float | None) -> list[str]:
    """The command line of one run."""
    if variant == "floor":
        return [sys.executable, "-m", "lunad.daemon.tools.bench", "--device", device,
                "--publish", endpoint]  # fmt: skip
    cmd = [sys.executable, "-m", "lunad.daemon.cli", "serve", "--device", device,
           "--publish", endpoint, "--rate", str(SENSOR_HZ), "--name", "bench"]  # fmt: skip
    if publish_hz:
        cmd += ["--publish-hz", f"{publish_hz:g}"]
    return cmd


def run_serve_once(
    variant: str,
    workdir: str,
    publish_hz: float | None = None,
    warmup_s: float = 2.0,
    duration_s: float = 10.0,
    idle_settle_s: float = 1.5,
    idle_s: float = 3.0,
    pin: bool = False,
    hold: Callable[[], AbstractContextManager[object]] = nullcontext,
) -> ServeRun:
    """One run: a fresh virtual sensor at 250 Hz in this process, ``variant``
    ('lunad' or 'floor') as a subprocess, and ``receiver_main`` as another, timing
    every message. ``pin``: the process under test on the last CPU, this process and
    the receiver on the others (``cpu_split``). ``hold``: a context that holds a
    signal's interruption while the processes start (``lunad.daemon.cli.Interrupts.held``)."""
    import array
    import select
    import signal
    import subprocess
    import time
    from pathlib import Path

    from lunad.sim.physics import Truth
    from lunad.sim.pty_device import PtyDevice

    work = Path(workdir)
    tag = f"{variant}-{time.monotonic_ns()}"
    endpoint = f"ipc://{work}/{tag}.sock"
    sent: list[int] = []

    def on_sent(index: int, t_ns: int) -> None:
        if index == len(sent):
            sent.append(t_ns)

    split = cpu_split() if pin else None
    old_affinity = os.sched_getaffinity(0)
    if split is not None:
        os.sched_setaffinity(0, split[0])
    out_path = work / f"{tag}.recv"
    log_path = work / f"{tag}.log"
    receiver: subprocess.Popen[bytes] | None = None
    dev: PtyDevice | None = None
    proc = None
    try:
        with hold():  # a signal now waits for the finally below, which stops them
            receiver = subprocess.Popen(
                [sys.executable, "-m", "lunad.daemon.tools.bench", "receive", "--connect", endpoint,
                 "--out", str(out_path)],
                stdout=subprocess.PIPE,
            )  # fmt: skip
            dev = PtyDevice(
                truth=Truth(2.0, 0.8, 10.0, 100.0),
                rate_hz=SENSOR_HZ,
                link=work / f"{tag}.tty",
                output_enabled=False,
                on_frame_sent=on_sent,
            ).start()
        assert receiver.stdout is not None
        with open(log_path, "wb") as log:
            t_spawn = time.monotonic_ns()
            with hold():
                proc = subprocess.Popen(
                    serve_command(variant, dev.path, endpoint, publish_hz),
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env={**os.environ, "PYTHONUNBUFFERED": "1"},
                )
            if split is not None:
                os.sched_setaffinity(proc.pid, split[1])
            ready, _, _ = select.select([receiver.stdout], [], [], 15.0)
            line = receiver.stdout.readline() if ready else b""
            if not line:
                raise RuntimeError(f"{variant}: no message within 15 s; see {log_path}")
            startup_s = (int(line) - t_spawn) / 1e9
            if split is not None:  # threads started before the first call inherited {0}
                for tid in os.listdir(f"/proc/{proc.pid}/task"):
                    os.sched_setaffinity(int(tid), split[1])
            time.sleep(warmup_s)
            c0, t0, n0 = cpu_ticks(proc.pid), time.monotonic_ns(), len(sent)
            time.sleep(duration_s)
            c1, t1, n1 = cpu_ticks(proc.pid), time.monotonic_ns(), len(sent)
            hz = os.sysconf("SC_CLK_TCK")
            cpu_s = (c1 - c0) / hz
            frames = n1 - n0
            dev.pause(3600.0)
            time.sleep(idle_settle_s)
            i0, ic0, it0 = task_totals(proc.pid), cpu_ticks(proc.pid), time.monotonic_ns()
            time.sleep(idle_s)
            i1, ic1, it1 = task_totals(proc.pid), cpu_ticks(proc.pid), time.monotonic_ns()
            rss = vm_hwm_mib(proc.pid)
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(5.0)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if receiver is not None:
            receiver.terminate()
            try:
                receiver.wait(5.0)
            except subprocess.TimeoutExpired:
                receiver.kill()
                receiver.wait()
            if receiver.stdout is not None:
                receiver.stdout.close()
        try:
            if dev is not None:
                dev.close()  # raises DeviceError if the virtual sensor died: the run is void
        finally:
            os.sched_setaffinity(0, old_affinity)
    idle_window_s = (it1 - it0) / 1e9
    if i0 is not None and i1 is not None:
        idle_cpu_s, idle_wakeups = (i1[0] - i0[0]) / 1e9, float(i1[1] - i0[1])
    else:
        idle_cpu_s, idle_wakeups = (ic1 - ic0) / hz, float("nan")
    records = array.array("q")
    with open(out_path, "rb") as f:
        records.frombytes(f.read())
    recv_seq, recv_t = records[0::2], records[1::2]
    seen: set[int] = set()
    lat: list[int] = []
    received = 0
    for seq, t in zip(recv_seq, recv_t, strict=False):
        if seq in seen or seq >= len(sent):
            continue
        seen.add(seq)
        ts = sent[seq]
        if t0 <= ts < t1:
            received += 1
            lat.append(t - ts)
    return ServeRun(
        variant=variant,
        publish_hz=publish_hz,
        frames=frames,
        received=received,
        cpu_us_per_frame=cpu_s * 1e6 / frames if frames else float("nan"),
        cpu_pct=100.0 * cpu_s / ((t1 - t0) / 1e9),
        lat_p50_us=percentile(lat, 0.50) / 1e3,
        lat_p99_us=percentile(lat, 0.99) / 1e3,
        idle_cpu_pct=100.0 * idle_cpu_s / idle_window_s,
        idle_wakeups_per_s=idle_wakeups / idle_window_s,
        rss_mib=rss,
        startup_s=startup_s,
        exit_code=code,
        log_tail=log_path.read_text(errors="replace")[-2000:] if code else "",
    )


def summarise(runs: list[ServeRun]) -> ServeSummary:
    """Medians of each figure over ``runs`` (one variant and mode)."""
    r0 = runs[0]
    return ServeSummary(
        variant=r0.variant,
        publish_hz=r0.publish_hz,
        rounds=len(runs),
        cpu_us_per_frame=median([r.cpu_us_per_frame for r in runs]),
        cpu_pct=median([r.cpu_pct for r in runs]),
        lat_p50_us=median([r.lat_p50_us for r in runs]),
        lat_p99_us=median([r.lat_p99_us for r in runs]),
        idle_cpu_pct=median([r.idle_cpu_pct for r in runs]),
        idle_wakeups_per_s=median([r.idle_wakeups_per_s for r in runs]),
        rss_mib=median([r.rss_mib for r in runs]),
        startup_s=median([r.startup_s for r in runs]),
        runs=runs,
    )


def bench_serve(
    rounds: int = 3,
    duration_s: float = 10.0,
    warmup_s: float = 2.0,
    idle_s: float = 3.0,
    publish_hz: float = 50.0,
    progress: Any = None,
    pin: bool = False,
    hold: Callable[[], AbstractContextManager[object]] = nullcontext,
) -> dict[str, ServeSummary]:
    """Alternate lunad (every frame), the floor and lunad ``--publish-hz`` for ``rounds``.

    ``hold``: as in ``run_serve_once``. Returns summaries keyed 'lunad', 'floor' and
    'lunad_hz'.
    """
    import tempfile

    plan = [("lunad", None), ("floor", None), ("lunad_hz", publish_hz)]
    runs: dict[str, list[ServeRun]] = {key: [] for key, _ in plan}
    with tempfile.TemporaryDirectory(prefix="lunad-bench-") as work:
        for rnd in range(rounds):
            for key, hz in plan:
                variant = "floor" if key == "floor" else "lunad"
                run = run_serve_once(
                    variant,
                    work,
                    publish_hz=hz,
                    warmup_s=warmup_s,
                    duration_s=duration_s,
                    idle_s=idle_s,
                    pin=pin,
                    hold=hold,
                )
                runs[key].append(run)
                if progress is not None:
                    progress(f"round {rnd + 1}/{rounds} {key}: {run.cpu_us_per_frame:.1f} us/frame")
    return {key: summarise(rs) for key, rs in runs.items()}
