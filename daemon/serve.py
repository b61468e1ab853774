"""``lunad serve``: read the sensor, clean every reading, publish it.

How this works: one thread owns everything. It blocks in the source's read (bounded
by the next housekeeping deadline, so an idle daemon wakes a few times a second and
never spins), feeds the bytes to the parser, runs each frame through the filter and
publishes one ``range`` message per frame. Housekeeping between reads: ``health``
once per interval and at every state change, the silent-sensor check, and the
reconnect schedule. A lost or absent device never stops the daemon: it reports
``reconnecting`` and retries with backoff (0.1 s doubling to 2 s) until the path
works again. SIGTERM/SIGINT set a flag and wake the blocked read.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from types import FrameType

from lunad.daemon.config import Config, SourceSection
from lunad.daemon.errors import SourceLostError, SourceOpenError
from lunad.daemon.health import Health, State
from lunad.daemon.publisher import Publisher
from lunad.daemon.source import Source, open_source
from lunad.filters import RangeFilter, Status
from lunad.protocol import commands
from lunad.protocol.commands import CommandId, CommandReply, decode_reply
from lunad.protocol.frame import Frame
from lunad.protocol.messages import encode_health, encode_range, reasons_json, topic
from lunad.protocol.parser import FrameParser

log = logging.getLogger("lunad.serve")

WAITING_AFTER_S = 1.0  # no bytes for this long: state waiting (the contract says within 2 s)
VERSION_TIMEOUT_S = 1.0  # a sensor that has not answered the version query by then is warned of
BACKOFF_FIRST_S = 0.1
BACKOFF_MAX_S = 2.0
READ_SLICE_S = 0.25  # longest blocking read; bounds the reaction to state changes
RETRY_LOG_EVERY_S = 60.0  # while a device stays absent, remind the log this often


class Daemon:
    """One sensor, one publisher, one loop.

    Args:
        cfg: validated configuration.
        source_opener: opens the source (tests can pass another backend).
    """

    def __init__(
        self, cfg: Config, source_opener: Callable[[SourceSection], Source] = open_source
    ) -> None:
        self.cfg = cfg
        self._open = source_opener
        self._stop = threading.Event()
        self._source: Source | None = None
        self.parser = FrameParser()
        self.filter = RangeFilter(cfg.filter.to_filter_config())
        self.seq = -1
        self._sensor_json = json.dumps(cfg.sensor.name)
        self._range_topic = topic("range", cfg.sensor.name)
        self._health_topic = topic("health", cfg.sensor.name)
        self._reasons_json: dict[tuple[str, ...], str] = {}

    def request_stop(self, signum: int | None = None, _frame: FrameType | None = None) -> None:
        """Ask the loop to stop and wake it; safe from a signal handler."""
        if signum is not None:
            log.info("received %s, stopping", signal.Signals(signum).name)
        self._stop.set()
        src = self._source
        if src is not None:
            src.cancel()

    def install_signal_handlers(self) -> None:
        """Stop cleanly on SIGTERM and SIGINT."""
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)

    def run(self, publisher: Publisher) -> int:
        """Serve until asked to stop; returns the exit code (0)."""
        cfg = self.cfg
        now = time.monotonic_ns()
        health = Health(cfg.sensor.name, now)
        interval_ns = int(cfg.publish.health_interval_s * 1e9)
        next_health = now
        last_bytes = now
        backoff = BACKOFF_FIRST_S
        next_open = now
        version_deadline: int | None = None
        open_failures = 0
        last_retry_log = 0
        src_desc = f"{cfg.source.kind} {cfg.source.device}"
        log.info(
            "serving sensor %r from %s, publishing on %s",
            cfg.sensor.name,
            src_desc,
            publisher.endpoint,
        )

        def set_state(state: State, t: int) -> None:
            nonlocal next_health
            if health.state is not state:
                health.state = state
                next_health = t

        while not self._stop.is_set():
            now = time.monotonic_ns()
            if self._source is None and now >= next_open:
                try:
                    self._source = self._open(cfg.source)
                except SourceOpenError as exc:
                    health.last_error = str(exc)
                    open_failures += 1
                    if open_failures == 1:
                        log.warning("%s; retrying every %.1f s at most", exc, BACKOFF_MAX_S)
                    elif (now - last_retry_log) / 1e9 >= RETRY_LOG_EVERY_S:
                        log.warning("still cannot open %s after %d tries", src_desc, open_failures)
                        last_retry_log = now
                    next_open = now + int(backoff * 1e9)
                    backoff = min(backoff * 2, BACKOFF_MAX_S)
                    set_state(State.RECONNECTING, now)
                else:
                    log.info("opened %s%s", self._source, _after(open_failures))
                    open_failures = 0
                    backoff = BACKOFF_FIRST_S
                    last_bytes = now
                    set_state(State.WAITING, now)
                    version_deadline = self._configure(now)

            if now >= next_health:
                msg = health.message(self.parser.stats, publisher.dropped_sends, now)
                publisher.send(self._health_topic, encode_health(msg))
                next_health = now + interval_ns

            src = self._source
            if src is None:
                wait_s = min(next_open, next_health) - now
                self._stop.wait(max(0.0, wait_s / 1e9))
                continue

            timeout_s = min(READ_SLICE_S, max(0.0, (next_health - now) / 1e9))
            try:
                chunk = src.read(timeout_s)
            except SourceLostError as exc:
                if self._stop.is_set():
                    break
                log.warning("lost %s: %s; reconnecting", src_desc, exc)
                health.last_error = str(exc)
                self._drop_source()
                now = time.monotonic_ns()
                next_open = now + int(BACKOFF_FIRST_S * 1e9)
                backoff = BACKOFF_FIRST_S * 2
                set_state(State.RECONNECTING, now)
                continue

            now = time.monotonic_ns()
            if chunk is not None:
                last_bytes = now
                if health.state is not State.CONNECTED:
                    log.info("data arriving from %s", src_desc)
                    set_state(State.CONNECTED, now)
                self._process(chunk.data, chunk.t_mono_ns, health, publisher)
            elif health.state is State.CONNECTED and now - last_bytes > WAITING_AFTER_S * 1e9:
                log.warning("no data from %s for %.1f s", src_desc, WAITING_AFTER_S)
                set_state(State.WAITING, now)
            if version_deadline is not None:
                if health.firmware is not None:
                    version_deadline = None
                elif now >= version_deadline:
                    log.warning(
                        "sensor on %s did not answer the version query within %.1f s; "
                        "carrying on with whatever data arrives",
                        src_desc,
                        VERSION_TIMEOUT_S,
                    )
                    version_deadline = None

        self._drop_source()
        log.info(
            "stopped: %d frames published, %d checksum errors, %d bytes discarded",
            health.frames,
            self.parser.stats.checksum_errors,
            self.parser.stats.bytes_discarded,
        )
        return 0

    def _process(self, data: bytes, t_mono_ns: int, health: Health, pub: Publisher) -> None:
        items = self.parser.feed(data, t_mono_ns)
        if not items:
            return
        t_unix_ns = time.time_ns() - (time.monotonic_ns() - t_mono_ns)
        step = self.filter.step
        send = pub.send
        rtopic = self._range_topic
        for item in items:
            if type(item) is not Frame:
                self._on_reply(item, health)  # type: ignore[arg-type]
                continue
            self.seq += 1
            raw_m = item.distance_m
            est = step(raw_m, item.amp, t_mono_ns)
            reasons = self._reasons_json.get(est.reasons)
            if reasons is None:
                reasons = self._reasons_json[est.reasons] = reasons_json(est.reasons)
            payload = encode_range(
                self._sensor_json,
                self.seq,
                t_mono_ns,
                t_unix_ns,
                raw_m,
                item.amp,
                item.temp_c,
                est.strength,
                est.range_m,
                est.sigma_m,
                est.lux_est,
                est.status.value,
                reasons,
                est.zone.value,
            )
            send(rtopic, payload)
            health.count(est.status is Status.DROPOUT)

    def _on_reply(self, reply: CommandReply, health: Health) -> None:
        value = decode_reply(reply)
        if reply.cmd_id == CommandId.GET_VERSION:
            health.firmware = str(value)
            log.info("sensor firmware %s", value)
        elif reply.cmd_id == CommandId.SAMPLE_FREQ:
            wanted = self.cfg.sensor.frame_rate_hz
            if value != wanted:
                log.warning("sensor reports frame rate %s Hz, asked for %d Hz", value, wanted)
            else:
                log.info("frame rate %s Hz", value)
        elif reply.cmd_id == CommandId.OUTPUT_EN:
            log.info("sensor output %s", "on" if value else "off")
        else:
            log.debug("reply to command %#04x: %r", reply.cmd_id, value)

    def _configure(self, now: int) -> int | None:
        """Ask for the firmware version, set rate and output; returns the reply deadline."""
        src = self._source
        if src is None or not self.cfg.sensor.configure:
            return None
        try:
            src.write(
                commands.get_version()
                + commands.set_frame_rate(self.cfg.sensor.frame_rate_hz)
                + commands.set_output_enabled(True)
            )
        except SourceLostError as exc:
            log.warning("cannot configure the sensor: %s", exc)
            return None
        return now + int(VERSION_TIMEOUT_S * 1e9)

    def _drop_source(self) -> None:
        src, self._source = self._source, None
        if src is not None:
            src.close()
        self.parser.reset()
        self.filter.reset()


def _after(failures: int) -> str:
    return f" after {failures} failed attempts" if failures else ""
