"""The subscriber client against a real PUB socket: typed messages, gaps, restarts, junk."""

from __future__ import annotations

import time
from pathlib import Path

import zmq

from lunad.protocol.client import Subscriber
from lunad.protocol.messages import RangeMessage, encode_range, topic


def msg(seq: int) -> bytes:
    return encode_range(
        b'"c"', seq, 1, 2, 1.0, 500, 30.0, 0.25, 1.0, 0.01, 10.0, "ok", b"[]", "stable"
    )


def test_gaps_restarts_and_bad_messages(tmp_path: Path) -> None:
    ep = f"ipc://{tmp_path}/c.sock"
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.bind(ep)
    try:
        with Subscriber(ep, sensor="c") as sub:
            deadline = time.monotonic() + 5
            first = None
            while first is None and time.monotonic() < deadline:  # slow-joiner handshake
                pub.send_multipart([topic("range", "c"), msg(0)])
                first = sub.recv(timeout_s=0.05)
            assert isinstance(first, RangeMessage)
            while sub.recv(timeout_s=0.1) is not None:
                pass
            sub.last_seq = 0
            for seq in (1, 2, 5, 6):
                pub.send_multipart([topic("range", "c"), msg(seq)])
            pub.send_multipart([topic("range", "c"), b"{not json"])
            pub.send_multipart([topic("range", "other"), msg(99)])
            pub.send_multipart([topic("range", "c"), msg(0)])  # daemon restarted
            pub.send_multipart([topic("range", "c"), msg(1)])
            got = []
            while (m := sub.recv(timeout_s=0.3)) is not None:
                got.append(m.seq)  # type: ignore[union-attr]
            assert got == [1, 2, 5, 6, 0, 1]
            assert sub.lost == 2
            assert sub.bad_messages == 1
    finally:
        pub.close(linger=0)
        ctx.term()
