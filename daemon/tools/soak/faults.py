"""The soak's fault actions: what each fault type does to the sensor, the daemon or a
subscriber, and how its recovery is timed and judged.

Recovery time of a fault: from its end (for an unplug, the replug) to the first frame
the daemon read after it arriving at the main subscriber. A silent sensor must also show
``waiting`` on health within 2 s. ``FaultActions`` is a part of ``runner.Soak`` (a base
class of it): its methods run on the soak's state, from the executor.
"""

from __future__ import annotations

import dataclasses
import random
import signal
import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lunad.daemon.tools.soak.judge import RECOVERY_LIMIT_S, STALL_LIMIT_S, WAITING_LIMIT_S
from lunad.daemon.tools.soak.ledger import Ledger
from lunad.daemon.tools.soak.report import FaultResult, SoakReport
from lunad.daemon.tools.soak.resources import fd_count
from lunad.daemon.tools.soak.schedule import Fault
from lunad.daemon.tools.soak.subscribers import (
    NS,
    SENSOR,
    MainSubscriber,
    SlowSubscriber,
    Watch,
)
from lunad.protocol.frame import encode_frame, temp_raw_from_c
from lunad.sim.pty_device import PtyDevice


class FaultActions:
    """``_fault`` runs one scheduled fault; ``_resume_slow`` ends a slow subscriber's."""

    # The soak's state these methods use; ``Soak.__init__`` and ``Soak._run`` set it.
    rate_hz: int
    rng: random.Random
    ledger: Ledger
    report: SoakReport
    dev: PtyDevice
    sub: MainSubscriber
    proc: subprocess.Popen[bytes]
    endpoint: str
    config: Path
    _health_interval: float
    _reloads: int
    _slow: SlowSubscriber | None
    _slow_fault: Fault | None
    _slow_started: float
    _slow_unread0: int
    _lag_window_max: float

    if TYPE_CHECKING:  # defined by Soak

        def _now_s(self) -> float: ...

        def _config_text(self) -> str: ...

        def _check_alive(self) -> None: ...

        def _sleep(self, seconds: float) -> None: ...

        def _recovery(self, t_end_ns: int, w: Watch | None = None) -> float | None: ...

        def _drain(self) -> tuple[bool, int, int, float]: ...

        def _log_count(self, text: str) -> int: ...

    def _fault(self, f: Fault) -> FaultResult:
        dev = self.dev
        start = self._now_s()
        details: dict[str, Any] = {}
        note = ""
        ok_extra = True
        d = f.duration_s
        if f.kind in ("garbage", "corrupt"):
            before = self._parser_counts()
            setattr(dev, f"{f.kind}_rate", f.params["rate"])
            self._sleep(d)
            setattr(dev, f"{f.kind}_rate", 0.0)
            t_end = time.monotonic_ns()
            rec = self._recovery(t_end)
            details["frames_corrupted" if f.kind == "corrupt" else "garbage_bytes"] = (
                dev.frames_corrupted if f.kind == "corrupt" else dev.garbage_bytes
            )
            details["parser_before"] = before
        elif f.kind == "cut":
            temp = temp_raw_from_c(40.0)
            end = time.monotonic() + d
            cuts = 0
            while time.monotonic() < end:
                frame = encode_frame(self.rng.randint(150, 250), self.rng.randint(500, 9000), temp)
                dev.inject_garbage(frame[: self.rng.randint(1, 8)])
                cuts += 1
                self._sleep(1.0 / f.params["per_s"])
            t_end = time.monotonic_ns()
            rec = self._recovery(t_end)
            details["cuts"] = cuts
        elif f.kind == "silence":
            t_start = time.monotonic_ns()
            waiting = self.sub.watch("health", t_start, "waiting")
            dev.pause(d)
            w_s = self.sub.wait(waiting, d)
            self._sleep(max(0.0, d - (time.monotonic_ns() - t_start) / NS))
            t_end = t_start + int(d * NS)
            rec = self._recovery(t_end)
            details["waiting_after_s"] = w_s
            ok_extra = w_s is not None and w_s <= WAITING_LIMIT_S
            note = f"waiting after {w_s:.2f} s" if w_s is not None else "never reported waiting"
        elif f.kind == "unplug":
            dev.pause(1e9)
            drained, missing, _unexpected, took = self._drain()
            details.update(drained=drained, missing=missing, drain_s=round(took, 3))
            t_unplug = time.monotonic_ns()
            reconnecting = self.sub.watch("health", t_unplug, "reconnecting")
            dev.unplug()
            self.ledger.reset_parser()
            self._sleep(d)
            r_s = self.sub.wait(reconnecting, 0.1)
            cmds = dev.commands_received
            w = self.sub.watch("range", 0)
            dev.replug()
            t_replug = time.monotonic_ns()
            w.after_ns = t_replug
            while dev.commands_received == cmds and time.monotonic_ns() - t_replug < 6 * NS:
                self._check_alive()
                time.sleep(0.005)
            dev.pause(0)
            t_end = t_replug
            rec = self._recovery(t_end, w)
            details["reconnecting_after_s"] = r_s
            ok_extra = drained and r_s is not None
            note = "drained, " if drained else f"{missing} frames missing at drain, "
            note += "reconnecting seen" if r_s is not None else "no reconnecting on health"
        elif f.kind == "rate_burst":
            settings = dev.sensor.settings
            t_fast = time.monotonic_ns()
            sent0 = dev.frames_sent
            dev.sensor.settings = dataclasses.replace(settings, rate_hz=250)
            self._sleep(f.params["fast_s"])
            t_slow = time.monotonic_ns()
            sent_fast = dev.frames_sent - sent0
            dev.sensor.settings = dataclasses.replace(dev.sensor.settings, rate_hz=1)
            self._sleep(f.params["slow_s"])
            t_end = time.monotonic_ns()
            dev.sensor.settings = dataclasses.replace(dev.sensor.settings, rate_hz=self.rate_hz)
            rec = self._recovery(t_end)
            reads = list(self.sub.read_times)  # counted by the daemon's read time
            n_fast = sum(1 for t in reads if t_fast <= t < t_slow)
            n_slow = sum(1 for t in reads if t_slow <= t < t_end)
            flaps = sum(1 for t, s in self.sub.states if t >= t_slow and s == "waiting")
            fast_s = (t_slow - t_fast) / NS
            details.update(
                fps_250=round(n_fast / fast_s, 1),
                sensor_fps_250=round(sent_fast / fast_s, 1),
                fps_1=round(n_slow / ((t_end - t_slow) / NS), 2),
                waiting_at_1hz=flaps,
            )
            # Keeping up: the daemon read, in the fast window, what the sensor wrote in it
            # (a starved soak process writes fewer than 250 a second; a frame written
            # just before the window closes may be read just after it).
            ok_extra = n_fast >= 0.9 * sent_fast - 5
            note = (
                f"{details['fps_250']:.0f} fps read at 250 Hz (the sensor wrote "
                f"{details['sensor_fps_250']:.0f}/s), {details['fps_1']:.2f} fps at 1 Hz, "
                f"{flaps} waiting state(s) at 1 Hz"
            )
        elif f.kind == "baud":
            dev.pause(1e9)
            end = time.monotonic() + d
            t_last = time.monotonic()
            sent = 0
            while time.monotonic() < end:
                self._sleep(0.02)
                now = time.monotonic()
                n = round(9 * self.rate_hz * (now - t_last))
                t_last = now
                dev.inject_garbage(self.rng.randbytes(n))
                sent += n
            states = {s for t, s in self.sub.states if t / NS >= end - d}
            t_end = time.monotonic_ns()
            dev.pause(0)
            rec = self._recovery(t_end)
            details.update(noise_bytes=sent, states=sorted(states))
            note = f"{sent} noise bytes"
        elif f.kind == "churn":
            from lunad.protocol.client import Subscriber

            fd0 = fd_count(self.proc.pid)
            end = time.monotonic() + d
            n = 0
            while time.monotonic() < end:
                s = Subscriber(self.endpoint, sensor=SENSOR)
                s.recv(timeout_s=0.0)
                self._sleep(f.params["interval_s"] / 2)
                s.close()
                n += 1
                self._sleep(f.params["interval_s"] / 2)
            t_end = time.monotonic_ns()
            fd_peak = fd_count(self.proc.pid)
            rec = None
            while time.monotonic_ns() - t_end < RECOVERY_LIMIT_S * NS:
                if fd_count(self.proc.pid) <= fd0:
                    rec = (time.monotonic_ns() - t_end) / NS
                    break
                self._check_alive()
                time.sleep(0.05)
            details.update(connections=n, fds_before=fd0, fds_after=fd_count(self.proc.pid))
            details["fds_right_after"] = fd_peak
            note = f"{n} connections, fds {fd0} -> {fd_peak} -> {details['fds_after']}"
        elif f.kind == "sighup":
            recs = []
            for _ in range(int(f.params["reloads"])):
                self._health_interval = 0.5 if self._health_interval == 1.0 else 1.0
                self.config.write_text(self._config_text())
                t_sig = time.monotonic_ns()
                self.proc.send_signal(signal.SIGHUP)
                self._reloads += 1
                while self._log_count("configuration reloaded") < self._reloads:
                    self._check_alive()
                    if time.monotonic_ns() - t_sig > RECOVERY_LIMIT_S * NS:
                        break
                    time.sleep(0.01)
                t_done = time.monotonic_ns()
                r = self._recovery(t_done)
                recs.append(None if r is None else r + (t_done - t_sig) / NS)
                self._sleep(f.params["spacing_s"])
            rec = None if any(r is None for r in recs) else max(recs)  # type: ignore[type-var]
            reloaded = self._log_count("configuration reloaded")
            ok_extra = reloaded == self._reloads
            details.update(reloads_logged=reloaded, reloads_sent=self._reloads)
            note = f"{reloaded}/{self._reloads} reloads logged so far"
        elif f.kind == "slow_subscriber":
            self._slow = SlowSubscriber(self.endpoint, int(f.params["rcvhwm"]))
            self._slow.start()
            self._slow_fault = f
            self._sleep(0.5)
            self._slow.reading.clear()
            self._slow_started = self._now_s()
            self._slow_unread0 = dev.frames_unread
            self.sub.window_max_lat_us = 0.0
            self.ledger.window_start()
            self._lag_window_max = 0.0
            return FaultResult(f.kind, round(start, 2), 0.0, None, True, "stopped reading")
        else:
            raise ValueError(f.kind)
        ok = rec is not None and rec <= RECOVERY_LIMIT_S and ok_extra
        return FaultResult(
            f.kind, round(start, 2), round(self._now_s() - start, 2), rec, ok, note, details
        )

    def _resume_slow(self, result: FaultResult) -> None:
        slow = self._slow
        assert slow is not None
        target = self.ledger.next_seq - 1
        t = time.monotonic_ns()
        stall_max_lat = self.sub.window_max_lat_us / 1e6
        read_lat = self.ledger.window_read_lat_max_ns / NS
        soak_lag = self._lag_window_max
        unread = self.dev.frames_unread - self._slow_unread0
        slow.reading.set()
        rec = None
        while time.monotonic_ns() - t < (RECOVERY_LIMIT_S + 1) * NS:
            if slow.last_seq is not None and slow.last_seq >= target:
                rec = (time.monotonic_ns() - t) / NS
                break
            self._check_alive()
            time.sleep(0.01)
        slow.close()
        self._slow = None
        self.report.slow_subscriber_lost += slow.lost
        self.report.slow_subscriber_received += slow.received
        result.duration_s = round(self._now_s() - self._slow_started, 2)
        result.recovery_s = rec
        # A stall of the whole machine (the soak's own ticker oversleeping) is not the
        # daemon's: it is allowed on top of the limit.
        no_stall = read_lat <= STALL_LIMIT_S + soak_lag and unread == 0
        result.ok = rec is not None and rec <= RECOVERY_LIMIT_S and no_stall
        result.details.update(
            hwm_lost=slow.lost,
            received=slow.received,
            main_max_latency_s=round(stall_max_lat, 4),
            daemon_read_max_latency_s=round(read_lat, 4),
            soak_lag_max_s=round(soak_lag, 4),
            sensor_frames_unread=unread,
        )
        result.note = (
            f"it lost {slow.lost} (HWM, expected), caught up; meanwhile sensor->daemon read "
            f"max {read_lat * 1000:.1f} ms, read->main sub max {stall_max_lat * 1000:.0f} ms, "
            f"soak's own lag max {soak_lag * 1000:.0f} ms"
        )

    def _parser_counts(self) -> dict[str, int]:
        h = self.sub.last_health
        if h is None:
            return {}
        return {"checksum_errors": h.checksum_errors, "bytes_discarded": h.bytes_discarded}
