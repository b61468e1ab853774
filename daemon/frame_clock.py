"""The rate a sensor really sends frames at, measured from when they are read.

The daemon stamps the frames of one read a frame period apart and waits some frame
periods before calling a sensor silent. A sensor
need not send at the rate it was asked for: its reply to the rate command may be
lost, its firmware may ignore the command, or it may have been left in another mode.
``FrameClock`` measures the rate from the reads and tells the daemon which rate to
time frames by.

How this works. The caller feeds each read's time and the frames it brought. Reads
are grouped into consecutive windows: a window opens at a read and closes at the
first later read that is at least ``WINDOW_S`` after it and brings its count to
``WINDOW_FRAMES``; that read opens the next window. A window's rate is

    frames read after its opening read, up to and including its closing read
    / (closing read time - opening read time)

Both ends are reads, and a read takes every byte that arrived before it, so both
ends sit on the sensor's own clock whatever happened in between: chunking by a USB
adapter or a pty changes nothing, and a daemon that stalled for 0.3 s and then read
75 frames at once is still on time at that read.

What does spoil a window is a gap in the stream itself. A sensor pause shows as a
read that comes more than ``PAUSE_MIN_S`` after the one before with under a
``PAUSE_FACTOR``-th of the frames that time holds at the measured rate (a stalled
daemon's read brings them all). Such a read is left out of its window, time and
frames: both its ends are reads, on the sensor's clock, so what remains is measured
as exactly as before, and a sensor that pauses every half second is still measured
right. Two such reads in a row are not a pause but the rate itself, lower (a sensor
now sending at 25 Hz where 250 was measured): from the second on they count, so the
measurement follows it. Any other gap (a read stamped late after a stall) lies inside
one window, because no read falls inside a gap, and the measured rate is the median
of the last ``KEEP_WINDOWS`` windows: two spoilt windows in that span leave it where
it was.

The clock starts at the rate it is given (the configured one) and gives a verdict
once ``MIN_WINDOWS`` windows are in. The sensor's rate changes only when the
measurement differs from it by more than ``TOLERANCE``; the new value is the
measurement, rounded to a rate the sensor can run at (500/n Hz) when it is within
``SNAP_TOLERANCE`` of one, and the configured rate when it is within ``TOLERANCE``
of that. Cost: a few additions and comparisons a read (about 0.1 us here), and a
sort of five floats a window (twice a second); the state is a fixed ring of five
window rates and a few numbers, nothing kept per read or per frame.

Nothing in here reads a clock, does I/O or logs: the caller passes the times and
reports what ``feed`` says changed.
"""

from __future__ import annotations

NS = 1_000_000_000

WINDOW_S = 0.5
"""A window spans at least this long, seconds. A read can come late after the frames
it brings (a USB adapter's latency timer holds bytes up to 16 ms): over 0.5 s that
moves a window's rate by at most 3 %, inside ``TOLERANCE``. Three windows, the
evidence for a verdict, then take 1.5 s."""
WINDOW_NS = int(WINDOW_S * NS)

WINDOW_FRAMES = 25
"""... and holds at least this many frames. A source read on a timer rather than as
bytes arrive (``socket://`` in low-power mode) is up to a frame behind at each end, so
a window of 25 frames errs by 4 % at most; at 250 Hz a window of 0.5 s holds 125."""

KEEP_WINDOWS = 5
"""The measured rate is the median of this many most recent windows: two windows
spoilt by gaps in the stream (2.5 s at 250 Hz) leave it unmoved."""

MIN_WINDOWS = 3
"""A verdict needs this many windows, and a new rate this many windows within
``TOLERANCE`` of it: the smallest median that one spoilt window cannot move. The
second rule keeps a window that straddles a change of rate, whose rate lies between
the old and the new one, from being taken when it is the median for a moment."""

TOLERANCE = 0.05
"""A measurement is taken as a new rate when it differs from the current one by more
than this fraction. Wider than ``--rate``'s integer rounding of the rates the sensor
runs at (it is asked for 23 Hz and may run at 500/21 = 23.8 Hz: 3.5 %; 4.2 % at
20 Hz), narrower than the step between two rates it runs at above 25 Hz (250, 166.7,
125, 100 ...; 500/19 against 500/20: 5 %)."""

SNAP_TOLERANCE = 0.01
"""A measurement within this fraction of 500/n Hz is taken as 500/n Hz exactly, the
rate the sensor runs at; the timing then does not carry a measurement's noise."""

PAUSE_MIN_S = 0.05
"""A read this long after the one before, seconds, may end a sensor pause: longer
than the gap between reads of a streaming sensor at a rate the daemon reads it on a
timer for (20 ms at ``--publish-hz 50``), short enough to catch a pause that would move a
0.5 s window by 10 %."""
PAUSE_MIN_NS = int(PAUSE_MIN_S * NS)

PAUSE_FACTOR = 4
"""... and it does when it brings under a quarter of the frames its gap holds at the
measured rate. A daemon stalled for that long reads them all; a rate that fell by up
to four times is not taken for pauses, and a larger fall only at its first read."""

SENSOR_BASE_HZ = 500
"""The TF-Luna's frame rates are 500/n Hz for n = 2..500 (M05 p.9, p.15;
``lunad.protocol.commands.FRAME_RATES_HZ`` holds them rounded down)."""
SENSOR_DIVISORS = range(2, 501)

NO_READ_YET = 1 << 63
"""The read times the clock keeps, before the first read: later than any read time, so
that the first read looks like time going back and opens a window, with no test of
its own on every read."""


def sensor_rate_near(hz: float) -> float:
    """The rate the sensor can run at (500/n Hz) nearest ``hz``, when it is within
    ``SNAP_TOLERANCE`` of it; else ``hz`` itself."""
    if hz <= 0:
        return hz
    n = round(SENSOR_BASE_HZ / hz)
    if n in SENSOR_DIVISORS:
        snapped = SENSOR_BASE_HZ / n
        if abs(snapped - hz) <= SNAP_TOLERANCE * hz:
            return snapped
    return hz


class FrameClock:
    """Measures a sensor's frame rate from its reads; says which rate to time frames by.

    Args:
        nominal_hz: the rate the sensor was asked for (a replay: the rate its recording
            gives), Hz; the clock times frames by it until the reads say otherwise.
        follow: True to time frames by the measured rate once it differs from
            ``nominal_hz`` (a serial sensor, and a replay, whose recorded read times
            are the live run's); False to keep ``nominal_hz`` and only measure (an I2C
            sensor, which the source triggers at that rate).

    Raises:
        ValueError: ``nominal_hz`` is not positive (caller misuse).

    Attributes:
        nominal_hz: as given, Hz.
        follow: as given.
        sensor_hz: the rate the sensor sends at by the evidence, Hz: ``nominal_hz``
            until a verdict says otherwise.
        rate_hz: the rate to time frames by, Hz: ``sensor_hz`` when following, else
            ``nominal_hz``.
        measured_hz: the median of the recent windows, Hz; None before ``MIN_WINDOWS``.
    """

    __slots__ = (
        "_count",
        "_next",
        "_rates",
        "_ref_hz",
        "_t_last",
        "_t_open",
        "_t_pause",
        "_windows",
        "follow",
        "measured_hz",
        "nominal_hz",
        "rate_hz",
        "sensor_hz",
    )

    def __init__(self, nominal_hz: float, follow: bool = True) -> None:
        if not nominal_hz > 0:
            raise ValueError(f"nominal_hz must be positive, got {nominal_hz}")
        self.nominal_hz = float(nominal_hz)
        self.follow = follow
        self.sensor_hz = self.nominal_hz
        self.rate_hz = self.nominal_hz
        self.measured_hz: float | None = None
        self._t_open = NO_READ_YET
        """Read time that opened the current window, ns, moved on by a pause left out."""
        self._t_last = NO_READ_YET
        """Time of the latest read, ns."""
        self._count = 0
        """Frames read since the window opened (the opening read's not counted)."""
        self._t_pause = NO_READ_YET
        """Time of the latest read that ended a pause, ns."""
        self._ref_hz = 0.0
        """The rate a pause is judged by, Hz: the measured one, or the last window's
        before there is one; 0 (no pause can be told) before any window closed."""
        self._rates = [0.0] * KEEP_WINDOWS
        """Rates of the most recent windows, Hz: a ring, ``_next`` the slot to fill."""
        self._next = 0
        self._windows = 0
        """Windows closed, up to ``KEEP_WINDOWS``."""

    @property
    def period_ns(self) -> int:
        """The frame period to time frames by, ns (``1 / rate_hz``)."""
        return int(NS / self.rate_hz)

    def feed(self, t_mono_ns: int, frames: int) -> bool:
        """Take one read: its time (ns, monotonic) and the frames it brought.

        Call it for reads that brought frames (a read of none says nothing about the
        rate). Frames the sensor sent that did not parse (a wrong checksum) count: the
        sensor sent them on its clock.

        Returns:
            True when ``sensor_hz`` changed (and ``rate_hz`` with it when following):
            the caller retimes and says so, once per change.
        """
        gap = t_mono_ns - self._t_last
        self._t_last = t_mono_ns
        if gap > PAUSE_MIN_NS and frames * PAUSE_FACTOR * NS < gap * self._ref_hz:
            after_pause = self._t_pause == t_mono_ns - gap
            self._t_pause = t_mono_ns
            if not after_pause:  # a sensor pause: its time and frames are left out
                self._t_open += gap
                return False
        count = self._count + frames
        elapsed = t_mono_ns - self._t_open
        if elapsed < WINDOW_NS or count < WINDOW_FRAMES:
            if elapsed < 0:  # the first read, or time went back (a recording appended
                self._t_open = t_mono_ns  # to after a reboot): this read opens a window
                count = 0
            self._count = count
            return False
        self._t_open = t_mono_ns
        self._count = 0
        return self._close_window(count * NS / elapsed)

    def _close_window(self, rate_hz: float) -> bool:
        """Add a window's rate; update the median and the verdict."""
        rates = self._rates
        rates[self._next] = rate_hz
        self._next = (self._next + 1) % KEEP_WINDOWS
        if self._windows < KEEP_WINDOWS:
            self._windows += 1
        n = self._windows
        if n < MIN_WINDOWS:
            self._ref_hz = rate_hz
            return False
        recent = sorted(rates[:n])
        mid = n // 2
        measured = recent[mid] if n % 2 else (recent[mid - 1] + recent[mid]) / 2
        self.measured_hz = self._ref_hz = measured
        sensor = self.sensor_hz
        if abs(measured - sensor) <= TOLERANCE * sensor:
            return False
        near = TOLERANCE * measured
        if sum(abs(r - measured) <= near for r in recent) < MIN_WINDOWS:
            return False  # a window across a change of rate, between the old and new ones
        new = sensor_rate_near(measured)
        nominal = self.nominal_hz
        if abs(new - nominal) <= TOLERANCE * nominal:
            new = nominal
        if new == sensor:
            return False
        self.sensor_hz = new
        if self.follow:
            self.rate_hz = new
        return True

    @property
    def differs(self) -> bool:
        """True when the sensor sends at another rate than ``nominal_hz``, by the evidence."""
        return self.sensor_hz != self.nominal_hz
