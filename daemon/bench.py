"""``lunad bench``: the floor reference loop and the measurement harness.

How this works. Three kinds of figure, each from a function here that
``lunad.daemon.cmd_bench`` calls:

1. ``bench_bulk``: numpy decode of a recorded stream (``lunad.protocol.bulk``), in
   frames per second, checked frame for frame against the streaming parser.
2. ``bench_pipeline``: parse + filter + encode of one frame at a time, pure Python,
   no I/O, in microseconds per frame (and each stage alone); and ``bench_message``, the
   same for one ``--publish-hz`` message, with warm caches and after a sleep.
3. ``bench_serve``: ``lunad serve`` as a subprocess against the virtual sensor
   (``PtyDevice`` in this process) at 250 Hz, and the *floor*: the loop in
   ``floor_main`` below, run the same way, alternating with lunad round by round.
   For each run: CPU per frame from ``/proc/<pid>/stat`` (utime + stime of all
   threads; the kernel keeps that total exact and reports it in clock ticks) over a
   steady window after a warm-up, divided by the frames the sensor wrote in it;
   latency from the frame's last byte written (the device's ``on_frame_sent`` hook)
   to the bench's SUB socket receiving the message with that ``seq``; idle CPU and
   wake-ups over a window with the sensor paused (``_task_totals``: nanoseconds, where
   the clock ticks above are 10 ms coarse); peak RSS (``VmHWM``); and start-up, from
   spawn to the first message received.

The floor is what any Python program must spend to do the job at all: blocking
``os.read`` on the tty, a checksum per frame and a small JSON message per frame on a
ZeroMQ PUB socket, no filter, no health, no reconnects. ``lunad / floor`` is the
overhead of everything else we do. It imports nothing of lunad (not even
``lunad.protocol``, whose package import pulls in pydantic), so its RSS and start-up
are the floor's too.

The harness imports numpy, the simulator and pyzmq inside its functions, so
``python -m lunad.daemon.bench`` (the floor) loads only os, termios and zmq.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import Any

FLOOR_TOPIC = b"range/floor"
IDENT = b'"sensor":"tfluna","run":"0000000000000000"'
"""``range_ident`` of the messages the pure-work benchmarks encode (a constant: it is
made once per daemon run)."""
SENSOR_HZ = 250  # the virtual sensor's frame rate in the serve runs, the TF-Luna's maximum
# set_output_enabled(True) from lunad.protocol.commands: 5A Len=05 ID=07 payload 01, CS.
# Spelled out so that the floor does not import lunad.protocol (and with it pydantic);
# tests/test_bench.py checks it against the encoder.
OUTPUT_ON = bytes((0x5A, 0x05, 0x07, 0x01, (0x5A + 0x05 + 0x07 + 0x01) & 0xFF))


# -- the floor reference loop ------------------------------------------------------


def _exit_on(*signums: int) -> None:
    """Make these signals raise SystemExit(0) in the main thread (clean exit, finally runs)."""
    import signal

    def stop(_signum: int, _frame: Any) -> None:
        raise SystemExit(0)

    for signum in signums:
        signal.signal(signum, stop)


def floor_main(argv: list[str] | None = None) -> int:
    """The floor: read the tty with blocking reads, check checksums, publish each frame.

    Run as ``python -m lunad.daemon.bench --device PATH --publish ENDPOINT``; stops on
    SIGTERM or SIGINT. Each message is ``range/floor`` and
    ``{"seq":N,"dist":D,"amp":A,"temp_raw":T}``.
    """
    import argparse
    import signal
    import termios
    import tty

    import zmq

    p = argparse.ArgumentParser(prog="python -m lunad.daemon.bench", description="floor loop")
    p.add_argument("--device", required=True)
    p.add_argument("--publish", required=True)
    args = p.parse_args(argv)

    _exit_on(signal.SIGTERM, signal.SIGINT)

    try:  # the device first: a missing one leaves no bound socket file behind
        fd = os.open(args.device, os.O_RDWR | os.O_NOCTTY)
    except OSError as exc:
        print(f"floor: {exc}", file=sys.stderr)
        return 1
    try:
        tty.setraw(fd)
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        os.write(fd, OUTPUT_ON)
    except (OSError, termios.error) as exc:
        os.close(fd)
        print(f"floor: {args.device} is not a serial port: {exc}", file=sys.stderr)
        return 1
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.bind(args.publish)

    send = sock.send_multipart
    noblock = zmq.NOBLOCK
    topic = FLOOR_TOPIC
    buf = b""
    seq = 0
    try:
        while True:
            buf += os.read(fd, 4096)
            i = buf.find(b"YY")
            while i >= 0 and len(buf) - i >= 9:
                if sum(buf[i : i + 8]) & 0xFF == buf[i + 8]:
                    msg = b'{"seq":%d,"dist":%d,"amp":%d,"temp_raw":%d}' % (
                        seq,
                        buf[i + 2] | buf[i + 3] << 8,
                        buf[i + 4] | buf[i + 5] << 8,
                        buf[i + 6] | buf[i + 7] << 8,
                    )
                    seq += 1
                    try:
                        send((topic, msg), noblock)
                    except zmq.Again:
                        pass
                    i = buf.find(b"YY", i + 9)
                else:
                    i = buf.find(b"YY", i + 1)
            buf = buf[i:] if i >= 0 else buf[-1:]
    except SystemExit:
        return 0
    finally:
        os.close(fd)
        sock.close()
        ctx.term()


def receiver_main(argv: list[str] | None = None) -> int:
    """The bench's subscriber, in a process of its own so that its receive times do
    not wait for the GIL of the process that plays the sensor.

    Run as ``python -m lunad.daemon.bench receive --connect ENDPOINT --out FILE``.
    Prints the monotonic time of the first message on stdout; on SIGTERM or SIGINT writes
    every message's ``seq`` and receive time (``time.monotonic_ns()``, the same
    clock the sensor's send times use) to FILE as int64 pairs, and exits 0.
    """
    import argparse
    import array
    import signal
    import time

    import zmq

    p = argparse.ArgumentParser(prog="python -m lunad.daemon.bench receive")
    p.add_argument("--connect", required=True)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)

    _exit_on(signal.SIGTERM, signal.SIGINT)  # SIGINT: Ctrl-C reaches the whole group
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.RECONNECT_IVL, 5)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"range/")
    sub.connect(args.connect)
    records = array.array("q")
    recv = sub.recv_multipart
    mono = time.monotonic_ns
    try:
        parts = recv()
        t = mono()
        records.extend((_seq_of(parts[1]), t))
        print(t, flush=True)
        while True:
            parts = recv()
            t = mono()
            records.extend((_seq_of(parts[1]), t))
    except SystemExit:
        pass
    finally:
        with open(args.out, "wb") as f:
            records.tofile(f)
        sub.close()
        ctx.term()
    return 0


# -- results ---------------------------------------------------------------------


@dataclass
class BulkResult:
    """Bulk decode of a synthetic recording (frames with garbage between some)."""

    frames: int
    stream_bytes: int
    bulk_fps: float
    streaming_fps: float
    same_as_streaming: bool


@dataclass
class PipelineResult:
    """Per-frame cost of the pure hot path, microseconds."""

    frames: int
    parse_us: float
    filter_us: float
    encode_us: float
    total_us: float
    message_frames: int
    """Frames in one ``--publish-hz`` message (sensor rate / publish rate, rounded up)."""
    message_gap_s: float
    """The time between two such messages (1 / publish rate), seconds."""
    message_warm_us: float
    """One such message (parse and filter its frames, encode the last), run right after
    the one before it: caches warm. Median."""
    message_cold_us: float
    """The same after sleeping ``message_gap_s``, as the low-power loop does between
    messages: what a wake-up costs in cache misses on this machine. Median."""


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


# -- 1. bulk decode ----------------------------------------------------------------


def synthetic_stream(n_frames: int, garbage_every: int = 50, seed: int = 0) -> bytes:
    """A recording-like byte stream: ``n_frames`` good frames, a burst of 1-16 random
    bytes before every ``garbage_every``-th one and a corrupted frame now and then."""
    import numpy as np

    rng = np.random.default_rng(seed)
    body = np.empty((n_frames, 9), dtype=np.uint8)
    body[:, 0] = body[:, 1] = 0x59
    dist = rng.integers(20, 800, n_frames, dtype=np.uint16)
    amp = rng.integers(50, 30000, n_frames, dtype=np.uint16)
    temp = np.full(n_frames, round((40.0 + 256.0) * 8.0), dtype=np.uint16)
    fields = np.stack([dist, amp, temp], axis=1).astype("<u2")
    body[:, 2:8] = fields.view(np.uint8).reshape(n_frames, 6)
    body[:, 8] = body[:, :8].sum(axis=1, dtype=np.uint8)
    parts: list[bytes] = []
    step = max(1, garbage_every)
    for start in range(0, n_frames, step):
        junk = rng.integers(0, 256, int(rng.integers(1, 17)), dtype=np.uint8).tobytes()
        block = body[start : start + step].copy()
        if start % (7 * step) == 0 and len(block) > 1:
            block[1, 8] ^= 0x5A  # a bad checksum
        parts.append(junk + block.tobytes())
    return b"".join(parts)


def bench_bulk(n_frames: int = 1_000_000, repeats: int = 5, check: bool = True) -> BulkResult:
    """Decode a synthetic recording with ``decode_bulk``; best of ``repeats``."""
    import time

    from lunad.protocol.bulk import decode_bulk
    from lunad.protocol.frame import Frame
    from lunad.protocol.parser import FrameParser

    data = synthetic_stream(n_frames)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = decode_bulk(data)
        best = min(best, time.perf_counter() - t0)
    frames = len(res.dist)
    n_check = min(len(data), 9 * 200_000)
    t0 = time.perf_counter()
    parsed = FrameParser().feed(data[:n_check], 0)
    streaming = time.perf_counter() - t0
    same = True
    if check:
        part = decode_bulk(data[:n_check])
        got = [(f.dist, f.amp, f.temp_raw) for f in parsed if type(f) is Frame]
        same = got == list(
            zip(part.dist.tolist(), part.amp.tolist(), part.temp_raw.tolist(), strict=True)
        )
    return BulkResult(
        frames=frames,
        stream_bytes=len(data),
        bulk_fps=frames / best,
        streaming_fps=sum(1 for f in parsed if hasattr(f, "dist")) / streaming,
        same_as_streaming=same,
    )


# -- 2. the pure hot path -----------------------------------------------------------


def _sensor_frames(n: int, seed: int = 1) -> list[bytes]:
    import random

    from lunad.protocol.frame import encode_frame, temp_raw_from_c
    from lunad.sim.physics import PaperSensor, Truth

    rng = random.Random(seed)
    model = PaperSensor()
    temp = temp_raw_from_c(40.0)
    out = []
    for k in range(n):
        truth = Truth(2.0 + 0.5 * ((k // 500) % 3), 0.8, 10.0, 100.0 + 50.0 * (k % 7))
        r = model.sample(truth, rng)
        out.append(encode_frame(r.dist_cm, r.amp, temp))
    return out


def bench_pipeline(
    n_frames: int = 50_000, publish_hz: float = 50.0, messages: int = 200
) -> PipelineResult:
    """Parse, filter and encode ``n_frames`` frames fed one at a time (as at 250 Hz);
    then ``messages`` pairs of ``--publish-hz`` messages (``bench_message``)."""
    import time

    from lunad.filters import RangeFilter
    from lunad.protocol.frame import Frame
    from lunad.protocol.messages import encode_range, reasons_json
    from lunad.protocol.parser import FrameParser

    chunks = _sensor_frames(n_frames)
    period = 4_000_000
    ts = [k * period for k in range(n_frames)]

    parser = FrameParser()
    t0 = time.perf_counter()
    frames: list[Frame] = []
    for chunk, t in zip(chunks, ts, strict=True):
        frames += parser.feed(chunk, t)  # type: ignore[arg-type]
    parse_s = time.perf_counter() - t0

    filt = RangeFilter()
    t0 = time.perf_counter()
    ests = [filt.step(f.distance_m, f.amp, f.t_mono_ns) for f in frames]
    filter_s = time.perf_counter() - t0

    rcache: dict[tuple[str, ...], bytes] = {}
    t0 = time.perf_counter()
    for seq, (f, e) in enumerate(zip(frames, ests, strict=True)):
        reasons = rcache.get(e.reasons)
        if reasons is None:
            reasons = rcache[e.reasons] = reasons_json(e.reasons)
        encode_range(
            IDENT,
            seq,
            1,
            f.t_mono_ns,
            f.t_mono_ns,
            f.distance_m,
            f.amp,
            f.temp_c,
            e.strength,
            e.range_m,
            e.sigma_m,
            e.lux_est,
            e.status,
            reasons,
            e.zone,
        )
    encode_s = time.perf_counter() - t0

    # All three together, as the read loop runs them.
    parser = FrameParser()
    filt = RangeFilter()
    rcache = {}
    seq = 0
    t0 = time.perf_counter()
    for chunk, t in zip(chunks, ts, strict=True):
        for fr in parser.feed(chunk, t):
            e = filt.step(fr.distance_m, fr.amp, fr.t_mono_ns)  # type: ignore[union-attr]
            reasons = rcache.get(e.reasons)
            if reasons is None:
                reasons = rcache[e.reasons] = reasons_json(e.reasons)
            encode_range(
                IDENT,
                seq,
                1,
                t,
                t,
                fr.distance_m,  # type: ignore[union-attr]
                fr.amp,  # type: ignore[union-attr]
                fr.temp_c,  # type: ignore[union-attr]
                e.strength,
                e.range_m,
                e.sigma_m,
                e.lux_est,
                e.status,
                reasons,
                e.zone,
            )
            seq += 1
    total_s = time.perf_counter() - t0
    us = 1e6 / n_frames
    per_message = math.ceil(SENSOR_HZ / publish_hz)
    warm_us, cold_us = bench_message(per_message, 1.0 / publish_hz, messages)
    return PipelineResult(
        n_frames,
        parse_s * us,
        filter_s * us,
        encode_s * us,
        total_s * us,
        per_message,
        1.0 / publish_hz,
        warm_us,
        cold_us,
    )


def bench_message(frames: int = 5, gap_s: float = 0.02, messages: int = 200) -> tuple[float, float]:
    """Median microseconds of one ``--publish-hz`` message's pure work: one read of
    ``frames`` frames parsed, each filtered (spaced a sensor frame apart, as
    ``Daemon._read_folded`` does), the last encoded. Each pair of messages sleeps
    ``gap_s`` first: the first of the pair runs cold, the second right after it, warm.
    The two differ by what caches and branch predictors lost while asleep; on a shared
    VM, several times the work itself (docs/performance.md, "Cold wake-ups").
    Returns (warm, cold)."""
    import time

    from lunad.filters import RangeFilter
    from lunad.protocol.frame import Frame
    from lunad.protocol.messages import encode_range, reasons_json
    from lunad.protocol.parser import FrameParser

    raw = _sensor_frames(2 * messages * frames, seed=2)
    reads = [b"".join(raw[i : i + frames]) for i in range(0, len(raw), frames)]
    parser = FrameParser()
    filt = RangeFilter()
    rcache: dict[tuple[str, ...], bytes] = {}
    spacing = 1_000_000_000 // SENSOR_HZ
    clock = time.perf_counter_ns
    warm: list[float] = []
    cold: list[float] = []
    for i, data in enumerate(reads):
        t = (i + 1) * frames * spacing
        if i % 2 == 0:
            time.sleep(gap_s)
        t0 = clock()
        items = parser.feed(data, t)
        k = len(items)
        for fr in items:
            k -= 1
            e = filt.step(fr.distance_m, fr.amp, t - k * spacing)  # type: ignore[union-attr]
        last: Frame = items[-1]  # type: ignore[assignment]
        reasons = rcache.get(e.reasons)
        if reasons is None:
            reasons = rcache[e.reasons] = reasons_json(e.reasons)
        encode_range(IDENT, i, frames, t, t, last.distance_m, last.amp, last.temp_c, e.strength,
                     e.range_m, e.sigma_m, e.lux_est, e.status, reasons, e.zone)  # fmt: skip
        (cold if i % 2 == 0 else warm).append(clock() - t0)
    return _median(warm) / 1e3, _median(cold) / 1e3


# -- 3. serve end to end -------------------------------------------------------------


def _cpu_ticks(pid: int) -> int:
    """utime + stime of every thread of ``pid``, in clock ticks."""
    with open(f"/proc/{pid}/stat", "rb") as f:
        stat = f.read()
    rest = stat[stat.rindex(b")") + 2 :].split()
    return int(rest[11]) + int(rest[12])  # fields 14 and 15 of proc(5)


def _task_totals(pid: int) -> tuple[int, int] | None:
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


def _vm_hwm_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _percentile(values: list[int], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    k = min(len(s) - 1, max(0, round(q * (len(s) - 1))))
    return float(s[k])


def _seq_of(payload: bytes) -> int:
    i = payload.index(b'"seq":') + 6
    j = i
    while 48 <= payload[j] <= 57:
        j += 1
    return int(payload[i:j])


def serve_command(variant: str, device: str, endpoint: str, publish_hz: float | None) -> list[str]:
    """The command line of one run."""
    if variant == "floor":
        return [sys.executable, "-m", "lunad.daemon.bench", "--device", device,
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
    signal's interruption while the processes start (``cli.Interrupts.held``)."""
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
                [sys.executable, "-m", "lunad.daemon.bench", "receive", "--connect", endpoint,
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
            c0, t0, n0 = _cpu_ticks(proc.pid), time.monotonic_ns(), len(sent)
            time.sleep(duration_s)
            c1, t1, n1 = _cpu_ticks(proc.pid), time.monotonic_ns(), len(sent)
            hz = os.sysconf("SC_CLK_TCK")
            cpu_s = (c1 - c0) / hz
            frames = n1 - n0
            dev.pause(3600.0)
            time.sleep(idle_settle_s)
            i0, ic0, it0 = _task_totals(proc.pid), _cpu_ticks(proc.pid), time.monotonic_ns()
            time.sleep(idle_s)
            i1, ic1, it1 = _task_totals(proc.pid), _cpu_ticks(proc.pid), time.monotonic_ns()
            rss = _vm_hwm_mib(proc.pid)
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
        lat_p50_us=_percentile(lat, 0.50) / 1e3,
        lat_p99_us=_percentile(lat, 0.99) / 1e3,
        idle_cpu_pct=100.0 * idle_cpu_s / idle_window_s,
        idle_wakeups_per_s=idle_wakeups / idle_window_s,
        rss_mib=rss,
        startup_s=startup_s,
        exit_code=code,
        log_tail=log_path.read_text(errors="replace")[-2000:] if code else "",
    )


def cpu_split() -> tuple[set[int], set[int]] | None:
    """(CPUs for the bench and its receiver, the CPU for the process under test), or
    None with fewer than two CPUs to run on."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        return None
    return set(cpus[:-1]), {cpus[-1]}


def _median(xs: list[float]) -> float:
    import statistics

    xs = [x for x in xs if x == x]
    return statistics.median(xs) if xs else float("nan")


def summarise(runs: list[ServeRun]) -> ServeSummary:
    """Medians of each figure over ``runs`` (one variant and mode)."""
    r0 = runs[0]
    return ServeSummary(
        variant=r0.variant,
        publish_hz=r0.publish_hz,
        rounds=len(runs),
        cpu_us_per_frame=_median([r.cpu_us_per_frame for r in runs]),
        cpu_pct=_median([r.cpu_pct for r in runs]),
        lat_p50_us=_median([r.lat_p50_us for r in runs]),
        lat_p99_us=_median([r.lat_p99_us for r in runs]),
        idle_cpu_pct=_median([r.idle_cpu_pct for r in runs]),
        idle_wakeups_per_s=_median([r.idle_wakeups_per_s for r in runs]),
        rss_mib=_median([r.rss_mib for r in runs]),
        startup_s=_median([r.startup_s for r in runs]),
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


if __name__ == "__main__":
    if sys.argv[1:2] == ["receive"]:
        sys.exit(receiver_main(sys.argv[2:]))
    sys.exit(floor_main())
