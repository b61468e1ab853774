"""SIGHUP: re-read the config and take it into use while serving.

A bad new config is refused and the running one stays. A new publish endpoint is bound
before the old socket closes, so subscribers of an unchanged endpoint lose nothing; a
new recording file is opened before the old one closes; the source is reopened only
when the port or the sensor changed (a new port's tries start afresh), and a replay's
new speed paces the rest of its file from where it is.

``Reloading`` is a part of ``serve.Daemon`` (a base class of it): its methods run on the
daemon's state, from the loop's housekeeping, never per frame.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lunad.daemon.config import Config, ConfigError, SourceSection, load_config
from lunad.daemon.errors import EX_UNAVAILABLE, PublishError
from lunad.daemon.health import Health
from lunad.daemon.notify import Notifier
from lunad.daemon.publisher import Publisher
from lunad.daemon.reconnect import BACKOFF_FIRST_S
from lunad.daemon.sources.base import Source
from lunad.daemon.sources.recording import Recorder
from lunad.daemon.sources.replay import ReplaySource, check_replay

log = logging.getLogger("lunad.serve")


def _same_but(new: SourceSection, old: SourceSection, *fields: str) -> bool:
    """Whether the [source] ``new`` is ``old`` but for ``fields``."""
    return new.model_copy(update={f: getattr(old, f) for f in fields}) == old


def _changed(new: Config, old: Config, name: str) -> bool:
    """Whether a reload changes the section (or setting) ``name``; [source]'s
    ``rate_hz`` is [sensor]'s ``frame_rate_hz`` copied, and counts there."""
    if name == "source":
        return not _same_but(new.source, old.source, "rate_hz")
    return bool(getattr(new, name) != getattr(old, name))


def _same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """True when both paths name one existing file (a symlink, ``./x`` and ``x``)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


class Reloading:
    """The SIGHUP reload of a ``Daemon``: ``_reload`` and the rebinding it may need."""

    # The daemon's state these methods use; ``Daemon.__init__`` and ``Daemon.run`` set it.
    cfg: Config
    config_path: Path | str | None
    overrides: dict[str, Any]
    notifier: Notifier
    health: Health
    pub: Publisher | None
    recorder: Recorder | None
    _source: Source | None
    exit_code: int
    _stopping: bool
    _next_open: int
    _open_failures: int
    _backoff: float
    _next_health: int

    if TYPE_CHECKING:  # defined by Daemon and Reconnecting

        def _apply(self, cfg: Config) -> None: ...

        def _new_recorder(self, cfg: Config) -> Recorder | None: ...

        def close_recorder(self) -> None: ...

        def _drop_source(self) -> None: ...

        def _wake_loop(self) -> None: ...

    def _reload(self, now: int) -> None:
        """Re-read the config (SIGHUP); a bad one is refused and the old one stays."""
        self.notifier.reloading()
        where = self.config_path or "the command line"
        try:
            new = load_config(self.config_path, self.overrides)
            if new.source.kind == "replay" and new.source != self.cfg.source:
                check_replay(new.source)
        except ConfigError as exc:
            log.error("SIGHUP: keeping the running configuration: %s", exc)
            self.notifier.ready()
            return
        old = self.cfg
        changed = [
            name
            for name in ("sensor", "source", "publish", "filter", "log_level")
            if _changed(new, old, name)
        ]
        recorder = self.recorder
        wanted = new.source.record
        moved = wanted != old.source.record and not (
            recorder is not None and wanted is not None and _same_file(wanted, recorder.path)
        )
        if moved or (recorder is None and wanted):
            try:
                recorder = self._new_recorder(new)
            except ConfigError as exc:
                log.error("SIGHUP: keeping the running configuration: %s", exc)
                self.notifier.ready()
                return
        rebind = ("endpoint", "sndhwm", "curve")
        if any(getattr(new.publish, k) != getattr(old.publish, k) for k in rebind):
            try:
                self._rebind(new, old)
            except PublishError as exc:
                if recorder is not self.recorder and recorder is not None:
                    recorder.close()
                if self.pub is None:
                    log.critical("SIGHUP: %s; cannot publish on any endpoint, stopping", exc)
                    self._stopping = True
                    self.exit_code = EX_UNAVAILABLE  # systemd restarts it on a failure
                    return
                log.error("SIGHUP: keeping the running configuration: %s", exc)
                self.notifier.ready()
                return
        if recorder is not self.recorder:
            self.close_recorder()
            self.recorder = recorder
        self._apply(new)
        self.health.filter_config = new.filter.to_filter_config()
        self.health.noise_configured = new.filter.sets_noise_model
        self.health.sensor = new.sensor.name
        same_port = _same_but(new.source, old.source, "record")
        src = self._source
        if (
            not same_port
            and isinstance(src, ReplaySource)
            and new.sensor == old.sensor
            and _same_but(new.source, old.source, "record", "speed")
        ):
            src.set_speed(new.source.speed)  # the replay goes on from where it is
            log.info("SIGHUP: %s", src)
        elif not same_port or new.sensor != old.sensor:  # a new recording keeps the port open
            self._drop_source()
            self._next_open = now
            if not same_port:  # the old port's failures are not the new one's
                self._open_failures = 0
                self._backoff = BACKOFF_FIRST_S
                self.health.last_error = None
        log.info(
            "SIGHUP: configuration reloaded from %s (changed: %s)",
            where,
            ", ".join(changed) or "nothing",
        )
        self._next_health = now
        self.notifier.ready()

    def _rebind(self, new: Config, old: Config) -> None:
        """Publish on ``new``'s endpoint and high-water mark from now on.

        The new socket is bound before the old one closes, so subscribers of an
        unchanged endpoint lose nothing. When that bind fails, the address may be the
        running socket's own (the same TCP port with another ``sndhwm``, or ``*`` for
        ``127.0.0.1``): the old socket is closed and the bind tried once more. If that
        fails too, the old endpoint is bound back.

        Raises:
            PublishError: the new endpoint cannot be bound; the old one is in use again,
                or, if even that failed, ``pub`` is None.
        """
        old_pub = self.pub
        try:
            pub = self._publisher(new)
        except PublishError:
            if old_pub is None:
                raise
            old_pub.close()
            self.pub = None
            try:
                pub = self._publisher(new)
            except PublishError:
                self.pub = self._publisher(old)
                self.pub.start_waker(self._wake_loop)
                raise
            old_pub = None
        self.pub = pub
        pub.start_waker(self._wake_loop)
        if old_pub is not None:
            old_pub.close()

    def _publisher(self, cfg: Config) -> Publisher:
        """A publisher bound as ``cfg`` says, CURVE included (a rebind that left it
        out would publish in clear text)."""
        p = cfg.publish
        return Publisher(p.endpoint, p.sndhwm, self._stale_after_s(cfg), curve=p.curve)

    @staticmethod
    def _stale_after_s(cfg: Config) -> float:
        """After how long a cached range is replayed as stale, seconds ([filter])."""
        return cfg.filter.to_filter_config().stale_after_s
