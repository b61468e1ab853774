"""``lunad soak``: the daemon for a long time under a seeded schedule of faults, judged.

``schedule`` plans the faults from the seed; ``runner`` plays the sensor, runs the
daemon and drives the faults (``faults``: what each does); ``ledger`` accounts for every
frame against a reference parser; ``subscribers`` read the stream; ``resources`` samples
the daemon; ``judge`` gives PASS or FAIL and ``report`` prints it; ``byte_check``
compares the byte recordings a soak keeps (``python -m lunad.daemon.tools.soak DIR``).
"""

from lunad.daemon.tools.soak.byte_check import DAEMON_INPUT, SENSOR_OUTPUT, ByteCheck, compare
from lunad.daemon.tools.soak.faults import FaultActions
from lunad.daemon.tools.soak.judge import (
    RECOVERY_LIMIT_S,
    RSS_LIMIT_MIB_PER_H,
    RSS_NOISE_FLOOR_KIB,
    STALL_LIMIT_S,
    WAITING_LIMIT_S,
    judge,
    rss_verdict,
)
from lunad.daemon.tools.soak.ledger import Ledger
from lunad.daemon.tools.soak.report import FaultResult, SoakReport, format_report
from lunad.daemon.tools.soak.resources import Sample, fd_count, fit_slope, vm_rss_kib
from lunad.daemon.tools.soak.runner import DRAIN_TIMEOUT_S, DaemonDied, Soak, run_soak
from lunad.daemon.tools.soak.schedule import (
    FAULT_HELP,
    FAULT_KINDS,
    MIN_DURATION_S,
    SHORT_SOAK_S,
    Fault,
    build_schedule,
    format_schedule,
    hms,
    parse_duration,
)
from lunad.daemon.tools.soak.subscribers import (
    NS,
    SENSOR,
    LatencyHistogram,
    MainSubscriber,
    SlowSubscriber,
    Watch,
)

__all__ = [
    "DAEMON_INPUT",
    "DRAIN_TIMEOUT_S",
    "FAULT_HELP",
    "FAULT_KINDS",
    "MIN_DURATION_S",
    "NS",
    "RECOVERY_LIMIT_S",
    "RSS_LIMIT_MIB_PER_H",
    "RSS_NOISE_FLOOR_KIB",
    "SENSOR",
    "SENSOR_OUTPUT",
    "SHORT_SOAK_S",
    "STALL_LIMIT_S",
    "WAITING_LIMIT_S",
    "ByteCheck",
    "DaemonDied",
    "Fault",
    "FaultActions",
    "FaultResult",
    "LatencyHistogram",
    "Ledger",
    "MainSubscriber",
    "Sample",
    "SlowSubscriber",
    "Soak",
    "SoakReport",
    "Watch",
    "build_schedule",
    "compare",
    "fd_count",
    "fit_slope",
    "format_report",
    "format_schedule",
    "hms",
    "judge",
    "parse_duration",
    "rss_verdict",
    "run_soak",
    "vm_rss_kib",
]
