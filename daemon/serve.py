"""``lunad serve``: read the sensor, clean every reading, publish it.

How this works: one thread owns everything. It blocks in the source's read (bounded
by the next housekeeping deadline, so an idle daemon wakes a few times a second and
never spins), feeds the bytes to the parser, runs each frame through the filter and
publishes one ``range`` message per frame. Between reads it does the housekeeping:
``health`` once per interval and at every state change, the silent-sensor check, the
reconnect schedule, the last-value cache for late subscribers, the systemd watchdog
(pinged only from this loop, so a wedged loop gets restarted) and SIGHUP reloads.

A lost or absent device never stops the daemon: it reports ``reconnecting`` and
retries with backoff (0.1 s doubling to 2 s) until the path works again. Opening,
configuring and reopening the source are in ``reconnect.py``, the SIGHUP reload in
``reload.py``: both are base classes of ``Daemon`` and never run per frame.

While bytes flow, an inner loop only reads, parses, filters and sends; it returns to
the housekeeping at the next deadline or when a flag asks for it. ``t_unix_ns`` is
the frame's monotonic read time plus an offset to the wall clock refreshed with every
health message, so a wall-clock step shows up within one health interval.

Low-power mode (``publish_hz``): the loop wakes about once per message, not per frame.
A source that buffers (a serial port) is read at each publish time: the loop sleeps
on a timer, off the port's wait queue, and takes what came. It filters every frame
and publishes only the latest; ``seq`` still counts every frame, so subscribers see
how many were folded.

Frame timing: the frames of one read are stamped a frame period apart for the filter,
and silence is a number of frame periods. The period is the one the sensor really sends
at: a ``FrameClock`` fed with every read measures it, starting from the configured rate,
and a sensor that did not take the rate command (a lost reply, firmware that ignores it)
is timed by its own rate once 1.5 s of frames show it, with one warning. A replay's
clock starts from the rate its recording gives and follows its recorded read times as
the live run's did, so it times every frame as the live run did, a sensor that ignored
``--rate`` included. An I2C sensor keeps the configured rate (it is triggered on that
schedule): its clock only measures, and a disagreement is logged.
"""

from __future__ import annotations

import logging
import signal
import time
from collections.abc import Callable
from pathlib import Path
from time import monotonic_ns
from types import FrameType
from typing import Any

from lunad.daemon.config import Config, ConfigError, SourceSection
from lunad.daemon.errors import SourceLostError
from lunad.daemon.frame_clock import FrameClock
from lunad.daemon.health import Health, State
from lunad.daemon.notify import Notifier
from lunad.daemon.publisher import Publisher
from lunad.daemon.reconnect import (
    BACKOFF_FIRST_S,
    RETRY_LOG_EVERY_S,
    VERSION_TIMEOUT_S,
    Reconnecting,
)
from lunad.daemon.reload import Reloading
from lunad.daemon.sources.base import Chunk, Source, open_source
from lunad.daemon.sources.recording import Recorder
from lunad.daemon.wakeup import Wakeup
from lunad.filters import Estimate, RangeFilter, Status
from lunad.protocol.frame import Frame
from lunad.protocol.messages import (
    encode_health,
    encode_range,
    new_run_id,
    range_ident,
    reasons_json,
    topic,
)
from lunad.protocol.parser import FrameParser

log = logging.getLogger("lunad.serve")

WAITING_AFTER_S = 1.0  # no bytes for this long: state waiting (the contract says within 2 s)
WAITING_PERIODS = 1.5  # ... or this many frame periods, whichever is longer (1 Hz: 1.5 s)
READ_SLICE_S = 5.0
"""Longest blocking read, seconds: a backstop only. Every timed duty (health, the
watchdog, reopening, the waiting state, the version query) is a
deadline that ends the read sooner, and stop, reload and subscriptions wake it; so a
silent sensor costs one wake-up per health message, no polling."""
NS = 1_000_000_000
_CONNECTED = State.CONNECTED
_DROPOUT = Status.DROPOUT


def _hz(rate_hz: float) -> str:
    """A frame rate for the log: 250, 166.7, 0.5."""
    return f"{rate_hz:.4g}"


class Daemon(Reconnecting, Reloading):
    """One sensor, one publisher, one loop.

    Args:
        cfg: validated configuration.
        config_path: the file SIGHUP re-reads (None: SIGHUP re-applies ``overrides``).
        overrides: the command-line values that keep overriding the file on reload.
        source_opener: opens the source (tests can pass another backend).
        notifier: systemd notification; from the environment by default.
    """

    def __init__(
        self,
        cfg: Config,
        config_path: Path | str | None = None,
        overrides: dict[str, Any] | None = None,
        source_opener: Callable[[SourceSection], Source] = open_source,
        notifier: Notifier | None = None,
    ) -> None:
        self.cfg = cfg
        self.config_path = config_path
        self.overrides = overrides or {}
        self._open = source_opener
        self.notifier = notifier or Notifier.from_env()
        self._wake = Wakeup()
        self._stopping = False
        self.exit_code = 0
        """What ``run`` returns: 0, or ``EX_UNAVAILABLE`` when it had to stop."""
        self._reload_requested = False
        self._source: Source | None = None
        self.pub: Publisher | None = None
        self.parser = FrameParser(cfg.sensor.frame_format, follow_format_replies=False)
        self.recorder: Recorder | None = None
        self.run_id = new_run_id()
        """This run's identity in every message (docs/messages.md: ``run``)."""
        self.seq = -1
        self._seq_sent = -1
        """``seq`` of the last range message sent: the next one summarises the frames
        after it (``frames``)."""
        self._unsent: tuple[Frame, float | None, Estimate, int] | None = None
        """``publish_hz``: the latest frame's estimate, until a publish time sends it."""
        self._reasons_json: dict[tuple[str, ...], bytes] = {}
        self.filter = RangeFilter(cfg.filter.to_filter_config())
        self._clock = FrameClock(cfg.sensor.frame_rate_hz, follow=cfg.source.timed_by_its_frames)
        """Measures the rate the sensor sends at; says which rate frames are timed by."""
        self._checksum_errors_seen = 0
        """Checksum errors already fed to ``_clock``: frames the sensor sent on its clock."""
        self._apply(cfg)

    def _apply(self, cfg: Config) -> None:
        """Take ``cfg`` into use; the filter keeps its state unless [filter] changed."""
        if cfg.filter != self.cfg.filter:
            self.filter = RangeFilter(cfg.filter.to_filter_config())
        self.cfg = cfg
        nominal, follow = self._sensor_rate_hz(), cfg.source.timed_by_its_frames
        if self._clock.nominal_hz != nominal or self._clock.follow != follow:
            self._clock = FrameClock(nominal, follow)
        self._set_frame_rate(self._clock.rate_hz)
        self._range_ident = range_ident(cfg.sensor.name, self.run_id)
        self._range_topic = topic("range", cfg.sensor.name)
        self._health_topic = topic("health", cfg.sensor.name)
        logging.getLogger("lunad").setLevel(cfg.log_level.upper())

    def _sensor_rate_hz(self) -> int:
        """The rate the sensor was set to, Hz: a replay's recorded one, else the
        configured one. The frame clock starts from it."""
        src = self._source
        return (src.frame_rate_hz if src is not None else None) or self.cfg.sensor.frame_rate_hz

    def _set_frame_rate(self, rate_hz: float) -> None:
        """Time the loop for a sensor sending ``rate_hz`` frames a second: the frame
        period that spaces a read's frames for the filter, the publish period (one
        frame period without ``publish_hz``) and the silence threshold."""
        cfg = self.cfg
        self._rate_hz = rate_hz
        self._frame_period_ns = int(NS / rate_hz)
        self._publish_period_ns = int(NS / (cfg.publish.publish_hz or rate_hz))
        self._waiting_after_ns = int(max(WAITING_AFTER_S, WAITING_PERIODS / rate_hz) * NS)

    # -- signals ------------------------------------------------------------

    def request_stop(self, signum: int | None = None, _frame: FrameType | None = None) -> None:
        """Ask the loop to stop and wake it; safe from a signal handler."""
        if signum is not None:
            log.info("received %s, stopping", signal.Signals(signum).name)
        self._stopping = True
        self._wake_loop()

    def request_reload(self, _signum: int | None = None, _frame: FrameType | None = None) -> None:
        """Ask the loop to re-read the config; safe from a signal handler."""
        self._reload_requested = True
        self._wake_loop()

    def install_signal_handlers(self) -> None:
        """SIGTERM/SIGINT stop cleanly, SIGHUP reloads the config."""
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)
        signal.signal(signal.SIGHUP, self.request_reload)

    def _wake_loop(self) -> None:
        self._wake.set()
        src = self._source
        if src is not None:
            src.cancel()

    # -- the loop -------------------------------------------------------------

    def run(self, publisher: Publisher) -> int:
        """Serve until asked to stop; returns the exit code (0)."""
        self.pub = publisher
        publisher.start_waker(self._wake_loop)
        now = time.monotonic_ns()
        health = self.health = Health(
            self.cfg.sensor.name,
            now,
            self.run_id,
            self.cfg.filter.to_filter_config(),
            self.cfg.filter.sets_noise_model,
        )
        self._next_health = now
        self._last_bytes = now
        self._backoff = BACKOFF_FIRST_S
        self._next_open = now
        self._version_deadline: int | None = None
        self._open_failures = 0
        self._last_retry_log = 0
        self._recovered_seen = 0
        self._last_recovered_log = -int(RETRY_LOG_EVERY_S * NS)
        self._next_publish = now
        self._tick_at = now
        self._unix_offset_ns = time.time_ns() - time.monotonic_ns()
        notifier = self.notifier
        wd = notifier.watchdog_interval_s
        wd_ns = int(wd * NS) if wd else None
        next_wd = now
        ready_sent = False
        if self.recorder is None:
            self.open_recorder()
        replay_waiting_logged = False
        log.info(
            "serving sensor %r from %s, publishing on %s%s",
            self.cfg.sensor.name,
            self._source_desc(),
            publisher.endpoint,
            f" at most {self.cfg.publish.publish_hz:g} times a second"
            if self.cfg.publish.publish_hz
            else "",
        )

        while not self._stopping:
            now = time.monotonic_ns()
            if self._reload_requested:
                self._reload_requested = False
                self._reload(now)
                if self._stopping:
                    break
            held = self.cfg.source.kind == "replay" and not self.pub.subscriptions
            if held and not replay_waiting_logged:
                log.info("replay waits for a subscriber before it starts")
                replay_waiting_logged = True
            if held and self._source is None and health.state is not State.WAITING:
                self._set_state(State.WAITING, now)
            if self._source is None and now >= self._next_open and not held:
                self._try_open(now)
            if not ready_sent:
                notifier.ready()
                ready_sent = True
            if now >= self._next_health:
                self._publish_health(now)
                self.pub.pump()
            elif self.pub.pending:
                self.pub.pump()
            now = time.monotonic_ns()
            if wd_ns is not None and now >= next_wd:
                notifier.watchdog()
                next_wd = now + wd_ns

            src = self._source
            deadlines = [self._next_health] + ([next_wd] if wd_ns is not None else [])
            if src is None:
                if not held:
                    deadlines.append(self._next_open)
                self._sleep_until(min(deadlines), now)
                continue
            if src.exhausted:
                log.info("end of %s", src)
                break
            if health.state is _CONNECTED:
                deadlines.append(self._last_bytes + self._waiting_after_ns)
            if self._version_deadline is not None:
                deadlines.append(self._version_deadline)
            until = min(now + int(READ_SLICE_S * NS), *deadlines)
            try:
                if self.cfg.publish.publish_hz:
                    got = self._read_folded(src, until)
                else:
                    got = self._read_each(src, until)
            except SourceLostError as exc:
                if self._stopping:
                    break
                self._lost(exc)
                continue
            self._after_read(got)

        if self._unsent is not None:  # frames folded since the last message (--publish-hz)
            self._send_unsent()  # at the end of a replay or a stop: sent
        self._drop_source()
        self.close_recorder()
        health.state = State.STOPPED  # the last health message: subscribers know it ended
        self._publish_health(time.monotonic_ns())  # sent by the publisher's linger at close
        notifier.stopping()
        self._wake.close()
        log.info(
            "stopped: %d frames published, %d checksum errors, %d bytes discarded",
            health.frames,
            self.parser.stats.checksum_errors,
            self.parser.stats.bytes_discarded,
        )
        return self.exit_code

    def _sleep_until(self, deadline_ns: int, now: int) -> None:
        self._wake.wait(max(0.0, (deadline_ns - now) / NS))

    def _read_each(self, src: Source, until_ns: int) -> bool:
        """Read and publish every frame until ``until_ns`` or a reason to look up.

        The inner loop of the daemon: while bytes flow it only reads, parses, filters
        and sends. It returns to the housekeeping loop at the deadline, on a read
        timeout or wake-up, on a stop/reload request, or a state change to report. New
        subscriptions are answered in here, between reads. True when any bytes came.

        A read of several frames (a backlog after this process stalled, a USB
        adapter's packet) gives the filter their times as the sensor sent them, a
        frame period apart and ending at the read, as ``_read_folded`` does; their
        messages keep the read time. Stamped alike, the first frame of a 0.1 s
        backlog came 0.1 s after the last one before it and the rest at ``dt = 0``:
        the filter took the stall's prediction error for noise, and after 4 % of
        such stalls its lux estimate went above 20 klux (docs/filter.md, "Gaps and
        stalls"). The period is the frame clock's (``_retime``): it returns here when
        that changes.
        """
        got = False
        read = src.read
        feed = self.parser.feed
        step = self._step
        send = self._send_range
        spacing = self._frame_period_ns
        clock_feed = self._clock.feed
        stats = self.parser.stats
        bad_seen = self._checksum_errors_seen
        pub = self.pub
        health = self.health
        assert pub is not None
        t_mono = monotonic_ns()
        while not (self._stopping or self._reload_requested):
            if pub.pending:
                pub.pump()  # here, not by leaving: a burst of socket events must not starve reads
                t_mono = monotonic_ns()
            left = until_ns - t_mono
            if left <= 0:
                break
            chunk = read(left / NS)
            if chunk is None:
                if pub.pending:
                    continue  # woken for a subscription, not a timeout
                break
            got = True
            data, t_read = chunk
            t_mono = self._last_bytes = monotonic_ns()  # a replay's chunks keep recorded times
            if self.recorder is not None:
                self._record(chunk)
            t_unix = t_read + self._unix_offset_ns
            items = feed(data, t_read)
            k = n = len(items)
            for item in items:
                k -= 1
                if type(item) is Frame:
                    raw_m = item.distance_m
                    send(item, raw_m, step(item, raw_m, t_read - k * spacing), t_read, t_unix)
                else:
                    n -= 1
                    self._on_reply(item)  # type: ignore[arg-type]
            if stats.checksum_errors != bad_seen:
                n += stats.checksum_errors - bad_seen
                bad_seen = stats.checksum_errors
            if n and clock_feed(t_read, n):
                self._retime()
                break
            if health.state is not _CONNECTED or self._version_deadline is not None:
                break
        self._checksum_errors_seen = bad_seen
        return got

    def _read_folded(self, src: Source, until_ns: int) -> bool:
        """Low-power inner loop (``publish_hz``): filter every frame, publish the latest.

        While the sensor streams, a source that buffers (``Source.buffers``: a serial
        port, a ``socket://`` one) is read at each publish time, and at least every half
        of the time after which the sensor counts as silent: the loop sleeps on a timer
        until then and takes what came, one wake-up per message. Sleeping in a
        read instead, even one the kernel holds for a message's worth of frames (the
        tty's VMIN), puts the loop on the port's wait queue, and the tty wakes it for
        every frame it receives before ``poll`` looks at VMIN: 250 wake-ups a second at
        250 Hz, and most of the full rate's CPU (docs/performance.md). Any other source
        (I2C, a replay) is read as it gives readings. Either way the loop filters every
        frame and publishes the last, at most ``publish_hz`` times a second.

        A message is due by its read's own time (``Chunk.t_mono_ns``), a publish period
        after the last message's read less half a frame: a replay's recorded time, so
        that it folds the frames as the live run did at any ``--speed``. The timer wakes
        a whole period after the last message's read, so that its read is due; a tick
        that read nothing new sends what is still unsent (the last frames before a
        stall), which a replay of the run may not.

        The frames of one read arrived a frame period apart, so the filter gets them
        spaced so, ending at the read time; their messages keep the read time (the
        contract's ``t_mono_ns``). Stamped all alike, the filter would see four frames
        in five at ``dt = 0``, and the lux estimate would learn from one in five. The
        period is the frame clock's: when that changes (``_retime``) this returns.

        While the sensor is silent it blocks in the read instead: no wake-ups at
        ``publish_hz``. Returns to the housekeeping loop at ``until_ns`` or as
        ``_read_each`` does.
        """
        got = False
        pub = self.pub
        health = self.health
        assert pub is not None
        wait = self._wake.wait
        feed = self.parser.feed
        filter_step = self.filter.step
        clock_feed = self._clock.feed
        stats = self.parser.stats
        bad_seen = self._checksum_errors_seen
        retimed = False
        period = self._publish_period_ns
        spacing = self._frame_period_ns
        ticking = src.buffers
        half_silence = self._waiting_after_ns // 2
        while not (self._stopping or self._reload_requested):
            if pub.pending:
                pub.pump()
            now = monotonic_ns()
            if ticking and health.state is _CONNECTED:
                tick = self._tick_at
                if tick > now + half_silence:  # read before the sensor would seem silent
                    tick = now + half_silence
                if tick > until_ns:
                    tick = until_ns
                if tick > now and wait((tick - now) / NS):
                    continue  # woken for a stop, a reload or a subscription
                chunk = src.read(0.0)
            elif until_ns > now:
                chunk = src.read((until_ns - now) / NS)
            else:
                break
            now = monotonic_ns()
            due = False
            if ticking and now >= self._tick_at:
                self._tick_at = max(self._tick_at + period, now)
                due = chunk is None and now >= self._next_publish  # nothing new: send the rest
            if chunk is not None:
                got = True
                data, t_mono = chunk
                self._last_bytes = now  # not t_mono: a replay's chunks keep recorded times
                if self.recorder is not None:
                    self._record(chunk)
                items = feed(data, t_mono)
                t = t_mono - len(items) * spacing
                n = dropouts = 0
                for item in items:
                    t += spacing
                    if type(item) is Frame:
                        raw_m = item.distance_m
                        est = filter_step(raw_m, item.amp, t)
                        if est.status is _DROPOUT:
                            dropouts += 1
                        n += 1
                        last = item
                    else:
                        self._on_reply(item)  # type: ignore[arg-type]
                if n:  # counted once a read, not per frame as ``_step`` does
                    self.seq += n
                    health.frames += n
                    health.dropouts += dropouts
                    self._unsent = (last, raw_m, est, t_mono)
                if stats.checksum_errors != bad_seen:
                    n += stats.checksum_errors - bad_seen
                    bad_seen = stats.checksum_errors
                if n:
                    retimed = clock_feed(t_mono, n)
                due = t_mono >= self._next_publish
            if due and self._unsent is not None:
                t_read = self._send_unsent()
                # a period from this message, less half a frame of jitter; a timer wakes
                # for the next one a whole period on, so that its read is due
                self._next_publish = t_read + period - spacing // 2
                if ticking:
                    self._tick_at = t_read + period
            if retimed:
                self._retime()
                break
            if chunk is not None and (
                health.state is not _CONNECTED or self._version_deadline is not None
            ):
                break
            if now >= until_ns:
                break
        self._checksum_errors_seen = bad_seen
        return got

    def _retime(self) -> None:
        """The frame clock's verdict changed: time frames by its rate, and say so once.

        A serial sensor, and a replay of one, is timed by the rate it sends at; an I2C
        sensor keeps the configured one (the source triggers it on that schedule), and
        a disagreement is only logged.
        """
        clock = self._clock
        sensor, nominal = _hz(clock.sensor_hz), _hz(clock.nominal_hz)
        if clock.follow:
            if self.cfg.source.kind == "replay":
                said = f"{self._source_desc()}: its sensor sends"
                asked = f"the {nominal} its recording gives"
                again = f"the {nominal} frames a second its recording gives again"
            else:
                said = "the sensor sends"
                asked = f"the configured {nominal}"
                again = f"the configured {nominal} frames a second again"
            if clock.differs:
                log.warning(
                    "%s %s frames a second, not %s; timing frames by %s",
                    said,
                    sensor,
                    asked,
                    sensor,
                )
            else:
                log.info("%s %s; timing frames by %s", said, again, nominal)
            self._set_frame_rate(clock.rate_hz)
            return
        if clock.differs:
            log.warning(
                "%s: frames come %s a second, not %s; timing frames by %s, the rate it is "
                "triggered at",
                self._source_desc(),
                sensor,
                nominal,
                nominal,
            )
        else:
            log.info(
                "%s: frames come %s a second again, the rate it is triggered at",
                self._source_desc(),
                nominal,
            )

    def _step(self, frame: Frame, raw_m: float | None, t_mono_ns: int) -> Estimate:
        """Filter one frame (``raw_m``: its distance, metres; taken at ``t_mono_ns``)
        and count it."""
        self.seq += 1
        est = self.filter.step(raw_m, frame.amp, t_mono_ns)
        health = self.health
        health.frames += 1
        if est.status is _DROPOUT:
            health.dropouts += 1
        return est

    def _send_unsent(self) -> int:
        """Publish the estimate ``--publish-hz`` folded since the last message (the last
        frame of the reads since, ``_unsent``); returns its read time, monotonic ns."""
        unsent = self._unsent
        assert unsent is not None
        self._unsent = None
        frame, raw_m, est, t_read = unsent
        self._send_range(frame, raw_m, est, t_read, t_read + self._unix_offset_ns)
        return t_read

    def _send_range(
        self, frame: Frame, raw_m: float | None, est: Estimate, t_mono_ns: int, t_unix_ns: int
    ) -> None:
        """Publish ``est`` of ``frame`` (``raw_m``: its distance, metres) as ``range``."""
        range_m, sigma_m, lux_est, strength, status, reasons, zone = est
        reasons_js = self._reasons_json.get(reasons)
        if reasons_js is None:
            reasons_js = self._reasons_json[reasons] = reasons_json(reasons)
        seq = self.seq
        frames = seq - self._seq_sent
        self._seq_sent = seq
        payload = encode_range(
            self._range_ident,
            seq,
            frames,
            t_mono_ns,
            t_unix_ns,
            raw_m,
            frame.amp,
            frame.temp_c,
            strength,
            range_m,
            sigma_m,
            lux_est,
            status,
            reasons_js,
            zone,
        )
        self.pub.send(self._range_topic, payload)  # type: ignore[union-attr]

    def _after_read(self, got: bool) -> None:
        now = time.monotonic_ns()
        health = self.health
        if got and health.state is not State.CONNECTED:
            log.info("data arriving from %s", self._source_desc())
            self._set_state(State.CONNECTED, now)
        elif health.state is State.CONNECTED and now - self._last_bytes > self._waiting_after_ns:
            log.warning(
                "no data from %s for %.1f s", self._source_desc(), self._waiting_after_ns / NS
            )
            self._set_state(State.WAITING, now)
        if self._version_deadline is not None:
            if health.firmware is not None:
                self._version_deadline = None
            elif now >= self._version_deadline:
                log.warning(
                    "sensor on %s did not answer the version query within %.1f s; "
                    "carrying on with whatever data arrives",
                    self._source_desc(),
                    VERSION_TIMEOUT_S,
                )
                self._version_deadline = None

    # -- housekeeping ---------------------------------------------------------

    def _set_state(self, state: State, now: int) -> None:
        if self.health.state is not state:
            self.health.state = state
            self._next_health = now

    # -- recording ------------------------------------------------------------

    def open_recorder(self) -> None:
        """Start recording every byte read to ``source.record``, when it is set.
        ``lunad serve`` calls it before binding, so that a bad path stops it there.

        Raises:
            ConfigError: the file cannot be opened or is not a recording; names the field.
        """
        self.recorder = self._new_recorder(self.cfg)

    def _new_recorder(self, cfg: Config) -> Recorder | None:
        path = cfg.source.record
        if not path:
            return None
        try:
            recorder = Recorder(
                path, source_desc=self._source_desc(cfg), frame_rate_hz=cfg.sensor.frame_rate_hz
            )
        except (OSError, ValueError) as exc:  # RecordFormatError is a ValueError
            raise ConfigError(f"source.record (--record): cannot record to {path}: {exc}") from None
        log.info("recording every byte read to %s", path)
        return recorder

    def _record(self, chunk: Chunk) -> None:
        """Append ``chunk`` to the recording. A failed write (a full or removed card)
        ends the recording, not the daemon: the readings matter more than their copy.
        The file keeps every record before it; a SIGHUP starts recording again."""
        recorder = self.recorder
        assert recorder is not None
        try:
            recorder(chunk)
        except (OSError, ValueError) as exc:
            note = f"recording to {recorder.path} stopped: {exc}"
            log.error("%s; serving goes on, SIGHUP to record again", note)
            self.health.last_error = note
            self.close_recorder()

    def close_recorder(self) -> None:
        """Stop recording (fsync and close); safe to call twice."""
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            try:
                recorder.close()
            except OSError as exc:
                log.warning("closing the recording %s: %s", recorder.path, exc)

    def _publish_health(self, now: int) -> None:
        pub = self.pub
        assert pub is not None
        self._unix_offset_ns = time.time_ns() - time.monotonic_ns()
        if self._source is not None:
            self._note_recovered_faults(self._source, now)
        msg = self.health.message(self.parser.stats, pub.dropped_sends, now, self._rate_hz)
        pub.send(self._health_topic, encode_health(msg))
        self._next_health = now + int(self.cfg.publish.health_interval_s * NS)
        clock = self._clock
        self.notifier.status(
            f"{msg.state}, {msg.fps:.1f} fps, dropout {msg.dropout_ratio:.1%}, "
            f"{msg.frames} frames, {msg.checksum_errors} checksum errors"
            + (f", sensor at {_hz(clock.sensor_hz)} Hz" if clock.differs else "")
        )
