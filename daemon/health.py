"""What the daemon knows about itself, summarised once a second on ``health/<sensor>``."""

from __future__ import annotations

import time
from enum import StrEnum

from lunad.protocol.messages import HealthMessage
from lunad.protocol.parser import ParserStats


class State(StrEnum):
    """Link state (DESIGN.md health contract)."""

    CONNECTED = "connected"  # bytes are arriving
    WAITING = "waiting"  # port open, sensor silent
    RECONNECTING = "reconnecting"  # port closed or failing; retrying


class Health:
    """Summarises the daemon's counters per interval as health messages.

    The read loop adds to ``frames`` (every filtered frame) and ``dropouts`` (those
    whose status is ``dropout``) itself: plain attributes, no call per frame.

    Args:
        sensor: the sensor name.
        t_mono_ns: when the daemon started (monotonic nanoseconds).
    """

    def __init__(self, sensor: str, t_mono_ns: int) -> None:
        self.sensor = sensor
        self.state = State.RECONNECTING
        self.last_error: str | None = None
        self.firmware: str | None = None
        self._t_start = t_mono_ns
        self._t_mark = t_mono_ns
        self._frames_mark = 0
        self._dropouts_mark = 0
        self.frames = 0
        self.dropouts = 0

    def message(self, stats: ParserStats, dropped_sends: int, t_mono_ns: int) -> HealthMessage:
        """A health message for the interval since the previous one (which it closes)."""
        dt = (t_mono_ns - self._t_mark) / 1e9
        frames = self.frames - self._frames_mark
        dropouts = self.dropouts - self._dropouts_mark
        self._t_mark, self._frames_mark, self._dropouts_mark = t_mono_ns, self.frames, self.dropouts
        return HealthMessage(
            sensor=self.sensor,
            t_unix_ns=time.time_ns(),
            state=self.state.value,
            frames=stats.frames,
            checksum_errors=stats.checksum_errors,
            bytes_discarded=stats.bytes_discarded,
            fps=round(frames / dt, 2) if dt > 0 else 0.0,
            dropout_ratio=round(dropouts / frames, 4) if frames else 0.0,
            dropped_sends=dropped_sends,
            uptime_s=round((t_mono_ns - self._t_start) / 1e9, 3),
            last_error=self.last_error,
            firmware=self.firmware,
        )
