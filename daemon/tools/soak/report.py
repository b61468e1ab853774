"""What a soak measured (``SoakReport``, also its JSON) and the human report."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from lunad.daemon.tools.soak.resources import Sample
from lunad.daemon.tools.soak.schedule import FAULT_KINDS, Fault, hms


@dataclass
class FaultResult:
    """What happened when one fault ran."""

    kind: str
    at_s: float
    duration_s: float
    recovery_s: float | None
    ok: bool
    note: str = ""
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class SoakReport:
    """Everything a soak measured, and its verdict."""

    seed: int
    duration_s: float
    rate_hz: int
    elapsed_s: float = 0.0
    schedule: list[Fault] = field(default_factory=list)
    faults: list[FaultResult] = field(default_factory=list)
    accounting: dict[str, int] = field(default_factory=dict)
    slow_subscriber_lost: int = 0
    slow_subscriber_received: int = 0
    frames_unread: int = 0
    health: dict[str, Any] = field(default_factory=dict)
    bad_messages: int = 0
    latency_us: dict[str, float] = field(default_factory=dict)
    samples: list[Sample] = field(default_factory=list)
    warmup_s: float = 0.0
    rss: dict[str, float] = field(default_factory=dict)
    fds: dict[str, float] = field(default_factory=dict)
    cpu: dict[str, float] = field(default_factory=dict)
    daemon_pid: int = 0
    daemon_died_at_s: float | None = None
    daemon_exit_code: int | None = None
    daemon_stop_s: float | None = None
    log_tracebacks: int = 0
    byte_check: dict[str, Any] = field(default_factory=dict)
    """With ``--keep-logs``: the two byte recordings compared (``byte_check.compare``)."""
    aborted: str = ""
    passed: bool = False
    conditions: dict[str, bool] = field(default_factory=dict)
    reasons: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["samples"] = [[s.t_s, s.rss_kib, s.fds, s.cpu_ticks, s.published] for s in self.samples]
        d["samples_columns"] = ["t_s", "rss_kib", "fds", "cpu_ticks", "published"]
        return d


def format_report(r: SoakReport) -> str:
    """The human report printed at the end."""
    acc = r.accounting
    out = [
        f"soak: seed {r.seed}, {hms(r.elapsed_s)} of streaming at {r.rate_hz} Hz, "
        f"daemon pid {r.daemon_pid}",
        "",
        "frames",
        f"  sent by the sensor (good, fully written)   {acc.get('frames_sent', 0)}",
        f"  found in the bytes by a reference parser   {acc.get('reference_frames', 0)}"
        f"  ({acc.get('false_frames', 0)} formed by garbage, "
        f"{acc.get('eaten_frames', 0)} real ones swallowed by them)",
        f"  published (distinct seq at the main sub)    {acc.get('published', 0)}",
        f"  lost                                       {acc.get('lost', 0)}"
        f"  (seq gaps {acc.get('gaps', 0)}, missing {acc.get('missing', 0)}, "
        f"wrong content {acc.get('mismatched', 0)}, unexpected {acc.get('unexpected', 0)})",
        f"  slow subscriber HWM losses (expected)      {r.slow_subscriber_lost}"
        f" of {r.slow_subscriber_lost + r.slow_subscriber_received}",
        f"  frames the sensor could not write           {r.frames_unread}",
    ]
    if r.health:
        h = r.health
        out.append(
            f"  daemon health: {h['frames']} frames, {h['checksum_errors']} checksum errors, "
            f"{h['bytes_discarded']} bytes discarded, {h['dropped_sends']} dropped sends"
        )
    if r.latency_us:
        lat = r.latency_us
        out.append(
            f"  read -> subscriber latency: p50 {lat['p50'] / 1000:.2f} ms, "
            f"p99 {lat['p99'] / 1000:.2f} ms, max {lat['max'] / 1000:.1f} ms; "
            f"sensor write -> daemon read max "
            f"{lat.get('sensor_to_daemon_read_max', float('nan')) / 1000:.1f} ms; "
            f"the soak's own scheduling lag max "
            f"{lat.get('soak_lag_max', float('nan')) / 1000:.0f} ms"
        )
    if r.byte_check:
        b = r.byte_check
        out.append(f"  byte recordings: {b.get('summary', b.get('error'))}")
    out += [
        "",
        f"faults ({len(r.faults)})",
        f"{'at':>9}  {'fault':<16}{'lasts':>7}{'recovery':>10}  ok",
    ]
    for f in r.faults:
        rec = "-" if f.recovery_s is None else f"{f.recovery_s:.3f}s"
        out.append(
            f"{f.at_s:8.1f}s  {f.kind:<16}{f.duration_s:6.1f}s{rec:>10}  "
            f"{'yes' if f.ok else 'NO '}  {f.note}"
        )
    by_kind: dict[str, list[float]] = {}
    for f in r.faults:
        if f.recovery_s is not None:
            by_kind.setdefault(f.kind, []).append(f.recovery_s)
    if by_kind:
        out.append("recovery by type (n, median, max):")
        for k in FAULT_KINDS:
            v = sorted(by_kind.get(k, []))
            if v:
                out.append(f"  {k:<16} {len(v):4d}  {v[len(v) // 2]:.3f} s  {v[-1]:.3f} s")
    rss, fds, cpu = r.rss, r.fds, r.cpu
    out += ["", "resources (daemon)"]
    if rss:
        out.append(
            f"  RSS {rss['start_mib']:.1f} -> {rss['end_mib']:.1f} MiB (max {rss['max_mib']:.1f});"
            f" after {r.warmup_s:.0f} s warm-up: {rss['mib_per_h']:+.2f} MiB/h fitted over "
            f"{rss['window_s']:.0f} s = {rss['growth_kib']:+.0f} KiB, "
            f"allowed {rss['allowed_kib']:.0f} KiB"
        )
    if fds:
        out.append(
            f"  open files: {fds['baseline']} at start, {fds['end']} at end "
            f"(min {fds.get('min')}, max {fds.get('max')}; "
            f"fit {fds.get('per_h_fit', 0.0):+.2f}/h)"
        )
    if cpu:
        out.append(
            f"  CPU {cpu['us_per_frame']:.0f} us per published frame, {cpu['pct']:.1f} % "
            f"on average ({cpu['cpu_s']:.1f} s)"
        )
    if r.samples:
        step = max(1, len(r.samples) // 12)
        pts = r.samples[::step] + ([r.samples[-1]] if (len(r.samples) - 1) % step else [])
        out.append(
            "  over time (s: MiB/fds): "
            + ", ".join(f"{s.t_s:.0f}: {s.rss_kib / 1024:.2f}/{s.fds}" for s in pts)
        )
    stop = "" if r.daemon_stop_s is None else f" {r.daemon_stop_s:.2f} s after SIGTERM"
    out.append(f"  daemon exit code {r.daemon_exit_code}{stop}")
    out += ["", "conditions"]
    for name, ok in r.conditions.items():
        out.append(f"  {'ok  ' if ok else 'FAIL'}  {name.replace('_', ' ')}")
    out.append("")
    if r.passed:
        out.append("PASS: every valid frame published, every fault recovered within 5 s, "
                   "no RSS or fd growth, the daemon never restarted")  # fmt: skip
    else:
        out.append("FAIL: " + "; ".join(r.reasons))
    return "\n".join(out)
