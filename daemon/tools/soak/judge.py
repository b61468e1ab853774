"""The soak's PASS/FAIL rules: the limits, and ``judge`` applying them to a report."""

from __future__ import annotations

from lunad.daemon.tools.soak.report import SoakReport
from lunad.daemon.tools.soak.resources import Sample, fit_slope
from lunad.daemon.tools.soak.schedule import FAULT_KINDS

RECOVERY_LIMIT_S = 5.0  # every fault must recover within this (docs/soak.md, PASS rule 2)
WAITING_LIMIT_S = 2.0  # a silent sensor shows state waiting within this (docs/architecture.md)
RSS_LIMIT_MIB_PER_H = 1.0
RSS_NOISE_FLOOR_KIB = 256.0  # below this, growth in a short window is allocator noise
STALL_LIMIT_S = 1.0  # sensor write -> daemon read, while a subscriber is slow


def judge(report: SoakReport) -> SoakReport:
    """Fill in ``conditions``, ``reasons`` and ``passed`` from the measurements."""
    acc = report.accounting
    reasons: list[str] = []
    lost = acc.get("lost", 0)
    no_loss = lost == 0 and report.bad_messages == 0 and acc.get("published", 0) > 0
    if lost:
        parts = [
            f"{acc[k]} {k.replace('_', ' ')}"
            for k in ("gaps", "missing", "mismatched", "unexpected", "seq_backwards")
            if acc.get(k)
        ]
        reasons.append(f"{lost} valid frame(s) lost or wrong: {', '.join(parts)}")
    if report.bad_messages:
        reasons.append(f"{report.bad_messages} message(s) broke the schema")
    if not acc.get("published"):
        reasons.append("nothing was published")
    kinds_done = {f.kind for f in report.faults}
    missing_kinds = [k for k in FAULT_KINDS if k not in kinds_done]
    failed = [f for f in report.faults if not f.ok]
    recovered = not failed and not missing_kinds
    for f in failed[:5]:
        rec = "never" if f.recovery_s is None else f"{f.recovery_s:.2f} s"
        reasons.append(f"{f.kind} at {f.at_s:.1f} s failed (recovery {rec}): {f.note}")
    if len(failed) > 5:
        reasons.append(f"... and {len(failed) - 5} more faults failed")
    if missing_kinds:
        reasons.append(f"fault types not exercised: {', '.join(missing_kinds)}")
    rss_ok = bool(report.rss.get("ok", False))
    if not rss_ok:
        reasons.append(
            f"RSS grew {report.rss.get('growth_kib', float('nan')):.0f} KiB after warm-up "
            f"({report.rss.get('mib_per_h', float('nan')):.2f} MiB/h), "
            f"allowed {report.rss.get('allowed_kib', float('nan')):.0f} KiB"
        )
    fd_ok = bool(report.fds.get("ok", False))
    if not fd_ok:
        reasons.append(
            f"open files grew from {report.fds.get('baseline')} to {report.fds.get('end')}"
        )
    alive = report.daemon_died_at_s is None and not report.aborted
    if report.daemon_died_at_s is not None:
        reasons.append(f"the daemon exited at {report.daemon_died_at_s:.1f} s")
    if report.aborted:
        reasons.append(f"soak aborted: {report.aborted}")
    clean = report.daemon_exit_code == 0 and report.log_tracebacks == 0
    if report.daemon_exit_code != 0 and report.daemon_died_at_s is None:
        reasons.append(f"the daemon exited with {report.daemon_exit_code} on SIGTERM")
    if report.log_tracebacks:
        reasons.append(f"{report.log_tracebacks} traceback(s) in the daemon's log")
    report.conditions = {
        "no_frame_lost": no_loss,
        "every_fault_recovered_5s": recovered,
        "rss_growth_under_1mib_per_h": rss_ok,
        "no_fd_growth": fd_ok,
        "daemon_never_restarted": alive,
        "clean_exit": clean,
    }
    report.reasons = reasons
    report.passed = all(report.conditions.values())
    return report


def rss_verdict(samples: list[Sample], warmup_s: float) -> dict[str, float]:
    """RSS after warm-up: fitted growth per hour and whether it is within the limit.

    The limit is 1 MiB/h over the window after warm-up; for a short window, where a
    fit extrapolates a page or two of allocator noise to an hour, at least
    ``RSS_NOISE_FLOOR_KIB`` of growth over the window is allowed.
    """
    post = [s for s in samples if s.t_s >= warmup_s]
    if len(post) < 3:
        post = samples[len(samples) // 2 :]
    xs = [s.t_s for s in post]
    ys = [s.rss_kib for s in post]
    slope = fit_slope(xs, ys)  # KiB/s
    window = (xs[-1] - xs[0]) if len(xs) >= 2 else 0.0
    growth = slope * window
    allowed = max(RSS_LIMIT_MIB_PER_H * 1024 * window / 3600, RSS_NOISE_FLOOR_KIB)
    rss = [s.rss_kib for s in samples] or [float("nan")]
    return {
        "start_mib": rss[0] / 1024,
        "end_mib": rss[-1] / 1024,
        "max_mib": max(rss) / 1024,
        "window_s": window,
        "mib_per_h": slope * 3600 / 1024,
        "growth_kib": growth,
        "allowed_kib": allowed,
        "ok": float(growth < allowed),
    }
