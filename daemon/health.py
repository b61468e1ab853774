"""What the daemon knows about itself, summarised once a second on ``health/<sensor>/``."""

from __future__ import annotations

import time
from enum import StrEnum

from lunad.filters import FilterConfig
from lunad.protocol.messages import HealthMessage
from lunad.protocol.parser import ParserStats


class State(StrEnum):
    """Link state (docs/messages.md, health ``state``)."""

    CONNECTED = "connected"  # bytes are arriving
    WAITING = "waiting"  # port open, sensor silent; or a replay waiting for a subscriber
    RECONNECTING = "reconnecting"  # port closed or failing; retrying
    STOPPED = "stopped"  # the daemon's last message: shutting down, or a replay ended


"""sigma0 and k of the datasheet fit: the noise model is ``default`` while they are."""


class Health:
    """Summarises the daemon's counters per interval as health messages.

    The read loop adds to ``frames`` (every filtered frame) and ``dropouts`` (those
    whose status is ``dropout``) itself: plain attributes, no call per frame.

    Two rates, both frames a second:

    - ``fps``: frames filtered in the interval since the previous health message,
      over its length; a measurement of that interval. It reads high in a message
      sent at a state change, milliseconds after the previous one, and low then high
      around a stall of the daemon (the backlog lands in the next interval).
    - ``frame_rate_hz``: the rate the daemon times frames by (the spacing of a
      read's frames for the filter, the silence threshold): the configured rate (a
      replay: its recording's), or the rate a serial sensor, or the one a replay
      plays, really sends at once it differs by more than 5 %
      (``lunad.daemon.frame_clock``). Steady where ``fps`` moves with every
      interval.

    Args:
        sensor: the sensor name.
        t_mono_ns: when the daemon started (monotonic nanoseconds).
        run: the daemon's run identity (docs/messages.md ``run``).
        filter_config: the filter settings in force, for the range gate.
        noise_configured: the config sets the noise model (sigma0 or k: ``lunad
            calibrate``), or the defaults are in force (``noise_model``).
    """

    def __init__(
        self,
        sensor: str,
        t_mono_ns: int,
        run: str,
        filter_config: FilterConfig,
        noise_configured: bool = False,
    ) -> None:
        self.sensor = sensor
        self.run = run
        self.state = State.RECONNECTING
        self.last_error: str | None = None
        self.firmware: str | None = None
        self.serial: str | None = None
        self.filter_config = filter_config
        self.noise_configured = noise_configured
        self._t_start = t_mono_ns
        self._t_mark = t_mono_ns
        self._frames_mark = 0
        self._dropouts_mark = 0
        self.frames = 0
        self.dropouts = 0

    def message(
        self,
        stats: ParserStats,
        dropped_sends: int,
        t_mono_ns: int,
        frame_rate_hz: float,
    ) -> HealthMessage:
        """A health message for the interval since the previous one (which it closes).

        Args:
            stats: the parser's counters.
            dropped_sends: messages the socket refused, since start.
            t_mono_ns: now, monotonic nanoseconds; ends the interval.
            frame_rate_hz: the rate the daemon times frames by, Hz (class docstring).
        """
        dt = (t_mono_ns - self._t_mark) / 1e9
        frames = self.frames - self._frames_mark
        dropouts = self.dropouts - self._dropouts_mark
        self._t_mark, self._frames_mark, self._dropouts_mark = t_mono_ns, self.frames, self.dropouts
        fc = self.filter_config
        return HealthMessage(
            sensor=self.sensor,
            run=self.run,
            t_unix_ns=time.time_ns(),
            t_mono_ns=t_mono_ns,
            state=self.state.value,
            frames=stats.frames,
            checksum_errors=stats.checksum_errors,
            bytes_discarded=stats.bytes_discarded,
            fps=round(frames / dt, 2) if dt > 0 else 0.0,
            frame_rate_hz=round(frame_rate_hz, 3),
            dropout_ratio=round(dropouts / frames, 4) if frames else 0.0,
            dropped_sends=dropped_sends,
            uptime_s=round((t_mono_ns - self._t_start) / 1e9, 3),
            last_error=self.last_error,
            firmware=self.firmware,
            serial=self.serial,
            min_range_m=fc.min_range_m,
            max_range_m=fc.max_range_m,
            noise_model="configured" if self.noise_configured else "default",
        )
