"""Check a soak's two byte recordings against each other: did every byte the virtual
sensor wrote reach the daemon, in order, and how long did each wait?

``lunad soak --keep-logs DIR`` keeps ``sensor-output.lunarec`` (every byte the sensor
wrote, stamped when written) and ``daemon-input.lunarec`` (every byte the daemon read,
stamped when read). This is the evidence behind a soak verdict that does not rely on
the soak's own reference parser: it found the soak's ledger bug (docs/soak.md).

    python -m lunad.daemon.tools.soak DIR

How: the daemon's chunks are located in the sensor's stream one after the other
(``bytes.find`` from where the previous chunk ended). Bytes passed over are bytes the
daemon never read (pyserial flushes the input when it opens a port, so bytes written
while no one had the port open would show up here). The wait of a chunk is its read
time minus the write time of its first byte. Both clocks are ``time.monotonic_ns()`` on
the same machine.
"""

from __future__ import annotations

import argparse
import sys
from array import array
from dataclasses import dataclass, field
from pathlib import Path

from lunad.daemon.sources.recording import Replay
from lunad.protocol.frame import Frame
from lunad.protocol.parser import FrameParser

SENSOR_OUTPUT = "sensor-output.lunarec"
"""With ``--keep-logs``: every byte the virtual sensor wrote, stamped when written."""
DAEMON_INPUT = "daemon-input.lunarec"
"""With ``--keep-logs``: every byte the daemon read (its ``[source] record``)."""


@dataclass
class ByteCheck:
    """What the comparison found. Times in seconds."""

    sensor_bytes: int = 0
    daemon_bytes: int = 0
    daemon_chunks: int = 0
    skipped: list[tuple[float, int]] = field(default_factory=list)
    """(when the first skipped byte was written, seconds into the run; how many)."""
    unmatched_chunks: int = 0
    """Daemon chunks not found in the sensor's stream at all."""
    max_wait_s: float = 0.0
    p99_wait_s: float = 0.0
    frames: int = 0
    """Data frames one ``FrameParser`` finds in the sensor's bytes."""

    @property
    def complete(self) -> bool:
        """Every byte the sensor wrote was read by the daemon, in order, nothing else."""
        return (
            not self.skipped
            and not self.unmatched_chunks
            and self.daemon_bytes == self.sensor_bytes
        )

    def summary(self) -> str:
        """One paragraph for people."""
        if self.complete:
            head = f"all {self.sensor_bytes} bytes the sensor wrote reached the daemon, in order"
        else:
            head = (
                f"the daemon read {self.daemon_bytes} of {self.sensor_bytes} bytes: "
                f"{len(self.skipped)} skipped span(s) "
                f"({sum(n for _, n in self.skipped)} bytes), "
                f"{self.unmatched_chunks} chunk(s) the sensor never wrote"
            )
        return (
            f"{head}; wait before read p99 {self.p99_wait_s * 1000:.1f} ms, "
            f"max {self.max_wait_s * 1000:.1f} ms; one parse of the sensor's bytes finds "
            f"{self.frames} frames"
        )


def compare(folder: Path | str) -> ByteCheck:
    """Compare ``sensor-output.lunarec`` with ``daemon-input.lunarec`` in ``folder``."""
    folder = Path(folder)
    stream = bytearray()
    written = array("q")  # write time of every byte, ns
    parser = FrameParser()
    out = ByteCheck()
    with Replay(folder / SENSOR_OUTPUT) as rec:
        for c in rec:
            stream += c.data
            written.extend(array("q", [c.t_mono_ns]) * len(c.data))
            out.frames += sum(1 for x in parser.feed(c.data, 0) if type(x) is Frame)
    out.sensor_bytes = len(stream)
    t0 = written[0] if written else 0
    waits: list[int] = []
    pos = 0
    with Replay(folder / DAEMON_INPUT) as rec:
        for c in rec:
            out.daemon_chunks += 1
            out.daemon_bytes += len(c.data)
            at = stream.find(c.data, pos)
            if at < 0:
                out.unmatched_chunks += 1
                continue
            if at > pos:
                out.skipped.append(((written[pos] - t0) / 1e9, at - pos))
            waits.append(c.t_mono_ns - written[at])
            pos = at + len(c.data)
    if waits:
        waits.sort()
        out.max_wait_s = waits[-1] / 1e9
        out.p99_wait_s = waits[min(len(waits) - 1, int(len(waits) * 0.99))] / 1e9
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m lunad.daemon.tools.soak DIR``: exit 0 when the streams agree."""
    p = argparse.ArgumentParser(
        prog="python -m lunad.daemon.tools.soak",
        description="Compare the byte recordings of `lunad soak --keep-logs DIR`.",
    )
    p.add_argument("folder", metavar="DIR", help="the --keep-logs folder of a soak")
    args = p.parse_args(argv)
    try:
        check = compare(args.folder)
    except (OSError, ValueError) as exc:
        print(f"byte_check: {exc}", file=sys.stderr)
        return 2
    print(check.summary())
    for when, n in check.skipped[:20]:
        print(f"  skipped {n} bytes written at {when:.3f} s")
    return 0 if check.complete else 1
