"""``lunad serve``: the daemon."""

from __future__ import annotations

import argparse
import gc
import sys
from typing import Any

from lunad.daemon.cli.source_args import add_source_args, source_overrides

DESCRIPTION = """\
Read a TF-Luna, clean every reading and publish it over ZeroMQ.

Each parsed frame becomes one message on topic range/<sensor>/; health/<sensor>/
follows about once a second and at every state change. The daemon keeps running
through garbage on the line, unplug/replug and a silent sensor, and reports them
on health. Flags override the config file. A bad file or flag exits with code 78.
"""

EPILOG = """\
examples:
  lunad serve --device /dev/serial0
  lunad serve --device /dev/ttyUSB0 --publish ipc:///run/lunad/front.sock --name front
  lunad serve --config /etc/lunad/front.toml
  lunad serve --device spy:///dev/ttyUSB0     # pyserial URL: hex dump of the traffic
  lunad serve --bus 1 --address 0x10          # TF-Luna wired for I2C (pin 5 to GND)
  lunad serve --replay field.lunarec --speed max   # replay a recording (lunad record)
  lunad serve --device /dev/serial0 --publish-hz 50   # low-power publishing
  lunad serve --device /dev/serial0 --publish tcp://0.0.0.0:7781 \\
      --curve-secret-key /etc/lunad/curve/server.key_secret \\
      --curve-clients /etc/lunad/curve/clients   # encrypted, for listed clients only

A TCP endpoint other hosts can reach is clear text unless CURVE is set (lunad keys
makes the keys; docs/security.md). The client keys directory is re-read when it
changes; the server key is read when the endpoint is bound.

SIGHUP re-reads the config file; a bad new config is refused and the old one stays.
Under systemd (Type=notify) it sends READY=1, STATUS=, WATCHDOG=1 and STOPPING=1.
"""


def add_parser(sub: Any) -> None:
    """Register ``serve``."""
    p = sub.add_parser(
        "serve",
        help="run the daemon",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.usage_exit_code = 78
    add_source_args(p)
    p.add_argument("--replay", metavar="FILE", help="replay a recording instead of a sensor")
    p.add_argument("--speed", help="replay speed factor, 0.01 to 1000, or 'max' (default 1)")
    p.add_argument("--record", metavar="FILE", help="also record every byte read to FILE")
    p.add_argument("--publish", metavar="ENDPOINT", help="ZeroMQ endpoint to bind")
    p.add_argument("--name", help="sensor name used in topics (default tfluna)")
    p.add_argument(
        "--publish-hz",
        metavar="N",
        help="low-power mode: read and filter every frame, publish at most N times a second",
    )
    p.add_argument(
        "--curve-secret-key",
        metavar="FILE",
        help="CURVE: the server's secret key file (lunad keys server); tcp:// only",
    )
    p.add_argument(
        "--curve-clients",
        metavar="DIR",
        help="CURVE: directory of the client public keys (*.key) to admit",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Validate the config, bind, and serve until SIGTERM/SIGINT.

    Signals that come while it starts are noted by ``StartupSignals`` (installed by
    ``lunad.daemon.cli.main.main`` before anything slow) and acted on once the daemon's own
    handlers are in place: a SIGTERM or SIGINT stops it (exit 0), a SIGHUP that came
    while the config was being read has it read again.
    """
    from lunad.daemon.cli.signals import StartupSignals

    startup: StartupSignals = getattr(args, "startup_signals", None) or StartupSignals()
    reloads_before_reading = startup.reloads

    from lunad.daemon.config import load_config
    from lunad.daemon.errors import EX_CONFIG, EX_UNAVAILABLE, ConfigError, PublishError

    try:
        overrides: dict[str, Any] = {
            **source_overrides(args),
            "source.path": args.replay,
            "source.speed": args.speed,
            "source.record": args.record,
            "publish.endpoint": args.publish,
            "publish.publish_hz": args.publish_hz,
            "publish.curve_secret_key": args.curve_secret_key,
            "publish.curve_clients": args.curve_clients,
            "sensor.name": args.name,
        }
        cfg = load_config(args.config, overrides)
        if cfg.source.kind == "replay":
            from lunad.daemon.sources.replay import check_replay

            check_replay(cfg.source)
    except ConfigError as exc:
        print(f"lunad serve: {exc}", file=sys.stderr)
        return EX_CONFIG

    from lunad.daemon.cli.main import setup_logging
    from lunad.daemon.publisher import Publisher
    from lunad.daemon.serve import Daemon

    setup_logging(cfg.log_level)
    if startup.stop is not None:
        _stopped_while_starting(startup.stop)
        return 0
    daemon = Daemon(cfg, args.config, overrides)
    try:
        daemon.open_recorder()
    except ConfigError as exc:
        print(f"lunad serve: {exc}", file=sys.stderr)
        return EX_CONFIG
    daemon.install_signal_handlers()
    # From here the daemon's handlers take every signal; what came before is in startup.
    if startup.stop is not None:
        daemon.request_stop(startup.stop)
    elif startup.reloads > reloads_before_reading:
        daemon.request_reload()
    try:
        publisher = Publisher(
            cfg.publish.endpoint,
            cfg.publish.sndhwm,
            cfg.filter.to_filter_config().stale_after_s,
            curve=cfg.publish.curve,
        )
    except PublishError as exc:
        daemon.close_recorder()
        print(f"lunad serve: {exc}", file=sys.stderr)
        return EX_UNAVAILABLE
    # Start-up's ~30k objects (modules, pydantic schemas, the config) stay for the life
    # of the process: frozen, no collection walks them again, the one at exit included,
    # which made stopping 3-4x quicker (docs/performance.md, "Stopping").
    gc.freeze()
    try:
        return daemon.run(publisher)
    finally:
        publisher.close()
        if daemon.pub is not None and daemon.pub is not publisher:
            daemon.pub.close()  # a SIGHUP's new endpoint


def _stopped_while_starting(signum: int) -> None:
    """Log a stop that came before anything was opened or bound."""
    import logging
    import signal

    logging.getLogger("lunad.serve").info(
        "received %s while starting, stopping before serving", signal.Signals(signum).name
    )
