"""The serve loop's link to the sensor: open the source, configure the sensor and take
its answers, and reopen the source when it is lost or cannot be opened.

A lost or absent device never stops the daemon: it reports ``reconnecting`` and retries
with backoff (0.1 s doubling to 2 s) until the path works again. Each new source gets a
new frame clock (the port may hold another sensor) and is asked for its firmware
version; the sensor's answers come back through the parser, between frames.

``Reconnecting`` is a part of ``serve.Daemon`` (a base class of it): its methods run on
the daemon's state, between reads, and none of them runs per frame.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from lunad.daemon.config import Config, SourceSection
from lunad.daemon.errors import SourceLostError, SourceOpenError
from lunad.daemon.frame_clock import FrameClock
from lunad.daemon.health import Health, State
from lunad.daemon.sources.base import Source
from lunad.filters import Estimate, RangeFilter
from lunad.protocol import commands
from lunad.protocol.commands import CommandId, CommandReply, decode_reply
from lunad.protocol.frame import Frame
from lunad.protocol.parser import FrameParser

log = logging.getLogger("lunad.serve")

VERSION_TIMEOUT_S = 1.0  # a sensor that has not answered the version query by then is warned of
BACKOFF_FIRST_S = 0.1
BACKOFF_MAX_S = 2.0
RETRY_LOG_EVERY_S = 60.0  # while a device stays absent, remind the log this often
NS = 1_000_000_000


class Reconnecting:
    """Opening, configuring, losing and reopening the source of a ``Daemon``."""

    # The daemon's state these methods use; ``Daemon.__init__`` and ``Daemon.run`` set it.
    cfg: Config
    health: Health
    parser: FrameParser
    filter: RangeFilter
    _source: Source | None
    _open: Callable[[SourceSection], Source]
    _clock: FrameClock
    _unsent: tuple[Frame, float | None, Estimate, int] | None
    _backoff: float
    _next_open: int
    _open_failures: int
    _last_retry_log: int
    _recovered_seen: int
    _last_recovered_log: int
    _last_bytes: int
    _next_publish: int
    _version_deadline: int | None

    if TYPE_CHECKING:  # defined by Daemon

        def _sensor_rate_hz(self) -> int: ...

        def _set_frame_rate(self, rate_hz: float) -> None: ...

        def _set_state(self, state: State, now: int) -> None: ...

    def _note_recovered_faults(self, src: Source, now: int) -> None:
        """Put faults the source got over by itself (I2C NACKs retried, a hung sensor
        rebooted) on health and in the log."""
        count, last = src.recovered_faults
        if count <= self._recovered_seen:
            return
        self._recovered_seen = count
        note = f"{self._source_desc()}: recovered from {count} fault(s) since opening; last: {last}"
        self.health.last_error = note
        if now - self._last_recovered_log >= RETRY_LOG_EVERY_S * NS:
            log.warning("%s", note)
            self._last_recovered_log = now

    def _try_open(self, now: int) -> None:
        try:
            self._source = self._open(self.cfg.source)
        except SourceOpenError as exc:
            self.health.last_error = str(exc)
            self._open_failures += 1
            if self._open_failures == 1:
                log.warning("%s; retrying every %.1f s at most", exc, BACKOFF_MAX_S)
                self._last_retry_log = now  # reminded a minute on
            elif (now - self._last_retry_log) / NS >= RETRY_LOG_EVERY_S:
                log.warning(
                    "still cannot open %s after %d tries", self._source_desc(), self._open_failures
                )
                self._last_retry_log = now
            self._next_open = now + int(self._backoff * NS)
            self._backoff = min(self._backoff * 2, BACKOFF_MAX_S)
            self._set_state(State.RECONNECTING, now)
            return
        failures = self._open_failures
        log.info("opened %s%s", self._source, f" after {failures} failed tries" if failures else "")
        rate = self._sensor_rate_hz()
        if rate != self.cfg.sensor.frame_rate_hz:
            log.info(
                "%s: its sensor sent %d frames a second; timing frames by that, not by --rate %d",
                self._source,
                rate,
                self.cfg.sensor.frame_rate_hz,
            )
        # a new port may hold another sensor, or one that takes the rate command now
        self._clock = FrameClock(rate, follow=self.cfg.source.timed_by_its_frames)
        self._set_frame_rate(rate)
        self._open_failures = 0
        self._recovered_seen = 0
        self._backoff = BACKOFF_FIRST_S
        self._last_bytes = now
        self._next_publish = 0  # the first read's frames go out: its clock may be a replay's
        self.health.firmware = None  # until this sensor answers: the port may have another
        self.health.serial = None
        self._set_state(State.WAITING, now)
        self._version_deadline = self._configure(now)

    def _lost(self, exc: SourceLostError) -> None:
        log.warning("lost %s: %s; reconnecting", self._source_desc(), exc)
        self.health.last_error = str(exc)
        self._drop_source()
        now = time.monotonic_ns()
        self._next_open = now + int(BACKOFF_FIRST_S * NS)
        self._backoff = BACKOFF_FIRST_S * 2
        self._set_state(State.RECONNECTING, now)

    def _on_reply(self, reply: CommandReply) -> None:
        value = decode_reply(reply)
        if reply.cmd_id == CommandId.GET_VERSION:
            self.health.firmware = str(value)
            log.info("sensor firmware %s", value)
        elif reply.cmd_id == CommandId.SAMPLE_FREQ:
            wanted = self._sensor_rate_hz()  # a replay's: the rate its recording was made at
            if value != wanted:
                log.warning("sensor reports frame rate %s Hz, asked for %d Hz", value, wanted)
            else:
                log.info("frame rate %s Hz", value)
        elif reply.cmd_id == CommandId.OUTPUT_EN:
            log.info("sensor output %s", "on" if value else "off")
        elif reply.cmd_id == CommandId.READ_MANU_BIN:
            self.health.serial = str(value).strip("\x00 ") or None
            log.info("sensor serial number %s", self.health.serial)
        elif reply.cmd_id == CommandId.OUTPUT_FORMAT:
            wanted = self.cfg.sensor.frame_format  # the parser reads that regardless
            if value is not wanted:
                log.warning("sensor reports output format %r, asked for %r", value, wanted)
        else:
            log.debug("reply to command %#04x: %r", reply.cmd_id, value)

    def _configure(self, now: int) -> int | None:
        """Ask for the firmware version, set rate and output; returns the reply deadline."""
        src = self._source
        if src is None or not self.cfg.sensor.configure or self.cfg.source.kind == "replay":
            return None
        try:
            src.write(commands.startup(self.cfg.sensor.frame_rate_hz, self.cfg.sensor.frame_format))
        except SourceLostError as exc:
            log.warning("cannot configure the sensor: %s", exc)
            return None
        return now + int(VERSION_TIMEOUT_S * NS)

    def _drop_source(self) -> None:
        src, self._source = self._source, None
        if src is not None:
            src.close()
        self.parser.reset()
        self.parser.fmt = self.cfg.sensor.frame_format  # a reload may have changed it
        self.filter.reset()
        self._unsent = None

    def _source_desc(self, cfg: Config | None = None) -> str:
        return (cfg or self.cfg).source.description
