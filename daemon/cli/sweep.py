"""``lunad sweep``: the paper's factorial sweep with Table I side by side, and the fit.

How this works: the command runs ``lunad.sim.sweep.run_sweep`` for the chosen
profiles (paper eqs 1-3 read literally, and the calibrated profile whose default
parameters ``lunad sweep --fit`` produced), prints Table I's rows next to the model's,
and optionally writes Fig. 2 / Fig. 3 style plots with Table I and the text's trends
on the model's axes. ``--plot`` checks matplotlib and its directory before the sweep,
so a missing extra costs no sweep. ``--fit`` re-runs the fit (``lunad.sim.fit``) and
prints parameters to paste into sim/paper_model.py, and each text claim's criteria.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from lunad.daemon.cli.arg_types import int_at_least

if TYPE_CHECKING:  # numpy behind them: imported when the command runs, not for every `lunad`
    from lunad.sim.paper_model import Profile
    from lunad.sim.sweep import RowResult

EPILOG = """examples:
  lunad sweep                        both profiles, Table I side by side
  lunad sweep --profile paper        equations 1-3 of the paper only
  lunad sweep --format json          rows as JSON objects
  lunad sweep --readings 200 --seed 7
  lunad sweep --fit                  refit the calibrated profile (seconds); each text
                                     claim printed with its criteria and values
  lunad sweep --plot figs/           per profile: fig2_*.png (vs lux), fig3_*.png (vs
                                     angle), table1_r_*.png (vs R), model lines with
                                     Table I and the text's bounds as markers
  lunad sweep --profile calibrated --readings 200 --plot figs/

--plot needs matplotlib: pip install 'lunad[plot]' (in a checkout:
.venv/bin/pip install matplotlib).

exit status: 0 done; 2 bad option; 69 --plot without matplotlib; 78 --plot DIR
cannot be created; 74 a plot cannot be written.
"""


DEFAULT_PROFILE = "both"
DEFAULT_FORMAT = "table"
DEFAULT_READINGS = 1000
SWEEP_ONLY = {
    "profile": "--profile",
    "fmt": "--format",
    "readings": "--readings",
    "seed": "--seed",
    "plot": "--plot",
}
"""The sweep's options (dest: flag). They default to None, not to their values, so that
``run`` can tell one given alongside ``--fit``, which has no use for it: the fit works
on the calibrated profile's exact expectation (no readings drawn, its own fixed seed for
its starting points) and plots nothing."""

_positive_int = int_at_least(1, "a positive integer")
MAX_READINGS = 100_000
"""Most readings per cell (our bound): 100 times the paper's 1000; its sweep peaks at
105 MB (``/usr/bin/time lunad sweep --readings 100000 --profile paper``), where 10^9
grew past 5 GB in 15 s."""


def _readings(text: str) -> int:
    """``--readings``: 1 to ``MAX_READINGS``."""
    value = _positive_int(text)
    if value > MAX_READINGS:
        raise argparse.ArgumentTypeError(f"at most {MAX_READINGS}, got {text!r}")
    return value


_seed = int_at_least(0, "a non-negative integer")
"""numpy.random.default_rng refuses a negative seed."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``sweep`` on the ``lunad`` command line."""
    p = subparsers.add_parser(
        "sweep",
        help="the paper's factorial sweep and its Table I side by side",
        description=(
            "Run the paper's full factorial sweep (lux 0-70,000, R 0.1-0.9, angle 0-85 deg,\n"
            "D_true = 2 m) and print Table I's rows with the paper's numbers and the model's.\n"
            "Profiles: 'paper' (equations 1-3, sigma in metres) and 'calibrated' (fitted to\n"
            "Table I; see docs/paper-model.md)."
        ),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--profile",
        choices=("paper", "calibrated", "both"),
        help="which profile(s) to run (default: both)",
    )
    p.add_argument(
        "--format",
        choices=("table", "json"),
        dest="fmt",
        help="output format (default: table)",
    )
    p.add_argument(
        "--readings",
        type=_readings,
        metavar="N",
        help="readings per cell (default: 1000, as in the paper)",
    )
    p.add_argument(
        "--seed",
        type=_seed,
        help="seed of the random generator (default: a fixed one, so that runs repeat)",
    )
    p.add_argument(
        "--fit",
        action="store_true",
        help="refit the calibrated profile to Table I and print its parameters"
        " (alone: no other option applies to it)",
    )
    p.add_argument(
        "--plot",
        type=Path,
        metavar="DIR",
        help="write Fig. 2, Fig. 3 and Table I R-row PNGs, paper and model on the same axes,"
        " into DIR (created if missing; needs matplotlib)",
    )
    p.set_defaults(func=run)


def _profiles(choice: str) -> list[Profile]:
    from lunad.sim.paper_model import CALIBRATED_DEFAULT, PAPER_METRES

    profiles: dict[str, list[Profile]] = {
        "paper": [PAPER_METRES],
        "calibrated": [CALIBRATED_DEFAULT],
        "both": [PAPER_METRES, CALIBRATED_DEFAULT],
    }
    return profiles[choice]


def _run_fit() -> int:
    from lunad.sim.fit import fit, format_claims, format_profile
    from lunad.sim.sweep import format_table

    result = fit()
    print(
        f"fit: objective {result.objective:.4g}, {result.evaluations} evaluations,"
        f" {result.seconds:.1f} s"
    )
    print(format_profile(result.profile))
    print("To make these the default, replace CALIBRATED_DEFAULT in sim/paper_model.py.\n")
    print("Table I from the fitted profile's exact expectation:")
    print(format_table(result.rows))
    print(format_claims(result.claims), end="")
    return 0


def _prepare_plot(out_dir: Path) -> int:
    """Check what ``--plot`` needs before the sweep runs; 0 or the exit code.

    A missing matplotlib is a missing support program (EX_UNAVAILABLE), a DIR that
    cannot be created a bad option (EX_CONFIG, as for ``lunad sim``'s output files).
    """
    from lunad.daemon.errors import EX_CONFIG, EX_UNAVAILABLE
    from lunad.sim.sweep import PLOT_INSTALL, require_matplotlib

    try:
        require_matplotlib()
    except ImportError as exc:
        print(
            f"lunad sweep: --plot needs matplotlib, which cannot be imported ({exc});"
            f" install it with {PLOT_INSTALL}",
            file=sys.stderr,
        )
        return EX_UNAVAILABLE
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"lunad sweep: --plot: cannot create {out_dir}: {exc}", file=sys.stderr)
        return EX_CONFIG
    return 0


def run(args: argparse.Namespace) -> int:
    """Run the sweep (or the fit); returns the process exit code.

    ``--fit`` with a sweep option is refused, as argparse refuses exclusive options:
    running the fit and dropping the option would hand back something other than
    what was asked for (no JSON, no plots) after seconds of work.
    """
    if args.fit:
        given = [flag for dest, flag in SWEEP_ONLY.items() if getattr(args, dest) is not None]
        if given:
            print(
                f"lunad sweep: error: argument --fit: not allowed with {', '.join(given)}"
                " (the fit refits the calibrated profile from its exact expectation;"
                " no other option applies to it)",
                file=sys.stderr,
            )
            return 2
        return _run_fit()
    if args.plot is not None and (code := _prepare_plot(args.plot)):
        return code
    from lunad.sim.sweep import DEFAULT_SEED, PAPER_GRID, format_json, format_table, run_sweep

    seed = DEFAULT_SEED if args.seed is None else args.seed
    readings = DEFAULT_READINGS if args.readings is None else args.readings
    profiles = _profiles(args.profile or DEFAULT_PROFILE)
    results: list[RowResult] = []
    for profile in profiles:
        results += run_sweep(profile, PAPER_GRID, readings, seed)
    if (args.fmt or DEFAULT_FORMAT) == "json":
        if len(profiles) == 1:
            objs = [r.to_json() for r in results]
            for o in objs:
                del o["profile"]
            import json

            print(json.dumps(objs, indent=2))
        else:
            print(format_json(results))
    else:
        print(format_table(results), end="")
    if args.plot is not None:
        from lunad.daemon.errors import EX_IOERR
        from lunad.sim.sweep import write_plots

        try:
            paths = write_plots(profiles, args.plot, readings, seed)
        except OSError as exc:
            print(f"lunad sweep: cannot write plots to {args.plot}: {exc}", file=sys.stderr)
            return EX_IOERR
        for path in paths:
            print(f"wrote {path}", file=sys.stderr)
    return 0
