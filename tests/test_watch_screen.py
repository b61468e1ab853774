"""``lunad watch`` on a real pseudo-terminal against a real ZeroMQ publisher: the full
screen (``--refresh``) read back through a small terminal emulator, the scrolling
lines' header, and the topic on ``--json`` lines; ``render`` on its own for the layout.
"""

from __future__ import annotations

import codecs
import fcntl
import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zmq

from lunad.daemon.cli.watch import (
    ASCII_GLYPHS,
    HISTORY_READINGS,
    RANGE_HEADER,
    ScreenModel,
    format_range,
    render,
    sparkline,
)
from lunad.protocol.messages import (
    HealthMessage,
    RangeMessage,
    State,
    encode_health,
    encode_range,
    range_ident,
    reasons_json,
    topic,
)

LUNAD = [sys.executable, "-m", "lunad.daemon.cli"]
SENSOR = "front"
RUN = "3f9c2a7be01d4c55"
STARTUP_S = 30.0
"""The watcher's first screen: Python, pyzmq and pydantic start in about a second here;
a loaded machine has taken ten times that for the daemon (conftest.STARTUP_S)."""
BLOCKS = "▁▂▃▄▅▆▇█"


# --- a terminal, as far as ncurses drives an xterm ----------------------------------

_CSI = re.compile(r"\x1b\[([?>=!]?)([0-9;]*)[ -/]*([@-~])")
_ESC_CHARSET = re.compile(r"\x1b[()*+].")
_ESC_ONE = re.compile(r"\x1b([^\[()*+\]])")
_OSC = re.compile(r"\x1b\].*?(?:\x07|\x1b\\)", re.S)
_PARTIAL = re.compile(r"\x1b(?:\[[?>=!]?[0-9;]*[ -/]*|[()*+]|\].*)?\Z", re.S)


class Terminal:
    """A grid of characters that ncurses output for TERM=xterm is played onto.

    Handles what ncurses sends that xterm's terminfo entry offers: cursor addressing
    and movement, erasing, inserting and deleting characters and lines, scroll regions,
    ``rep`` and the alternate screen. Attributes, colours and modes are ignored: the
    test reads text.
    """

    def __init__(self, cols: int, rows: int) -> None:
        self._decode = codecs.getincrementaldecoder("utf-8")("replace").decode
        self._pending = ""
        self.resize(cols, rows)

    def resize(self, cols: int, rows: int) -> None:
        """A new, blank grid, as a window resized by hand shows until redrawn."""
        self.cols, self.rows = cols, rows
        self.grid = [[" "] * cols for _ in range(rows)]
        self.x = self.y = 0
        self.top, self.bottom = 0, rows - 1
        self.saved = (0, 0)
        self.last = " "
        self.wrap_next = False

    def lines(self) -> list[str]:
        return ["".join(row).rstrip() for row in self.grid]

    def text(self) -> str:
        return "\n".join(self.lines())

    def feed(self, data: bytes) -> None:
        s = self._pending + self._decode(data)
        self._pending = ""
        i = 0
        while i < len(s):
            c = s[i]
            if c == "\x1b":
                for pattern, handle in (
                    (_CSI, self._csi),
                    (_OSC, None),
                    (_ESC_CHARSET, None),
                    (_ESC_ONE, self._esc),
                ):
                    m = pattern.match(s, i)
                    if m:
                        if handle is not None:
                            handle(m)
                        i = m.end()
                        break
                else:
                    if _PARTIAL.match(s, i):
                        self._pending = s[i:]
                        return
                    i += 1  # an escape this terminal does not know: dropped
                continue
            self._char(c)
            i += 1

    # characters and controls

    def _char(self, c: str) -> None:
        if c == "\r":
            self._move(0, self.y)
        elif c in "\n\x0b\x0c":
            self._index()
        elif c == "\b":
            self._move(self.x - 1, self.y)
        elif c == "\t":
            self._move((self.x // 8 + 1) * 8, self.y)
        elif c >= " ":
            self._put(c)

    def _put(self, c: str) -> None:
        if self.wrap_next:
            self.x = 0
            self._index()
        self.grid[self.y][self.x] = c
        self.last = c
        if self.x == self.cols - 1:
            self.wrap_next = True  # xterm's pending wrap (xenl)
        else:
            self.x += 1

    def _move(self, x: int, y: int) -> None:
        self.x = min(max(x, 0), self.cols - 1)
        self.y = min(max(y, 0), self.rows - 1)
        self.wrap_next = False

    def _index(self) -> None:
        self.wrap_next = False
        if self.y == self.bottom:
            self._scroll(1)
        else:
            self._move(self.x, self.y + 1)

    def _scroll(self, n: int, at: int | None = None) -> None:
        """Lines ``at``..bottom move up ``n`` (down for a negative ``n``)."""
        top = self.top if at is None else at
        region = self.grid[top : self.bottom + 1]
        blank = [[" "] * self.cols for _ in range(min(abs(n), len(region)))]
        region = region[n:] + blank if n > 0 else blank + region[: len(region) + n]
        self.grid[top : self.bottom + 1] = region

    def _esc(self, m: re.Match[str]) -> None:
        c = m.group(1)
        if c == "7":
            self.saved = (self.x, self.y)
        elif c == "8":
            self._move(*self.saved)
        elif c == "M":
            if self.y == self.top:
                self._scroll(-1)
            else:
                self._move(self.x, self.y - 1)
        elif c in "DE":
            self._index()
            if c == "E":
                self._move(0, self.y)
        elif c == "c":
            self.resize(self.cols, self.rows)

    def _csi(self, m: re.Match[str]) -> None:
        private, raw, final = m.groups()
        params = [int(p) if p else 0 for p in raw.split(";")] if raw else []
        n = max(params[0], 1) if params else 1
        row = self.grid[self.y]
        if private:
            if private == "?" and 1049 in params and final == "h":
                self.resize(self.cols, self.rows)  # the alternate screen starts blank
            return
        if final in "Hf":
            y = params[0] if params else 1
            x = params[1] if len(params) > 1 else 1
            self._move(max(x, 1) - 1, max(y, 1) - 1)
        elif final == "A":
            self._move(self.x, self.y - n)
        elif final in "Be":
            self._move(self.x, self.y + n)
        elif final in "Ca":
            self._move(self.x + n, self.y)
        elif final == "D":
            self._move(self.x - n, self.y)
        elif final in "G`":
            self._move(n - 1, self.y)
        elif final == "d":
            self._move(self.x, n - 1)
        elif final == "K":
            mode = params[0] if params else 0
            lo, hi = {0: (self.x, self.cols), 1: (0, self.x + 1)}.get(mode, (0, self.cols))
            row[lo:hi] = [" "] * (hi - lo)
        elif final == "J":
            mode = params[0] if params else 0
            if mode == 0:
                row[self.x :] = [" "] * (self.cols - self.x)
                for r in self.grid[self.y + 1 :]:
                    r[:] = [" "] * self.cols
            elif mode == 1:
                row[: self.x + 1] = [" "] * (self.x + 1)
                for r in self.grid[: self.y]:
                    r[:] = [" "] * self.cols
            else:
                for r in self.grid:
                    r[:] = [" "] * self.cols
        elif final == "X":
            hi = min(self.cols, self.x + n)
            row[self.x : hi] = [" "] * (hi - self.x)
        elif final == "P":
            del row[self.x : self.x + n]
            row.extend([" "] * (self.cols - len(row)))
        elif final == "@":
            row[self.x : self.x] = [" "] * n
            del row[self.cols :]
        elif final in "LM" and self.top <= self.y <= self.bottom:
            self._scroll(-n if final == "L" else n, at=self.y)
        elif final in "ST":
            self._scroll(n if final == "S" else -n)
        elif final == "r":
            top = params[0] if params else 1
            bottom = params[1] if len(params) > 1 and params[1] else self.rows
            self.top, self.bottom = max(top, 1) - 1, min(bottom, self.rows) - 1
            self._move(0, 0)
        elif final == "b":
            for _ in range(n):
                self._put(self.last)
        # m (attributes), h/l (modes), t (window ops), n (reports): nothing to draw


def test_the_terminal_plays_what_ncurses_sends() -> None:
    """The emulator itself, on sequences ncurses uses for xterm."""
    term = Terminal(10, 3)
    term.feed(b"\x1b[?1049h\x1b[1;1Habc\x1b[2;3Hx\x1b[3b\x1b[1;2H\x1b[K")
    assert term.lines() == ["a", "  xxxx", ""]
    term.feed("\x1b[3;9H▁▂\x1b[2;1H\x1b[2P".encode())
    assert term.lines() == ["a", "xxxx", "        ▁▂"]
    term.feed(b"\x1b[1;3r\x1b[3;1H\n")  # LF on the bottom line scrolls the region
    assert term.lines() == ["xxxx", "        ▁▂", ""]
    term.feed(b"\x1b")  # a sequence cut between two reads
    term.feed(b"[2;1H\x1b[2K")
    assert term.lines() == ["xxxx", "", ""]


# --- the publisher and the watcher --------------------------------------------------


class Publisher:
    """A ZeroMQ PUB socket sending v2 messages as the daemon does."""

    def __init__(self, endpoint: str) -> None:
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.PUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.bind(endpoint)
        self._ident = range_ident(SENSOR, RUN)
        self.seq = 0
        self.started = time.monotonic()

    def range(self, range_m: float | None) -> None:
        status, reasons = ("ok", ()) if range_m is not None else ("dropout", ("weak_signal",))
        payload = encode_range(
            self._ident, self.seq, 1, time.monotonic_ns(), time.time_ns(),
            range_m, 1500, 40.125, 0.75, range_m, 0.00412 if range_m else None, 350.2,
            status, reasons_json(reasons), "stable",
        )  # fmt: skip
        self._sock.send_multipart([topic("range", SENSOR), payload])
        self.seq += 1

    def health(self, state: State, last_error: str | None = None) -> None:
        msg = HealthMessage(
            sensor=SENSOR, run=RUN, t_unix_ns=time.time_ns(), t_mono_ns=time.monotonic_ns(),
            state=state, frames=self.seq, checksum_errors=0, bytes_discarded=0,
            fps=100.0 if state == "connected" else 0.0, frame_rate_hz=100.0,
            dropout_ratio=0.0, dropped_sends=0, uptime_s=time.monotonic() - self.started,
            last_error=last_error, firmware="3.0.9",
        )  # fmt: skip
        self._sock.send_multipart([topic("health", SENSOR), encode_health(msg)])

    def close(self) -> None:
        self._sock.close(linger=0)
        self._ctx.term()


@pytest.fixture
def publisher(tmp_path: Path) -> Iterator[tuple[str, Publisher]]:
    endpoint = f"ipc://{tmp_path}/watch.sock"
    pub = Publisher(endpoint)
    try:
        yield endpoint, pub
    finally:
        pub.close()


def _set_size(fd: int, cols: int, rows: int) -> None:
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))


class OnPty:
    """A ``lunad`` command with a pseudo-terminal for stdin and stdout (stderr kept
    apart for its summary line), its screen played onto a ``Terminal``."""

    def __init__(self, args: list[str], tmp: Path, cols: int = 80, rows: int = 24) -> None:
        self.master, slave = os.openpty()
        _set_size(slave, cols, rows)
        self.term = Terminal(cols, rows)
        self.raw = b""
        self._err_path = tmp / f"stderr-{time.monotonic_ns()}"
        with open(self._err_path, "wb") as err:
            self.proc = subprocess.Popen(
                [*LUNAD, *args],
                stdin=slave,
                stdout=slave,
                stderr=err,
                env={**os.environ, "TERM": "xterm", "LANG": "C.UTF-8", "LC_ALL": "C.UTF-8"},
                process_group=0,  # its own group: signals for the test stay with the test
            )
        os.close(slave)

    @property
    def stderr(self) -> str:
        return self._err_path.read_text(errors="replace")

    def pump(self, timeout_s: float) -> bool:
        """Play what the command wrote within ``timeout_s``; False once it closed."""
        ready, _, _ = select.select([self.master], [], [], timeout_s)
        if not ready:
            return True
        try:
            data = os.read(self.master, 65536)
        except OSError:  # EIO: every slave end closed, the command has ended
            return False
        self.raw += data
        self.term.feed(data)
        return bool(data)

    def until(
        self,
        seen: Callable[[Terminal], bool],
        timeout_s: float = 10.0,
        tick: Callable[[], None] | None = None,
    ) -> None:
        """Pump until ``seen`` holds, calling ``tick`` about every 10 ms; fail after
        ``timeout_s`` with the screen in the message."""
        deadline = time.monotonic() + timeout_s
        while not seen(self.term):
            if time.monotonic() > deadline:
                pytest.fail(f"not seen within {timeout_s} s; the screen:\n{self.term.text()}")
            if tick is not None:
                tick()
            ended = not self.pump(0.01) and self.proc.poll() is not None
            if ended and not seen(self.term):
                pytest.fail(f"the command ended ({self.proc.returncode}): {self.stderr}")

    def resize(self, cols: int, rows: int) -> None:
        """What a terminal window does when dragged: a new size, then SIGWINCH."""
        _set_size(self.master, cols, rows)
        self.term.resize(cols, rows)
        self.proc.send_signal(signal.SIGWINCH)

    def finish(self, timeout_s: float = 10.0) -> int:
        """Wait for the command to end, reading the pty meanwhile; its exit code."""
        deadline = time.monotonic() + timeout_s
        while self.proc.poll() is None and time.monotonic() < deadline:
            self.pump(0.05)
        while self.pump(0.05) and self.proc.poll() is not None and time.monotonic() < deadline:
            pass
        return self.proc.wait(timeout=max(0.1, deadline - time.monotonic()))

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        os.close(self.master)


@pytest.fixture
def on_pty(tmp_path: Path) -> Iterator[Callable[..., OnPty]]:
    made: list[OnPty] = []

    def start(*args: str, cols: int = 80, rows: int = 24) -> OnPty:
        made.append(OnPty(list(args), tmp_path, cols, rows))
        return made[-1]

    yield start
    for each in made:
        each.close()


def _row(term: Terminal, label: str) -> str:
    """The screen row that starts with ``label``, or ''."""
    return next((line for line in term.lines() if line.startswith(label)), "")


class Feed:
    """Sends the daemon's messages on a schedule from ``OnPty.until``'s ticks: a range
    every 10 ms while ``ranges``, a health message every ``health_every_s`` while
    ``state`` is set, as a daemon with ``health_interval_s`` that short would."""

    def __init__(self, pub: Publisher, health_every_s: float = 0.2) -> None:
        self.pub = pub
        self.ranges = True
        self.state: State | None = "connected"
        self.last_error: str | None = None
        self.health_every_s = health_every_s
        self._next_range = self._next_health = 0.0

    def __call__(self) -> None:
        now = time.monotonic()
        if self.ranges and now >= self._next_range:
            n = self.pub.seq
            self.pub.range(None if n % 10 == 9 else 1.0 + 0.5 * (n % 20) / 20)
            self._next_range = now + 0.01
        if self.state is not None and now >= self._next_health:
            self.pub.health(self.state, self.last_error)
            self._next_health = now + self.health_every_s


def test_full_screen_shows_the_reported_state_and_fits_80_columns(
    publisher: tuple[str, Publisher], on_pty: Callable[..., OnPty]
) -> None:
    """The issue: ``--refresh`` redrew only on range messages, so with the sensor
    unplugged it showed ``connected 100 fps`` for ever while the daemon reported
    ``reconnecting``, and it scrolled below about 140 columns. Now the health row says
    what the last health message says, ``no health for N s`` once they stop, the age of
    the last reading once readings stop, and every row fits the terminal."""
    endpoint, pub = publisher
    feed = Feed(pub)
    w = on_pty("watch", "--refresh", "--connect", endpoint, "--duration", "120")

    def connected_with_history(term: Terminal) -> bool:
        spark = _row(term, "history")
        history_row = term.lines()[term.lines().index(spark) + 1] if spark else ""
        return (
            _row(term, "health").split()[1:2] == ["connected"]
            and sum(history_row.count(b) for b in BLOCKS) >= HISTORY_READINGS * 0.8
        )

    w.until(connected_with_history, STARTUP_S, feed)
    lines = w.term.lines()
    assert (lines[0] + "\n").startswith(f"lunad watch  sensor {SENSOR}  {endpoint}"[:79])
    assert re.fullmatch(
        r"range      (1\.\d{3} m ± 0\.4 cm +ok|- m +dropout) +zone stable", _row(w.term, "range")
    ), lines
    assert _row(w.term, "light") == "light      350 lux"
    assert all(len(line) <= 79 for line in lines), lines  # nothing reached column 80

    # The sensor is unplugged: readings stop, the daemon reports it, the screen follows.
    feed.ranges = False
    feed.state = "reconnecting"
    feed.last_error = "lost serial /dev/ttyUSB0 115200 Bd: readable but returned no data"
    w.until(lambda t: _row(t, "health").split()[1:2] == ["reconnecting"], 10.0, feed)
    w.until(lambda t: "no reading for" in t.text(), 10.0, feed)
    lines = w.term.lines()
    assert "connected" not in w.term.text()
    assert any(line.strip().startswith("last error: lost serial /dev/ttyUSB0") for line in lines)
    assert all(len(line) <= 79 for line in lines), lines

    # The daemon goes silent: its last state is not shown as if current.
    feed.state = None
    w.until(lambda t: _row(t, "health").startswith("health     no health for"), 10.0)
    assert "reconnecting" not in w.term.text()

    # A narrower window: the screen is redrawn to fit it, the sparkline shortened.
    w.resize(60, 20)
    w.until(lambda t: _row(t, "history").startswith("history    last 48 readings"), 10.0)
    assert all(len(line) <= 59 for line in w.term.lines()), w.term.lines()

    os.write(w.master, b"q")
    assert w.finish() == 0, w.stderr
    assert re.fullmatch(r"\d+ readings, 0 lost \(seq gaps\)\n", w.stderr), w.stderr


def test_full_screen_needs_a_terminal(tmp_path: Path) -> None:
    r = subprocess.run(
        [*LUNAD, "watch", "--refresh", "--connect", f"ipc://{tmp_path}/x.sock"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode == 2
    assert r.stderr == "lunad watch: --refresh needs a terminal; without one, leave it out\n"


def test_lines_on_a_terminal_get_a_header_every_20_lines(
    publisher: tuple[str, Publisher], on_pty: Callable[..., OnPty]
) -> None:
    endpoint, pub = publisher
    feed = Feed(pub, health_every_s=3600.0)
    feed.state = None
    w = on_pty("watch", "--connect", endpoint, "--count", "45")
    w.until(lambda t: w.proc.poll() is not None, STARTUP_S, feed)
    assert w.finish() == 0, w.stderr
    lines = w.raw.decode().splitlines()
    assert [i for i, line in enumerate(lines) if line == RANGE_HEADER] == [0, 21, 42]
    assert sum(line.startswith("#") for line in lines) == 45


def test_json_lines_carry_their_topic(publisher: tuple[str, Publisher]) -> None:
    endpoint, pub = publisher
    feed = Feed(pub)
    proc = subprocess.Popen(
        [*LUNAD, "watch", "--connect", endpoint, "--json", "--count", "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + STARTUP_S
        while proc.poll() is None and time.monotonic() < deadline:
            feed()
            time.sleep(0.005)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    messages = [json.loads(line) for line in out.splitlines()]
    assert {m["topic"] for m in messages} == {"range/front/", "health/front/"}
    for m in messages:
        assert next(iter(m)) == "topic"
        kind = m.pop("topic").split("/")[0]
        (RangeMessage if kind == "range" else HealthMessage).model_validate(m)


# --- the layout, without a terminal -------------------------------------------------


def _range(seq: int, range_m: float | None, **kw: object) -> RangeMessage:
    fields: dict[str, object] = dict(
        sensor=SENSOR, run=RUN, seq=seq, t_mono_ns=1, t_unix_ns=1, raw_m=range_m, amp=428,
        temp_c=40.125, strength=0.21, range_m=range_m, sigma_m=0.0082 if range_m else None,
        lux_est=12345.6, status="ok" if range_m else "dropout", zone="marginal",
        reasons=[] if range_m else ["weak_signal"],
    )  # fmt: skip
    fields.update(kw)
    return RangeMessage.model_validate(fields)


def _health(state: str, **kw: object) -> HealthMessage:
    fields: dict[str, object] = dict(
        sensor=SENSOR, run=RUN, t_unix_ns=1, t_mono_ns=1, state=state, frames=2**40,
        checksum_errors=2**33, bytes_discarded=2**35, fps=250.0, frame_rate_hz=250.0,
        dropout_ratio=1.0, dropped_sends=2**33, uptime_s=86400 * 400.0,
        last_error="x" * 300, firmware="3.0.9",
    )  # fmt: skip
    fields.update(kw)
    return HealthMessage.model_validate(fields)


def test_render_fits_80_by_24_with_the_widest_values() -> None:
    model = ScreenModel("ipc:///run/lunad/" + "n" * 100 + ".sock", started=0.0)
    long_reasons = ["weak_signal", "saturated", "high_ambient", "too_close", "too_far"]
    for i in range(100):
        status = "degraded" if i % 2 else "dropout"  # an ok message has no reasons
        model.add(
            _range(2**63, 7.9999 if i % 2 else None, reasons=long_reasons, status=status), now=1.0
        )
    model.add(_health("reconnecting"), now=1.0)
    for now in (1.0, 100.0, 10**6):
        rows = render(model, now)
        assert len(rows) <= 24
        assert all(len(row) <= 79 for row in rows), rows


def test_render_never_shows_a_stale_state() -> None:
    model = ScreenModel("tcp://127.0.0.1:7781", started=0.0)
    for t in (1.0, 2.0, 3.0):
        model.add(_health("connected"), now=t)
    model.add(_range(1, 2.0), now=3.0)
    assert render(model, 3.1)[8].split()[:2] == ["health", "connected"]
    assert "no reading" not in "\n".join(render(model, 3.4))
    assert "no reading for 0.5 s" in "\n".join(render(model, 3.5))
    assert render(model, 5.4)[8].split()[:2] == ["health", "connected"]  # 2.4 intervals
    late = render(model, 5.6)
    assert late[8] == "health     no health for 2.6 s"
    assert "connected" not in "\n".join(late)


def test_render_keeps_the_daemons_last_word() -> None:
    """``stopped`` is the last health message a daemon sends (docs/messages.md): it
    does not turn into "no health" when nothing follows."""
    model = ScreenModel("tcp://127.0.0.1:7781", started=0.0)
    model.add(_health("stopped", last_error=None), now=1.0)
    assert render(model, 60.0)[8] == "health     stopped 59 s ago (the daemon's last message)"


def test_sparkline_levels_and_gaps() -> None:
    assert sparkline([1.0, 1.5, None, 2.0], ASCII_GLYPHS) == "_= #"
    assert sparkline([2.0, 2.02, 2.0], ASCII_GLYPHS) == "_._"  # 2 cm of a 10 cm span
    assert sparkline([None, None], ASCII_GLYPHS) == "  "


def test_the_header_names_each_column_where_it_starts() -> None:
    line = format_range(_range(690, 2.5431, status="degraded", reasons=["outlier"]))
    for name, field in (("seq", "#690"), ("status", "degraded"), ("why not ok", "outlier")):
        assert RANGE_HEADER.index(name) == line.index(field), (name, RANGE_HEADER, line)
