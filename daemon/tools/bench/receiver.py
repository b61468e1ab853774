"""The bench's subscriber: a process of its own that timestamps every message.

Run by ``rounds.run_serve_once`` as ``python -m lunad.daemon.tools.bench receive``. Like
the floor it imports nothing of lunad at the top, so it starts quickly.
"""

from __future__ import annotations

from lunad.daemon.tools.bench.floor import exit_on


def receiver_main(argv: list[str] | None = None) -> int:
    """The bench's subscriber, in a process of its own so that its receive times do
    not wait for the GIL of the process that plays the sensor.

    Run as ``python -m lunad.daemon.tools.bench receive --connect ENDPOINT --out FILE``.
    Prints the monotonic time of the first message on stdout; on SIGTERM or SIGINT writes
    every message's ``seq`` and receive time (``time.monotonic_ns()``, the same
    clock the sensor's send times use) to FILE as int64 pairs, and exits 0.
    """
    import argparse
    import array
    import signal
    import time

    import zmq

    p = argparse.ArgumentParser(prog="python -m lunad.daemon.tools.bench receive")
    p.add_argument("--connect", required=True)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)

    exit_on(signal.SIGTERM, signal.SIGINT)  # SIGINT: Ctrl-C reaches the whole group
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.RECONNECT_IVL, 5)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"range/")
    sub.connect(args.connect)
    records = array.array("q")
    recv = sub.recv_multipart
    mono = time.monotonic_ns
    try:
        parts = recv()
        t = mono()
        records.extend((seq_of(parts[1]), t))
        print(t, flush=True)
        while True:
            parts = recv()
            t = mono()
            records.extend((seq_of(parts[1]), t))
    except SystemExit:
        pass
    finally:
        with open(args.out, "wb") as f:
            records.tofile(f)
        sub.close()
        ctx.term()
    return 0


def seq_of(payload: bytes) -> int:
    """The ``seq`` of a range message's JSON payload, read without parsing the JSON."""
    i = payload.index(b'"seq":') + 6
    j = i
    while 48 <= payload[j] <= 57:
        j += 1
    return int(payload[i:j])
