"""``lunad soak``: run the daemon for a long time under a seeded schedule of faults.

How this works. The soak process plays the sensor (a ``PtyDevice`` in this process),
runs ``lunad serve --config FILE`` as a real subprocess, as systemd would, and
subscribes to it like robot code. A seeded schedule of faults is built up front,
scaled to the duration (every fault type at least once, then repeated rounds in a
shuffled order) and printed (``schedule.py``); one executor thread drives it, each
fault by its action in ``faults.py``, where recovery is timed.

Exact accounting: a ``Ledger`` (``ledger.py``) runs a reference parser over every byte
the device writes and matches each published message against it; a frame that reached
the daemon and is missing from the stream is a loss. Bytes still in the pty when it is
unplugged die with it, and pyserial flushes the input on open; so before an unplug (and
at the end) the sensor is paused and the ledger drained (published == reference), and
after a replug the sensor stays silent until the daemon has sent its start-up commands
(it has opened the port).

Resources: RSS (``VmRSS``), open file descriptors and CPU ticks of the daemon are
sampled every few seconds; RSS growth per hour is a least-squares fit after warm-up.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path

from lunad.daemon.sources.base import Chunk
from lunad.daemon.sources.recording import Recorder
from lunad.daemon.tools.bench.measure import cpu_ticks
from lunad.daemon.tools.soak.byte_check import DAEMON_INPUT, SENSOR_OUTPUT, compare
from lunad.daemon.tools.soak.faults import FaultActions
from lunad.daemon.tools.soak.judge import RECOVERY_LIMIT_S, judge, rss_verdict
from lunad.daemon.tools.soak.ledger import Ledger
from lunad.daemon.tools.soak.report import FaultResult, SoakReport
from lunad.daemon.tools.soak.resources import Sample, fd_count, fit_slope, vm_rss_kib
from lunad.daemon.tools.soak.schedule import Fault, build_schedule, hms
from lunad.daemon.tools.soak.subscribers import SENSOR, MainSubscriber, SlowSubscriber, Watch
from lunad.sim.pty_device import DeviceError, PtyDevice

DRAIN_TIMEOUT_S = 5.0
LUNAD_SERVE = (sys.executable, "-m", "lunad.daemon.cli", "serve")


class DaemonDied(Exception):
    """The soak cannot go on: the daemon process exited, or the virtual sensor stopped."""


class Soak(FaultActions):
    """One soak run. ``run()`` returns the judged ``SoakReport``."""

    def __init__(
        self,
        duration_s: float,
        seed: int = 0,
        rate_hz: int = 100,
        progress: Callable[[str], None] | None = None,
        keep_logs: Path | str | None = None,
        schedule: list[Fault] | None = None,
        sample_s: float | None = None,
        held: Callable[[], AbstractContextManager[None]] = contextlib.nullcontext,
    ) -> None:
        self.duration_s = duration_s
        self.seed = seed
        self.rate_hz = rate_hz
        self.progress = progress
        self.keep_logs = Path(keep_logs) if keep_logs else None
        self.schedule = schedule if schedule is not None else build_schedule(duration_s, seed)
        self.sample_s = sample_s or (2.0 if duration_s <= 900 else 10.0)
        self.rng = random.Random(seed ^ 0x50A4)
        self.ledger = Ledger()
        self.report = SoakReport(seed=seed, duration_s=duration_s, rate_hz=rate_hz)
        self.report.schedule = list(self.schedule)
        self._reloads = 0
        self._health_interval = 1.0
        self._t0 = 0.0
        self._stop_sampler = threading.Event()
        self._slow: SlowSubscriber | None = None
        self._slow_fault: Fault | None = None
        self._slow_started = 0.0
        self._slow_unread0 = 0
        self._lag_max = 0.0  # how late the soak's own ticker woke: its scheduling lag
        self._sensor_rec: Recorder | None = None  # with keep_logs: the sensor's bytes
        self._lag_window_max = 0.0
        self._held = held
        """Holds a stop (``Interrupts.held``) while a process or folder is made, until
        whatever removes it is in place."""

    # -- helpers --

    def _now_s(self) -> float:
        return time.monotonic() - self._t0

    def _config_text(self) -> str:
        record = f'record = "{self.keep_logs / DAEMON_INPUT}"\n' if self.keep_logs else ""
        return (
            'log_level = "info"\n'
            f'[sensor]\nname = "{SENSOR}"\nframe_rate_hz = {self.rate_hz}\n'
            f'[source]\ndevice = "{self.link}"\n{record}'
            f'[publish]\nendpoint = "{self.endpoint}"\n'
            f"health_interval_s = {self._health_interval}\n"
        )

    def _check_alive(self) -> None:
        error = self.dev.error
        if error is not None:  # the soak's own virtual sensor: nothing left to measure
            raise DaemonDied(f"the virtual sensor stopped: {type(error).__name__}: {error}")
        code = self.proc.poll()
        if code is not None:
            if self.report.daemon_died_at_s is None:
                self.report.daemon_died_at_s = self._now_s()
                self.report.daemon_exit_code = code
            raise DaemonDied(f"the daemon exited with code {code}")

    def _sleep(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self._check_alive()
            time.sleep(min(left, 0.1))

    def _recovery(self, t_end_ns: int, w: Watch | None = None) -> float | None:
        if w is None:
            w = self.sub.watch("range", t_end_ns)
        return self.sub.wait(w, RECOVERY_LIMIT_S + 1.0)

    def _drain(self) -> tuple[bool, int, int, float]:
        """Sensor paused by the caller: wait until every reference frame was published."""
        t = time.monotonic()
        time.sleep(0.05)
        while time.monotonic() - t < DRAIN_TIMEOUT_S:
            if self.ledger.settled():
                break
            self._check_alive()
            time.sleep(0.01)
        took = time.monotonic() - t
        missing, unexpected = self.ledger.close_books()
        return missing == 0 and unexpected == 0, missing, unexpected, took

    def _log_count(self, text: str) -> int:
        try:
            return self.log_path.read_text(errors="replace").count(text)
        except OSError:
            return 0

    # -- sampling --

    def _sample(self) -> Sample | None:
        pid = self.proc.pid
        try:
            return Sample(
                round(self._now_s(), 2),
                vm_rss_kib(pid),
                fd_count(pid),
                cpu_ticks(pid),
                self.ledger.published,
            )
        except (OSError, ValueError, IndexError):
            return None

    def _ticker(self) -> None:
        """Measures the soak process's own scheduling lag (a 50 ms sleep that overslept):
        latencies at the subscriber above it are the soak's, not the daemon's."""
        while not self._stop_sampler.is_set():
            t = time.monotonic()
            time.sleep(0.05)
            lag = time.monotonic() - t - 0.05
            self._lag_max = max(self._lag_max, lag)
            self._lag_window_max = max(self._lag_window_max, lag)

    def _sampler(self) -> None:
        next_progress = 60.0
        while not self._stop_sampler.wait(self.sample_s):
            s = self._sample()
            if s is not None:
                self.report.samples.append(s)
            if self.progress is not None and self._now_s() >= next_progress:
                next_progress += 60.0
                self.progress(self.progress_line())

    def progress_line(self) -> str:
        """One line of how the soak is going."""
        acc = self.ledger.summary()
        done = len(self.report.faults)
        failed = sum(1 for f in self.report.faults if not f.ok)
        s = self.report.samples[-1] if self.report.samples else None
        first = self.report.samples[0] if self.report.samples else None
        cpu = ""
        if s and first and s.published > first.published:
            hz = os.sysconf("SC_CLK_TCK")
            us = (s.cpu_ticks - first.cpu_ticks) / hz * 1e6 / (s.published - first.published)
            cpu = f", CPU {us:.0f} us/frame"
        res = f" | RSS {s.rss_kib / 1024:.1f} MiB, {s.fds} fds{cpu}" if s else ""
        return (
            f"[soak {hms(self._now_s())}/{hms(self.duration_s)}] faults {done}/"
            f"{len(self.schedule)} ({failed} failed), sent {acc['frames_sent']}, "
            f"published {acc['published']}, lost {acc['lost']}{res}"
        )

    # -- the run --

    def run(self) -> SoakReport:
        """Start everything, drive the schedule, stop, judge.

        The temporary folder (pty link, socket, config, log) is removed however this
        ends, a failed start included.
        """
        made: Path | None = None
        try:
            with self._held():
                made = self.work = Path(tempfile.mkdtemp(prefix="lunad-soak-"))
            return self._run()
        finally:
            if made is not None:
                shutil.rmtree(made, ignore_errors=True)

    def _run(self) -> SoakReport:
        self.link = self.work / "tfluna"
        self.endpoint = f"ipc://{self.work}/soak.sock"
        self.config = self.work / "soak.toml"
        self.log_path = self.work / "daemon.log"
        on_written = self.ledger.on_written
        rep = self.report
        with contextlib.ExitStack() as started:  # undone only if a later step fails
            if self.keep_logs is not None:
                self.keep_logs.mkdir(parents=True, exist_ok=True)
                for name in (DAEMON_INPUT, SENSOR_OUTPUT):
                    (self.keep_logs / name).unlink(missing_ok=True)
                rec = Recorder(self.keep_logs / SENSOR_OUTPUT, "soak: sensor writes")
                self._sensor_rec = rec
                started.callback(rec.close)
                on_written = self._record_written
            self.config.write_text(self._config_text())
            self.dev = PtyDevice(
                rate_hz=self.rate_hz,
                link=self.link,
                seed=self.seed,
                output_enabled=False,
                on_bytes_written=on_written,
            )
            started.callback(self.dev.close)
            self.dev.pause(1e9)  # until the subscription is live: seq 0 must arrive
            self.dev.start()
            self.sub = MainSubscriber(self.endpoint, self.ledger)
            self.sub.start()
            started.callback(self.sub.close)
            log_file = started.enter_context(open(self.log_path, "wb"))
            with self._held():
                self.proc = subprocess.Popen(
                    [*LUNAD_SERVE, "--config", str(self.config)],
                    stdout=log_file,
                    stderr=subprocess.STDOUT,
                    env={**os.environ, "PYTHONUNBUFFERED": "1"},
                )
                started.callback(self._stop_daemon)
            started.pop_all()  # from here the finally below closes them
        rep.daemon_pid = self.proc.pid
        sampler = threading.Thread(target=self._sampler, name="soak-sampler", daemon=True)
        ticker = threading.Thread(target=self._ticker, name="soak-ticker", daemon=True)
        try:
            fd_baseline = 0
            rep.warmup_s = max(20.0, 0.1 * self.duration_s)
            try:
                self._start_stream()
                s0 = self._sample()
                if s0 is not None:
                    rep.samples.append(s0)
                    fd_baseline = s0.fds
                sampler.start()
                ticker.start()
                self._execute()
            except DaemonDied as exc:
                rep.aborted = str(exc)
            self._finish(fd_baseline)
        finally:
            self._stop_sampler.set()
            for t in (sampler, ticker):
                if t.is_alive():
                    t.join(5.0)
            if self._slow is not None:
                self._slow.close()
            self._stop_daemon()
            log_file.close()
            self.sub.close()
            try:
                self.dev.close()
            except DeviceError as exc:  # judged as a FAIL below, with the report and logs kept
                rep.aborted = rep.aborted or str(exc)
            if self._sensor_rec is not None:
                self._sensor_rec.close()
                self._check_bytes()
            rep.accounting = self.ledger.summary()
            rep.bad_messages = self.sub.bad_messages
            rep.frames_unread = self.dev.frames_unread
            rep.log_tracebacks = self._log_count("Traceback")
            judge(rep)
            self._keep()
        return rep

    def _record_written(self, data: bytes, ends: list[int], t_ns: int = 0) -> None:
        assert self._sensor_rec is not None
        self._sensor_rec(Chunk(data, t_ns))
        self.ledger.on_written(data, ends, t_ns)

    def _start_stream(self) -> None:
        w = self.sub.watch("health", 0, None)
        deadline = time.monotonic() + 15.0
        while self.sub.health_msgs == 0:  # any health message: our subscription is live
            self._check_alive()
            if time.monotonic() > deadline:
                raise DaemonDied("no health message within 15 s")
            time.sleep(0.02)
        _ = w
        while self.dev.commands_received == 0:  # the daemon opened the port (and flushed it)
            self._check_alive()
            if time.monotonic() > deadline:
                raise DaemonDied("the daemon did not configure the sensor within 15 s")
            time.sleep(0.01)
        first = self.sub.watch("range", 0)
        self.dev.pause(0)
        if self.sub.wait(first, 5.0) is None:
            raise DaemonDied("no reading within 5 s of the sensor starting")
        self._t0 = time.monotonic()

    def _execute(self) -> None:
        events: list[tuple[float, int, Fault]] = []
        for i, f in enumerate(self.schedule):
            events.append((f.at_s, i, f))
            if f.kind == "slow_subscriber":
                events.append((f.params["resume_at_s"], i, f))
        events.sort(key=lambda e: (e[0], e[1]))
        slow_result: FaultResult | None = None
        for at, _i, f in events:
            wait = at - self._now_s()
            if wait > 0:
                self._sleep(wait)
            if self._now_s() > self.duration_s * 1.5 + 30 and f.kind != "slow_subscriber":
                continue  # far behind schedule: skip rather than run forever
            if f.kind == "slow_subscriber" and slow_result is not None and self._slow is not None:
                self._resume_slow(slow_result)
                self.report.faults.append(slow_result)
                slow_result = None
                continue
            result = self._fault(f)
            if f.kind == "slow_subscriber":
                slow_result = result
            else:
                self.report.faults.append(result)
        left = self.duration_s - self._now_s()
        if left > 0:
            self._sleep(left)
        self.report.faults.sort(key=lambda r: r.at_s)

    def _finish(self, fd_baseline: int) -> None:
        rep = self.report
        self.dev.pause(1e9)
        with contextlib.suppress(DaemonDied):
            self._drain()
        rep.elapsed_s = round(self._now_s(), 2)
        time.sleep(1.0)  # let the daemon close what churn and the slow subscriber left
        end = self._sample()
        if end is not None:
            rep.samples.append(end)
        hz = os.sysconf("SC_CLK_TCK")
        samples = rep.samples
        if len(samples) >= 2:
            a, b = samples[0], samples[-1]
            frames = max(1, b.published - a.published)
            cpu_s = (b.cpu_ticks - a.cpu_ticks) / hz
            rep.cpu = {
                "us_per_frame": round(cpu_s * 1e6 / frames, 1),
                "pct": round(100 * cpu_s / max(1e-9, b.t_s - a.t_s), 2),
                "cpu_s": round(cpu_s, 2),
            }
        rep.rss = rss_verdict(samples, rep.warmup_s)
        fds = [s.fds for s in samples] or [0]
        post = [s for s in samples if s.t_s >= rep.warmup_s]
        slope = fit_slope([s.t_s for s in post], [float(s.fds) for s in post]) * 3600
        fd_end = end.fds if end else fds[-1]
        rep.fds = {
            "baseline": fd_baseline,
            "end": fd_end,
            "min": min(fds),
            "max": max(fds),
            "per_h_fit": round(slope, 2),
            "ok": float(fd_end <= fd_baseline),
        }
        h = self.sub.last_health
        if h is not None:
            rep.health = {
                k: getattr(h, k)
                for k in ("state", "frames", "checksum_errors", "bytes_discarded", "dropped_sends")
            }
            rep.health["uptime_s"] = h.uptime_s
        lat = self.sub.latency
        rep.latency_us = {
            "p50": round(lat.quantile(0.5), 1),
            "p99": round(lat.quantile(0.99), 1),
            "max": round(lat.max_us, 1),
            "sensor_to_daemon_read_max": round(self.ledger.read_lat_max_ns / 1000, 1),
            "soak_lag_max": round(self._lag_max * 1e6, 1),
        }

    def _stop_daemon(self) -> None:
        proc = self.proc
        if proc.poll() is None:
            t = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            try:
                self.report.daemon_exit_code = proc.wait(5.0)
                self.report.daemon_stop_s = round(time.monotonic() - t, 3)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                self.report.daemon_exit_code = None
        elif self.report.daemon_exit_code is None:
            self.report.daemon_exit_code = proc.returncode

    def _check_bytes(self) -> None:
        assert self.keep_logs is not None
        try:
            check = compare(self.keep_logs)
        except (OSError, ValueError) as exc:
            self.report.byte_check = {"error": str(exc)}
            return
        self.report.byte_check = {
            "complete": check.complete,
            "sensor_bytes": check.sensor_bytes,
            "daemon_bytes": check.daemon_bytes,
            "skipped_spans": len(check.skipped),
            "max_wait_s": round(check.max_wait_s, 4),
            "p99_wait_s": round(check.p99_wait_s, 4),
            "frames": check.frames,
            "summary": check.summary(),
        }

    def _keep(self) -> None:
        if self.keep_logs is None:
            return
        self.keep_logs.mkdir(parents=True, exist_ok=True)
        for name in ("daemon.log", "soak.toml"):
            with contextlib.suppress(OSError):
                shutil.copy(self.work / name, self.keep_logs / name)
        (self.keep_logs / "report.json").write_text(json.dumps(self.report.to_json(), indent=1))


def run_soak(
    duration_s: float,
    seed: int = 0,
    rate_hz: int = 100,
    progress: Callable[[str], None] | None = None,
    keep_logs: Path | str | None = None,
) -> SoakReport:
    """Run a soak of ``duration_s`` seconds; the judged report."""
    return Soak(duration_s, seed, rate_hz, progress, keep_logs).run()
