"""``lunad watch``: a live, readable view of a daemon's stream."""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from lunad.protocol.client import Subscriber

DESCRIPTION = """\
Subscribe to a lunad daemon and print its stream: one line per reading (or every
Nth), health lines as they come, or one refreshing status line. Reports messages
lost on the way (gaps in seq) when it stops.
"""

EPILOG = """\
examples:
  lunad watch --connect tcp://127.0.0.1:7781
  lunad watch --connect ipc:///run/lunad/front.sock --every 25
  lunad watch --connect tcp://127.0.0.1:7781 --refresh
  lunad watch --connect tcp://127.0.0.1:7781 --json --count 100 > readings.jsonl
"""

NOTHING_YET_AFTER_S = 5.0
"""ZeroMQ connects in the background and says nothing when it cannot: after this long
with no message, say what to check."""
NOTHING_YET = (
    "lunad watch: nothing from %s yet; is the daemon running and publishing there"
    " (--publish, [publish] endpoint), and for an ipc:// socket may you read it (group lunad)?"
)


def add_parser(sub: Any) -> None:
    """Register ``watch``."""
    p = sub.add_parser(
        "watch",
        help="live view of a daemon's stream",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--connect",
        metavar="ENDPOINT",
        default="tcp://127.0.0.1:7781",
        help="where the daemon publishes (default tcp://127.0.0.1:7781)",
    )
    p.add_argument("--sensor", help="only this sensor's messages")
    p.add_argument(
        "--every",
        type=int,
        default=1,
        metavar="N",
        help="print every Nth reading (with --json too; health messages all)",
    )
    p.add_argument("--refresh", action="store_true", help="one refreshing status line")
    p.add_argument("--json", action="store_true", help="print the raw JSON messages")
    p.add_argument("--count", type=int, metavar="N", help="stop after N readings")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=run)


def format_range(msg: Any) -> str:
    """One line for a range message."""
    rng = f"{msg.range_m:7.3f} m" if msg.range_m is not None else "      - m"
    sig = f"±{msg.sigma_m * 100:4.1f} cm" if msg.sigma_m is not None else "        "
    raw = f"{msg.raw_m:5.2f}" if msg.raw_m is not None else "    -"
    lux = f"{msg.lux_est:7.0f}" if msg.lux_est is not None else "      -"
    reasons = ",".join(msg.reasons)
    return (
        f"#{msg.seq:<7d} range {rng} {sig}  raw {raw} m  amp {msg.amp:5d}  "
        f"S {msg.strength:5.2f}  lux {lux}  {msg.status:8s} {msg.zone:10s} {reasons}"
    )


def format_health(msg: Any) -> str:
    """One line for a health message."""
    fw = msg.firmware or "?"
    err = f"  last error: {msg.last_error}" if msg.last_error else ""
    return (
        f"[health] {msg.state:12s} {msg.fps:6.1f} fps  frames {msg.frames}  "
        f"checksum errors {msg.checksum_errors}  discarded {msg.bytes_discarded} B  "
        f"dropout {msg.dropout_ratio:.1%}  dropped sends {msg.dropped_sends}  "
        f"fw {fw}  up {msg.uptime_s:.0f} s{err}"
    )


USAGE_ERROR = 2
"""Exit code for a bad flag, the one argparse gives for the flags it checks itself."""


class EndpointError(ValueError):
    """``--connect`` names no endpoint a SUB socket can connect to; the message says why."""


def _subscribe(endpoint: str, sensor: str | None) -> Subscriber:
    """A connected ``Subscriber``.

    Raises:
        EndpointError: ``endpoint`` is not one to connect to; libzmq's own error is a
            traceback that names neither the flag nor the endpoint's expected form.
    """
    import zmq

    from lunad.daemon.config import tcp_port_problem
    from lunad.protocol.client import Subscriber

    problem = tcp_port_problem(endpoint)  # the rest, libzmq refuses at connect
    if problem is None:
        try:
            return Subscriber(endpoint, sensor=sensor)
        except zmq.ZMQError as exc:
            problem = str(exc) if exc.errno is None else zmq.strerror(exc.errno)
    raise EndpointError(
        f"--connect {endpoint!r}: {problem}; expected tcp://HOST:PORT or ipc:///PATH"
    )


@dataclass(frozen=True, slots=True)
class WatchResult:
    """What a watch saw: readings received, readings lost (seq gaps), the last seq."""

    readings: int
    lost: int
    last_seq: int | None


def watch(
    endpoint: str,
    out: TextIO,
    sensor: str | None = None,
    every: int = 1,
    refresh: bool = False,
    as_json: bool = False,
    count: int | None = None,
    duration: float | None = None,
) -> WatchResult:
    """Print the stream until ``count`` readings or ``duration`` seconds.

    Every ``every``-th reading is printed, as a line or, with ``as_json``, as its JSON
    message; health messages are all printed, being rare. ``count`` counts readings
    received, printed or not.

    Raises:
        EndpointError: ``endpoint`` is not one to connect to.
    """
    from lunad.protocol.messages import RangeMessage

    readings = 0
    deadline = None if duration is None else time.monotonic() + duration
    heard = False
    hint_at = time.monotonic() + NOTHING_YET_AFTER_S
    last_health = ""
    with _subscribe(endpoint, sensor) as sub:
        try:
            while count is None or readings < count:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    break
                msg = sub.recv(timeout_s=0.5 if left is None else min(0.5, left))
                if msg is None:
                    if not heard and time.monotonic() >= hint_at:
                        hint_at = math.inf
                        print(NOTHING_YET % endpoint, file=sys.stderr)
                    continue
                heard = True
                if as_json:
                    if isinstance(msg, RangeMessage):
                        readings += 1
                        if readings % every:
                            continue
                    out.write(msg.model_dump_json() + "\n")
                    continue
                if isinstance(msg, RangeMessage):
                    readings += 1
                    if refresh:
                        out.write("\r" + format_range(msg)[:150] + "  " + last_health + "\x1b[K")
                        out.flush()
                    elif readings % every == 0:
                        out.write(format_range(msg) + "\n")
                else:
                    last_health = f"[{msg.state} {msg.fps:.0f} fps]"
                    if not refresh:
                        out.write(format_health(msg) + "\n")
                if not refresh:
                    out.flush()
        except KeyboardInterrupt:
            pass  # Ctrl-C is the usual stop: the summary still counts what came
        result = WatchResult(readings, sub.lost, sub.last_seq)
    if refresh:
        out.write("\n")
    return result


def run(args: argparse.Namespace) -> int:
    """Watch until Ctrl-C, ``--count`` or ``--duration``."""
    if args.every < 1:
        print("lunad watch: --every must be at least 1", file=sys.stderr)
        return USAGE_ERROR
    try:
        result = watch(
            args.connect,
            sys.stdout,
            args.sensor,
            args.every,
            args.refresh,
            args.json,
            args.count,
            args.duration,
        )
    except EndpointError as exc:
        print(f"lunad watch: {exc}", file=sys.stderr)
        return USAGE_ERROR
    except KeyboardInterrupt:
        return 0
    print(f"{result.readings} readings, {result.lost} lost (seq gaps)", file=sys.stderr)
    return 0
