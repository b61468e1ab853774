"""The floor: what any Python program must spend to do ``lunad serve``'s job at all.

Blocking ``os.read`` on the tty, a checksum per frame and a small JSON message per
frame on a ZeroMQ PUB socket, no filter, no health, no reconnects. ``lunad / floor`` is
the overhead of everything else we do (``rounds.bench_serve`` runs both the same way).
It imports nothing of lunad (not even ``lunad.protocol``, whose package import pulls in
pydantic), so its RSS and start-up are the floor's too: this package's modules import
only the standard library at the top, and

    python -m lunad.daemon.tools.bench --device PATH --publish ENDPOINT

loads only os, termios and zmq besides.
"""

from __future__ import annotations

import os
import sys
from typing import Any

FLOOR_TOPIC = b"range/floor"
# set_output_enabled(True) from lunad.protocol.commands: 5A Len=05 ID=07 payload 01, CS.
# Spelled out so that the floor does not import lunad.protocol (and with it pydantic);
# tests/test_bench.py checks it against the encoder.
OUTPUT_ON = bytes((0x5A, 0x05, 0x07, 0x01, (0x5A + 0x05 + 0x07 + 0x01) & 0xFF))


def exit_on(*signums: int) -> None:
    """Make these signals raise SystemExit(0) in the main thread (clean exit, finally runs)."""
    import signal

    def stop(_signum: int, _frame: Any) -> None:
        raise SystemExit(0)

    for signum in signums:
        signal.signal(signum, stop)


def floor_main(argv: list[str] | None = None) -> int:
    """The floor: read the tty with blocking reads, check checksums, publish each frame.

    Run as ``python -m lunad.daemon.tools.bench --device PATH --publish ENDPOINT``; stops on
    SIGTERM or SIGINT. Each message is ``range/floor`` and
    ``{"seq":N,"dist":D,"amp":A,"temp_raw":T}``.
    """
    import argparse
    import signal
    import termios
    import tty

    import zmq

    p = argparse.ArgumentParser(prog="python -m lunad.daemon.tools.bench", description="floor loop")
    p.add_argument("--device", required=True)
    p.add_argument("--publish", required=True)
    args = p.parse_args(argv)

    exit_on(signal.SIGTERM, signal.SIGINT)

    try:  # the device first: a missing one leaves no bound socket file behind
        fd = os.open(args.device, os.O_RDWR | os.O_NOCTTY)
    except OSError as exc:
        print(f"floor: {exc}", file=sys.stderr)
        return 1
    try:
        tty.setraw(fd)
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        os.write(fd, OUTPUT_ON)
    except (OSError, termios.error) as exc:
        os.close(fd)
        print(f"floor: {args.device} is not a serial port: {exc}", file=sys.stderr)
        return 1
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.bind(args.publish)

    send = sock.send_multipart
    noblock = zmq.NOBLOCK
    topic = FLOOR_TOPIC
    buf = b""
    seq = 0
    try:
        while True:
            buf += os.read(fd, 4096)
            i = buf.find(b"YY")
            while i >= 0 and len(buf) - i >= 9:
                if sum(buf[i : i + 8]) & 0xFF == buf[i + 8]:
                    msg = b'{"seq":%d,"dist":%d,"amp":%d,"temp_raw":%d}' % (
                        seq,
                        buf[i + 2] | buf[i + 3] << 8,
                        buf[i + 4] | buf[i + 5] << 8,
                        buf[i + 6] | buf[i + 7] << 8,
                    )
                    seq += 1
                    try:
                        send((topic, msg), noblock)
                    except zmq.Again:
                        pass
                    i = buf.find(b"YY", i + 9)
                else:
                    i = buf.find(b"YY", i + 1)
            buf = buf[i:] if i >= 0 else buf[-1:]
    except SystemExit:
        return 0
    finally:
        os.close(fd)
        sock.close()
        ctx.term()
