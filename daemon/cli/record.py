"""``lunad record``: save a sensor's raw byte stream with read times, for replay."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import threading
import time
from typing import Any

from lunad.daemon.cli.source_args import add_source_args, source_overrides

log = logging.getLogger("lunad.record")

DESCRIPTION = """\
Record everything a sensor sends, byte for byte, with the time each chunk was read.
The file format is versioned and append-only; a power cut costs at most the last
second, and a torn last record is skipped on replay. It keeps the frame rate the
sensor was set to (--rate), by which a replay spaces the frames of one read. Replay it
through the very parser and filter the daemon uses with `lunad serve --replay FILE`.

Recording while the daemon runs: use `lunad serve --record FILE` instead (a port
opens exclusively, so the two cannot share it). A file takes one writer at a time:
one that another `lunad record` or `lunad serve --record` is writing is refused.

A sensor that is absent or unplugged is waited for, as the daemon does. A port that
another process holds (usually the daemon: `sudo systemctl stop lunad@NAME` first) is
not: one line names the port, its holder and how to stop it, and the --out file is
removed if this run created it and recorded nothing into it.

Exit codes: 0 when stopped by SIGINT/SIGTERM or --duration; 69 when the port is in
use by another process; 78 for a bad option, config, or --out (not a recording,
cannot be created, being recorded already); 74 when the recording cannot be written
any more (disk full, card removed), after one line saying why: every chunk recorded
before it is kept.
"""

EPILOG = """\
examples:
  lunad record --device /dev/serial0 --out field.lunarec
  lunad record --device /dev/ttyUSB0 --rate 250 --duration 60 --out sun-test.lunarec
  lunad record --bus 1 --out i2c.lunarec
  lunad serve --replay field.lunarec --speed max     # then: lunad watch
"""

BACKOFF_MAX_S = 2.0


def add_parser(sub: Any) -> None:
    """Register ``record``."""
    p = sub.add_parser(
        "record",
        help="record a sensor's raw byte stream",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.usage_exit_code = 78
    add_source_args(p)
    p.add_argument("--out", required=True, metavar="FILE", help="recording to write or extend")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Record until SIGINT/SIGTERM or ``--duration``; reconnects like the daemon."""
    from lunad.daemon.cli.main import setup_logging
    from lunad.daemon.config import load_config
    from lunad.daemon.errors import (
        EX_CONFIG,
        EX_IOERR,
        EX_UNAVAILABLE,
        ConfigError,
        LunadError,
        SourceLostError,
        SourceOpenError,
    )
    from lunad.daemon.reconnect import RETRY_LOG_EVERY_S
    from lunad.daemon.sources.base import Source, open_source
    from lunad.daemon.sources.recording import Recorder
    from lunad.daemon.sources.serial import PortBusyError
    from lunad.protocol import commands

    try:
        cfg = load_config(args.config, source_overrides(args))
    except ConfigError as exc:
        print(f"lunad record: {exc}", file=sys.stderr)
        return EX_CONFIG
    setup_logging(cfg.log_level)
    stop = threading.Event()
    src: Source | None = None

    def on_signal(*_: object) -> None:
        stop.set()
        if src is not None:
            src.cancel()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    startup = getattr(args, "startup_signals", None)
    if startup is not None and startup.stopped("lunad record"):
        return 0  # before --out is touched
    deadline = None if args.duration is None else time.monotonic() + args.duration
    backoff = 0.1
    failures = 0  # opens that failed in a row
    said_at = 0.0  # when the last of them was logged (monotonic seconds)
    created = not os.path.lexists(args.out)  # an empty file of ours is removed on a busy port
    try:
        rec = Recorder(
            args.out,
            source_desc=cfg.source.description,
            frame_rate_hz=cfg.sensor.frame_rate_hz,
        )
    except (LunadError, OSError, ValueError) as exc:
        print(f"lunad record: --out: {exc}", file=sys.stderr)
        return EX_CONFIG
    write_error: OSError | None = None
    busy: PortBusyError | None = None
    startup = b""
    try:
        while not stop.is_set():
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                break
            if src is None:
                try:
                    src = open_source(cfg.source)
                except PortBusyError as exc:  # its holder keeps it: waiting would record nothing
                    busy = exc
                    break
                except SourceOpenError as exc:  # said once, then once a RETRY_LOG_EVERY_S
                    failures += 1
                    now = time.monotonic()
                    if failures == 1:
                        log.warning("%s; retrying every %.1f s at most", exc, BACKOFF_MAX_S)
                        said_at = now
                    elif now - said_at >= RETRY_LOG_EVERY_S:
                        log.warning("still cannot open it after %d tries: %s", failures, exc)
                        said_at = now
                    stop.wait(min(backoff, left or backoff))
                    backoff = min(backoff * 2, BACKOFF_MAX_S)
                    continue
                log.info(
                    "recording %s to %s%s",
                    src,
                    args.out,
                    f" after {failures} failed tries" if failures else "",
                )
                failures = 0
                startup = (
                    commands.startup(cfg.sensor.frame_rate_hz, cfg.sensor.frame_format)
                    if cfg.sensor.configure
                    else b""
                )
            try:
                if startup:
                    src.write(startup)
                    startup = b""
                chunk = src.read(min(0.5, left) if left is not None else 0.5)
            except SourceLostError as exc:
                log.warning("lost the source: %s; reconnecting in %.1f s", exc, backoff)
                src.close()
                src = None
                stop.wait(min(backoff, left or backoff))  # a port that fails at once: no spin
                backoff = min(backoff * 2, BACKOFF_MAX_S)
                continue
            if chunk is not None:
                backoff = 0.1
                try:
                    rec(chunk)
                except OSError as exc:
                    write_error = exc
                    break
    finally:
        if src is not None:
            src.close()
        if busy is not None and created and rec.records == 0:
            with contextlib.suppress(OSError):  # unlinked while our lock still holds it
                os.unlink(args.out)
        try:
            rec.close()
        except OSError as exc:  # the final fsync: the card went while recording
            write_error = write_error or exc
    if busy is not None:
        kept = f" ({rec.records} chunks kept in {args.out})" if rec.records else ""
        print(f"lunad record: {busy}{kept}", file=sys.stderr)
        return EX_UNAVAILABLE
    if write_error is not None:
        print(
            f"lunad record: writing {args.out} failed: {write_error} ({rec.records} chunks kept)",
            file=sys.stderr,
        )
        return EX_IOERR
    print(f"recorded {rec.records} chunks, {rec.bytes} bytes to {args.out}")
    return 0
