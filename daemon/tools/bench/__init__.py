"""``lunad bench``: the figures you can quote, measured on this machine.

``bulk`` and ``pipeline`` time the pure work (decode; parse, filter, encode), ``rounds``
runs ``lunad serve`` against the ``floor`` (the least any Python program can spend on
the job) with the ``receiver`` timing every message and ``measure`` reading ``/proc``;
``report`` holds the targets and prints the table; ``filter_cost`` times the filter
against another revision's (``--filter-against``). ``python -m lunad.daemon.tools.bench``
runs the floor (``receive``: the receiver); every module imports only the standard
library at the top, so that the floor's RSS and start-up stay its own.
"""

from lunad.daemon.tools.bench.bulk import BulkResult, bench_bulk, synthetic_stream
from lunad.daemon.tools.bench.filter_cost import FilterCost, FilterCostError, compare
from lunad.daemon.tools.bench.floor import FLOOR_TOPIC, OUTPUT_ON, floor_main
from lunad.daemon.tools.bench.measure import (
    cpu_split,
    cpu_ticks,
    median,
    percentile,
    task_totals,
    vm_hwm_mib,
)
from lunad.daemon.tools.bench.pipeline import IDENT, PipelineResult, bench_message, bench_pipeline
from lunad.daemon.tools.bench.receiver import receiver_main, seq_of
from lunad.daemon.tools.bench.report import (
    TARGETS,
    idle_wakeups_allowed,
    idle_without_polling,
    ratio,
    render_table,
    round_ratios,
    verdict,
)
from lunad.daemon.tools.bench.rounds import (
    SENSOR_HZ,
    ServeRun,
    ServeSummary,
    bench_serve,
    run_serve_once,
    serve_command,
    summarise,
)

__all__ = [
    "FLOOR_TOPIC",
    "IDENT",
    "OUTPUT_ON",
    "SENSOR_HZ",
    "TARGETS",
    "BulkResult",
    "FilterCost",
    "FilterCostError",
    "PipelineResult",
    "ServeRun",
    "ServeSummary",
    "bench_bulk",
    "bench_message",
    "bench_pipeline",
    "bench_serve",
    "compare",
    "cpu_split",
    "cpu_ticks",
    "floor_main",
    "idle_wakeups_allowed",
    "idle_without_polling",
    "median",
    "percentile",
    "ratio",
    "receiver_main",
    "render_table",
    "round_ratios",
    "run_serve_once",
    "seq_of",
    "serve_command",
    "summarise",
    "synthetic_stream",
    "task_totals",
    "verdict",
    "vm_hwm_mib",
]
