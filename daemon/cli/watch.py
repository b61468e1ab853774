"""``lunad watch``: a live, readable view of a daemon's stream.

Three outputs: scrolling lines (a column header on a terminal), JSON lines carrying
their topic, and a full-screen view (``--refresh``, curses) built by ``render`` from a
``ScreenModel``. The model and ``render`` are pure (the caller passes the time), so a
test checks the screen's text without a terminal; ``_screen`` only feeds the model
and draws, on every message (at most ``REDRAW_MIN_GAP_S`` apart) and on a timer, so
ages and a silent daemon show even when nothing arrives.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import statistics
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from lunad.daemon.cli.arg_types import int_at_least, positive_float, sensor_name
from lunad.daemon.cli.signals import Interrupts
from lunad.daemon.errors import EXIT_USAGE

if TYPE_CHECKING:
    from lunad.protocol.client import Subscriber
    from lunad.protocol.messages import HealthMessage, RangeMessage

DESCRIPTION = """\
Subscribe to a lunad daemon and show its stream. Reports messages lost on the way
(gaps in seq) when it stops: Ctrl-C, SIGTERM (exit 0 for either), --count or
--duration.

Lines (the default): one per reading (or every Nth) and one per health message. On a
terminal a header names the columns at the start and every 20 lines; piped or
redirected, the lines come alone.

--refresh: a full-screen view that fits 80 columns and 24 rows: the latest reading
(range, sigma, status, reasons, zone, lux), its age once none came for 0.5 s, the
daemon's health state exactly as its last health message says, or "no health for
N s" once none came for 2.5 health intervals ("stopped", the daemon's last word,
stays), and a sparkline of the last 60
readings (blank: no range). It redraws as messages come (at most 25 times a
second) and 10 times a second when none do; it follows the window's size. q or
Ctrl-C quits.

--json: one JSON object per line, the message as published with its ZeroMQ topic
added as a first key, e.g. {"topic":"range/front/","v":2,"sensor":"front",...};
drop "topic" to get the message as docs/messages.md defines it.
"""

EPILOG = """\
examples:
  lunad watch --connect tcp://127.0.0.1:7781
  lunad watch --connect ipc:///run/lunad/front.sock --every 25
  lunad watch --connect tcp://127.0.0.1:7781 --refresh
  lunad watch --connect tcp://127.0.0.1:7781 --json --count 100 > readings.jsonl
  # a CURVE endpoint
  lunad watch --connect tcp://192.168.1.10:7781 --curve-server-key ~/keys/server.key \\
              --curve-client-key ~/keys/robot1.key_secret
"""

NOTHING_YET_AFTER_S = 5.0
"""ZeroMQ connects in the background and says nothing when it cannot: after this long
with no message, say what to check."""
NOTHING_YET = (
    "lunad watch: nothing from %s yet; is the daemon running and publishing there"
    " (--publish, [publish] endpoint), and for an ipc:// socket may you read it (group lunad)?"
)
NOTHING_YET_PLAIN = (
    " Is it a CURVE endpoint (--curve-server-key and --curve-client-key)? Does it serve"
    " its 64 subscribers already (its log says 'shut ... connection(s) at once')?"
)
NOTHING_YET_SENSOR = (
    " Does the daemon call its sensor %r ([sensor] name, --name)? --sensor takes the exact name."
)
UNDECODED = (
    "lunad watch: %d message(s) from %s did not decode and were skipped: they are not"
    " lunad's message contract (docs/messages.md); is it lunad, and of this version?"
)
NOTHING_YET_CURVE = (
    " Is this client's public key in the daemon's curve_clients? It refuses a key it does"
    " not list without a word to the client (its log says 'CURVE: refused')."
)

HEADER_EVERY_LINES = 20
"""Lines between column headers on a terminal: one stays in view on a 24-row screen."""

REDRAW_EVERY_S = 0.1
"""The full screen's timer (10 Hz): ages and a silent daemon show with nothing arriving."""
REDRAW_MIN_GAP_S = 0.04
"""At most 25 redraws a second on messages: a 250 Hz stream redrawn per message would
cost the Pi the daemon runs on CPU for frames no eye can follow."""
HISTORY_READINGS = 60
"""Readings in the sparkline: 0.6 s at 100 Hz, and it fits 80 columns with its label."""
SPARK_MIN_SPAN_M = 0.10
"""The sparkline's smallest height span, metres: a still target's centimetre noise
would otherwise fill all eight levels and look like motion."""
RANGE_QUIET_S = 0.5
"""No reading for this long and the screen says how long: the daemon's own stale
limit (``stale_after_s``, 0.5 s by default, docs/messages.md)."""
HEALTH_INTERVAL_DEFAULT_S = 1.0
"""The health interval assumed until two health messages came (docs/messages.md:
about once a second; ``[publish] health_interval_s``)."""
HEALTH_LATE_INTERVALS = 2.5
"""Health intervals without a health message after which its state is no longer shown:
two missed messages, with half an interval for the network and a busy host."""
HEALTH_GAPS_KEPT = 8
"""Health arrival gaps the interval is the median of: extra messages at state changes
make short gaps, which the median outvotes."""


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
    p.add_argument("--sensor", type=sensor_name, help="only this sensor's messages")
    p.add_argument(
        "--curve-server-key",
        metavar="FILE",
        help="a CURVE endpoint: the daemon's public key file (server.key), with --curve-client-key",
    )
    p.add_argument(
        "--curve-client-key",
        metavar="FILE",
        help="a CURVE endpoint: this client's secret key file (NAME.key_secret, made by"
        " lunad keys client), whose public key the daemon lists",
    )
    p.add_argument(
        "--every",
        type=int_at_least(1),
        default=1,
        metavar="N",
        help="print every Nth reading (with --json too; health messages all)",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--refresh",
        "--screen",
        dest="refresh",
        action="store_true",
        help="full-screen view on a terminal (curses), redrawn in place",
    )
    mode.add_argument(
        "--json", action="store_true", help='JSON lines, each with a "topic" key first'
    )
    p.add_argument("--count", type=int_at_least(1), metavar="N", help="stop after N readings")
    p.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=run)


def _at_columns(*names: tuple[int, str]) -> str:
    """A line with each name starting at its column."""
    line = ""
    for column, name in names:
        line = line.ljust(column) + name
    return line


RANGE_HEADER = _at_columns(
    (0, "seq"),
    (9, "filtered range ± 1 sigma"),
    (35, "sensor's reading"),
    (59, "strength"),
    (68, "light"),
    (81, "status"),
    (90, "zone"),
    (101, "why not ok"),
)
"""Column names over ``format_range``'s fields, each at its field's first column."""


def format_range(msg: RangeMessage) -> str:
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


def format_health(msg: HealthMessage) -> str:
    """One line for a health message."""
    fw = msg.firmware or "?"
    err = f"  last error: {msg.last_error}" if msg.last_error else ""
    return (
        f"[health] {msg.state:12s} {msg.fps:6.1f} fps  frames {msg.frames}  "
        f"checksum errors {msg.checksum_errors}  discarded {msg.bytes_discarded} B  "
        f"dropout {msg.dropout_ratio:.1%}  dropped sends {msg.dropped_sends}  "
        f"fw {fw}  up {msg.uptime_s:.0f} s{err}"
    )


def format_json(msg: RangeMessage | HealthMessage) -> str:
    """A message as one JSON line with its topic as the first key, ``"topic"``."""
    from lunad.protocol.messages import topic

    name = json.dumps(topic(msg.kind, msg.sensor).decode())
    return '{"topic":' + name + "," + msg.model_dump_json()[1:]


class EndpointError(ValueError):
    """``--connect`` names no endpoint a SUB socket can connect to; the message says why."""


CurveKeys = tuple[str, str]
"""(the daemon's public key file, this client's secret key file), for a CURVE endpoint."""


def _subscribe(endpoint: str, sensor: str | None, curve: CurveKeys | None = None) -> Subscriber:
    """A connected ``Subscriber``.

    Raises:
        EndpointError: ``endpoint`` is not one to connect to, or ``curve``'s key files
            are not usable; libzmq's own error is a traceback that names neither the flag
            nor the endpoint's expected form.
    """
    import zmq

    from lunad.daemon.config import tcp_port_problem
    from lunad.protocol.client import Subscriber

    problem = tcp_port_problem(endpoint)  # the rest, libzmq refuses at connect
    if problem is None:
        try:
            if curve is None:
                return Subscriber(endpoint, sensor=sensor)
            return Subscriber(
                endpoint, sensor=sensor, curve_server_key=curve[0], curve_client_key=curve[1]
            )
        except zmq.ZMQError as exc:
            problem = str(exc) if exc.errno is None else zmq.strerror(exc.errno)
        except ValueError as exc:  # a key file the client cannot use: it says which
            raise EndpointError(f"--curve-server-key/--curve-client-key: {exc}") from None
    raise EndpointError(
        f"--connect {endpoint!r}: {problem}; expected tcp://HOST:PORT or ipc:///PATH"
    )


@dataclass(frozen=True, slots=True)
class WatchResult:
    """What a watch saw: readings received, readings lost (seq gaps), the last seq, and
    messages that did not decode (``Subscriber.bad_messages``: skipped)."""

    readings: int
    lost: int
    last_seq: int | None
    undecoded: int = 0


def watch(
    endpoint: str,
    out: TextIO,
    sensor: str | None = None,
    every: int = 1,
    as_json: bool = False,
    count: int | None = None,
    duration: float | None = None,
    header: bool = False,
    curve: CurveKeys | None = None,
) -> WatchResult:
    """Print the stream as lines until ``count`` readings or ``duration`` seconds.

    Every ``every``-th reading is printed, as a line or, with ``as_json``, as its JSON
    message with its topic; health messages are all printed, being rare. ``count``
    counts readings received, printed or not. With ``header`` (a person at a terminal)
    the column names come first and every ``HEADER_EVERY_LINES`` lines.

    Raises:
        EndpointError: ``endpoint`` is not one to connect to.
    """
    from lunad.protocol.messages import RangeMessage

    readings = 0
    deadline = None if duration is None else time.monotonic() + duration
    heard = False
    hint_at = time.monotonic() + NOTHING_YET_AFTER_S
    lines = 0
    with _subscribe(endpoint, sensor, curve) as sub:
        try:
            while count is None or readings < count:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    break
                msg = sub.recv(timeout_s=0.5 if left is None else min(0.5, left))
                if msg is None:
                    if not heard and time.monotonic() >= hint_at:
                        hint_at = math.inf
                        if sub.bad_messages:
                            print(UNDECODED % (sub.bad_messages, endpoint), file=sys.stderr)
                        else:
                            more = NOTHING_YET_PLAIN if curve is None else NOTHING_YET_CURVE
                            if sensor is not None:
                                more += NOTHING_YET_SENSOR % sensor
                            print(NOTHING_YET % endpoint + more, file=sys.stderr)
                    continue
                heard = True
                if isinstance(msg, RangeMessage):
                    readings += 1
                    if readings % every:
                        continue
                if as_json:
                    text = format_json(msg)
                else:
                    if header and lines % HEADER_EVERY_LINES == 0:
                        out.write(RANGE_HEADER + "\n")
                    lines += 1
                    if isinstance(msg, RangeMessage):
                        text = format_range(msg)
                    else:
                        text = format_health(msg)
                out.write(text + "\n")
                out.flush()
        except KeyboardInterrupt:
            pass  # Ctrl-C is the usual stop: the summary still counts what came
        return WatchResult(readings, sub.lost, sub.last_seq, sub.bad_messages)


@dataclass
class ScreenModel:
    """What the full screen shows, fed message by message; times are ``time.monotonic``
    seconds, passed in by the caller.

    Attributes:
        endpoint: where the messages come from, for the title.
        started: when watching began.
        reading: the latest range message, and ``reading_at`` when it came.
        history: the last ``HISTORY_READINGS`` filtered ranges, metres; None for a
            reading without one (a dropout).
        health: the latest health message, and ``health_at`` when it came.
        readings: range messages received; lost: frames missed (``Subscriber.lost``);
            undecoded: messages skipped, not lunad's contract (``Subscriber.bad_messages``).
        sensors: every sensor name seen, to notice a mixed stream without ``--sensor``.
    """

    endpoint: str
    started: float
    reading: RangeMessage | None = None
    reading_at: float = 0.0
    history: deque[float | None] = field(default_factory=lambda: deque(maxlen=HISTORY_READINGS))
    health: HealthMessage | None = None
    health_at: float = 0.0
    health_gaps: deque[float] = field(default_factory=lambda: deque(maxlen=HEALTH_GAPS_KEPT))
    readings: int = 0
    lost: int = 0
    undecoded: int = 0
    sensors: set[str] = field(default_factory=set)

    def add(self, msg: RangeMessage | HealthMessage, now: float) -> None:
        """Take a message that came at ``now``."""
        from lunad.protocol.messages import RangeMessage

        self.sensors.add(msg.sensor)
        if isinstance(msg, RangeMessage):
            self.reading, self.reading_at = msg, now
            self.history.append(msg.range_m)
            self.readings += 1
        else:
            if self.health is not None:
                self.health_gaps.append(now - self.health_at)
            self.health, self.health_at = msg, now

    @property
    def health_interval_s(self) -> float:
        """How often health messages come, seconds: the median of the recent gaps."""
        if not self.health_gaps:
            return HEALTH_INTERVAL_DEFAULT_S
        return statistics.median(self.health_gaps)


@dataclass(frozen=True, slots=True)
class Glyphs:
    """The characters the screen draws with: Unicode, or ASCII for a terminal whose
    encoding lacks the block characters."""

    levels: str
    plus_minus: str
    degrees: str


UNICODE_GLYPHS = Glyphs("▁▂▃▄▅▆▇█", "±", "°C")
ASCII_GLYPHS = Glyphs("_.-:=+*#", "+-", "C")

LABEL_WIDTH = 11
"""Columns of a screen row's label ("range", "health", ...) with its gap."""


def sparkline(values: deque[float | None] | list[float | None], glyphs: Glyphs) -> str:
    """One character per value from the lowest level to the highest; blank for None.

    Scaled from the smallest value over at least ``SPARK_MIN_SPAN_M``.
    """
    known = [v for v in values if v is not None]
    if not known:
        return " " * len(values)
    low = min(known)
    span = max(max(known) - low, SPARK_MIN_SPAN_M)
    top = len(glyphs.levels) - 1
    return "".join(
        " " if v is None else glyphs.levels[min(top, int((v - low) / span * (top + 1)))]
        for v in values
    )


def _ago(seconds: float) -> str:
    """A duration to the precision a person reads it at: 0.4 s, 12 s, 5 min."""
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 600:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min"


def _row(label: str, text: str) -> str:
    return f"{label:<{LABEL_WIDTH}}{text}".rstrip()


def render(
    model: ScreenModel, now: float, width: int = 80, glyphs: Glyphs = UNICODE_GLYPHS
) -> list[str]:
    """The screen's rows as text, none longer than ``width - 1`` columns (curses cannot
    write a screen's bottom-right cell; one column less everywhere keeps rows alike).

    At 80 columns every row fits uncut; narrower, the sparkline shrinks and the rest is
    cut at the edge. 16 rows: it fits 24 with room to spare.
    """
    limit = max(1, width - 1)
    rows: list[str] = []
    sensor = ""  # before the endpoint, which a narrow screen cuts
    if len(model.sensors) > 1:
        sensor = f"sensors {','.join(sorted(model.sensors))} (--sensor picks one)  "
    elif model.sensors:
        sensor = f"sensor {next(iter(model.sensors))}  "
    rows.append(f"lunad watch  {sensor}{model.endpoint}")
    rows.append("")
    rows += _reading_rows(model, now, glyphs)
    rows.append("")
    rows += _health_rows(model, now)
    rows.append("")
    spark_width = max(0, min(HISTORY_READINGS, limit - LABEL_WIDTH))
    recent = list(model.history)[-spark_width:] if spark_width else []
    known = [v for v in recent if v is not None]
    if known:
        scale = f"last {len(recent)} readings, {min(known):.3f} .. {max(known):.3f} m"
        scale += "; blank: no range" if len(known) < len(recent) else ""
    else:
        scale = "no range yet" if not recent else f"last {len(recent)} readings: no range"
    rows.append(_row("history", scale))
    rows.append(_row("", sparkline(recent, glyphs)))
    rows.append("")
    undecoded = f", {model.undecoded} that did not decode" if model.undecoded else ""
    rows.append(f"{model.readings} readings, {model.lost} lost (seq gaps){undecoded}   q quits")
    return [row[:limit] for row in rows]


def _reading_rows(model: ScreenModel, now: float, glyphs: Glyphs) -> list[str]:
    """Range, reasons, raw reading, light, and how long ago it came once that is long."""
    msg = model.reading
    if msg is None:
        waited = now - model.started
        quiet = f"none yet ({_ago(waited)})"
        if waited >= NOTHING_YET_AFTER_S and model.health is None:
            quiet += ": is the daemon publishing here? (--publish; ipc: group lunad)"
        return [_row("range", quiet), "", "", "", ""]
    if msg.range_m is not None and msg.sigma_m is not None:
        value = f"{msg.range_m:.3f} m {glyphs.plus_minus} {msg.sigma_m * 100:.1f} cm"
    else:
        value = "- m"
    lux = f"{msg.lux_est:.0f} lux" if msg.lux_est is not None else "- (not seen in the noise)"
    raw = f"{msg.raw_m:.2f} m" if msg.raw_m is not None else "- m"
    age = now - model.reading_at
    quiet = (
        f"no reading for {_ago(age)}: the values above are the last" if age >= RANGE_QUIET_S else ""
    )
    return [
        _row("range", f"{value:<24}{msg.status:<10}zone {msg.zone}"),
        _row("reasons", ", ".join(msg.reasons) or "-"),
        _row(
            "raw",
            f"{raw}   amp {msg.amp:5d}   S {msg.strength:4.2f}   "
            f"{msg.temp_c:.1f} {glyphs.degrees}   seq {msg.seq}",
        ),
        _row("light", lux),
        _row("", quiet),
    ]


def _health_rows(model: ScreenModel, now: float) -> list[str]:
    """The daemon's state as its last health message gave it, while that is recent."""
    msg = model.health
    if msg is None:
        return [_row("health", f"none yet ({_ago(now - model.started)})"), "", "", ""]
    age = now - model.health_at
    if msg.state == "stopped":  # the daemon's last message: it stays true
        return [_row("health", f"stopped {_ago(age)} ago (the daemon's last message)"), "", "", ""]
    if age > HEALTH_LATE_INTERVALS * model.health_interval_s:
        return [_row("health", f"no health for {_ago(age)}"), "", "", ""]
    error = f"last error: {msg.last_error}" if msg.last_error else ""
    return [
        _row("health", f"{msg.state:<14}{msg.fps:.1f} fps   dropout {msg.dropout_ratio:.1%}"),
        _row(
            "",
            f"frames {msg.frames}   checksum errors {msg.checksum_errors}   "
            f"discarded {msg.bytes_discarded} B",
        ),
        _row(
            "",
            f"dropped sends {msg.dropped_sends}   fw {msg.firmware or '?'}   "
            f"up {_ago(msg.uptime_s)}",
        ),
        _row("", error),
    ]


class TerminalError(RuntimeError):
    """The full screen cannot run here (no terminal, or one curses does not know)."""


def screen(
    endpoint: str,
    sensor: str | None = None,
    count: int | None = None,
    duration: float | None = None,
    curve: CurveKeys | None = None,
) -> WatchResult:
    """The full-screen view until q, Ctrl-C, ``count`` readings or ``duration`` seconds.

    Raises:
        EndpointError: ``endpoint`` is not one to connect to.
        TerminalError: stdout is not a terminal curses can drive.
    """
    import curses

    if not sys.stdout.isatty() or not sys.stdin.isatty():
        raise TerminalError("--refresh needs a terminal; without one, leave it out")
    with _subscribe(endpoint, sensor, curve) as sub:
        model = ScreenModel(endpoint, time.monotonic())
        try:
            curses.wrapper(_screen, sub, model, count, duration)
        except curses.error as exc:
            raise TerminalError(f"--refresh: cannot drive this terminal: {exc}") from exc
        except KeyboardInterrupt:
            pass  # Ctrl-C is the usual stop; curses.wrapper restored the terminal
        return WatchResult(model.readings, sub.lost, sub.last_seq, sub.bad_messages)


def _screen(
    stdscr: Any,
    sub: Subscriber,
    model: ScreenModel,
    count: int | None,
    duration: float | None,
) -> None:
    """Feed ``model`` from ``sub`` and draw it, inside ``curses.wrapper``."""
    import curses

    if curses.tigetstr("cup") is None:  # TERM=dumb, say: the screen would be smeared
        raise TerminalError("--refresh: this terminal cannot place the cursor (TERM=dumb?)")
    try:
        curses.curs_set(0)
    except curses.error:
        pass  # a terminal without an invisible cursor: it shows, nothing else changes
    stdscr.nodelay(True)
    try:
        UNICODE_GLYPHS.levels.encode(stdscr.encoding)
        glyphs = UNICODE_GLYPHS
    except (UnicodeEncodeError, LookupError):
        glyphs = ASCII_GLYPHS
    deadline = math.inf if duration is None else model.started + duration
    drawn_at = -math.inf
    news = True  # a message since the last draw: redraw after the short gap, not the timer
    while count is None or model.readings < count:
        now = time.monotonic()
        if now >= deadline:
            break
        if now - drawn_at >= (REDRAW_MIN_GAP_S if news else REDRAW_EVERY_S):
            key = stdscr.getch()
            if key in (ord("q"), ord("Q")):
                break
            if key == curses.KEY_RESIZE:
                curses.update_lines_cols()
                stdscr.clear()
            _draw(stdscr, render(model, now, stdscr.getmaxyx()[1], glyphs))
            drawn_at, news = now, False
        due = drawn_at + (REDRAW_MIN_GAP_S if news else REDRAW_EVERY_S)
        msg = sub.recv(timeout_s=max(0.0, min(due, deadline) - time.monotonic()))
        model.undecoded = sub.bad_messages
        if msg is not None:
            model.add(msg, time.monotonic())
            model.lost = sub.lost
            news = True
            if msg.kind == "health":
                drawn_at = -math.inf  # a state change shows at once


def _draw(stdscr: Any, rows: list[str]) -> None:
    """Put ``rows`` on the screen from the top, each cleared to its end."""
    import curses

    height = stdscr.getmaxyx()[0]
    for y, text in enumerate(rows[:height]):
        try:
            stdscr.addstr(y, 0, text)
            stdscr.clrtoeol()
        except curses.error:
            pass  # a screen resized smaller under us: the next draw fits it
    stdscr.clrtobot()
    stdscr.refresh()


def run(args: argparse.Namespace) -> int:
    """Watch until Ctrl-C, ``--count`` or ``--duration`` (or q on the full screen)."""
    keys = (args.curve_server_key, args.curve_client_key)
    if (keys[0] is None) != (keys[1] is None):
        print(
            "lunad watch: --curve-server-key and --curve-client-key go together",
            file=sys.stderr,
        )
        return EXIT_USAGE
    curve = None if keys[0] is None or keys[1] is None else (keys[0], keys[1])
    # The imports first, while a stop is only noted (``startup_signals``): a
    # KeyboardInterrupt inside them (in a string ``exec`` that dataclasses and pydantic
    # run) has CPython end the process by SIGINT at exit, though it was caught.
    import lunad.daemon.config
    import lunad.protocol.client  # noqa: F401

    # as Ctrl-C: `timeout` or a supervisor gets the summary too; the second one is ignored
    Interrupts(signal.SIGTERM, signal.SIGINT)
    startup = getattr(args, "startup_signals", None)
    if startup is not None and startup.stopped("lunad watch"):
        return 0
    try:
        if args.refresh:
            result = screen(args.connect, args.sensor, args.count, args.duration, curve)
        else:
            result = watch(
                args.connect,
                sys.stdout,
                args.sensor,
                args.every,
                args.json,
                args.count,
                args.duration,
                header=not args.json and sys.stdout.isatty(),
                curve=curve,
            )
    except (EndpointError, TerminalError) as exc:
        print(f"lunad watch: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 0
    undecoded = f", {result.undecoded} that did not decode" if result.undecoded else ""
    print(f"{result.readings} readings, {result.lost} lost (seq gaps){undecoded}", file=sys.stderr)
    return 0
