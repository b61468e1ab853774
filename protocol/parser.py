"""Streaming parser for the TF-Luna UART byte stream.

How this works: the caller feeds whatever bytes it read, in any chunking, with the
monotonic read time. The parser scans for a header: ``59 59`` starts a 9-byte data
frame, ``5A`` a command reply whose (ID, Len) pair must be a known one. A candidate
is accepted only when its checksum is right (and a reply only when no whole good data
frame lies inside its declared length); otherwise exactly one byte is dropped
and the scan resumes from the next byte, so garbage never costs the good frame that
follows it (TFLUNA.md section 10; pyubx2 skips a whole declared length and can lose
a frame starting inside it). Bytes that start no frame are counted as discarded.

Invariant (property-tested): ``bytes_fed == 9 * frames + reply_bytes + bytes_discarded
+ buffered``. The buffer never holds more than one partial frame (< 30 bytes).
Nothing in here raises on wire data, reads a clock, or logs.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from lunad.protocol.commands import COMMAND_HEADER_BYTE, REPLY_LENGTHS, CommandId, CommandReply
from lunad.protocol.frame import (
    DATA_FRAME_LEN,
    DATA_HEADER,
    DATA_HEADER_BYTE,
    Frame,
    OutputFormat,
)

_HEADERS = (DATA_HEADER_BYTE, COMMAND_HEADER_BYTE)
_FIELDS = struct.Struct("<2xHHHx")  # Dist, Amp, Temp of one 9-byte data frame (M05 p.24)
_new = tuple.__new__
"""Builds a ``Frame`` from a tuple without the ``NamedTuple``'s generated Python
``__new__``: one C call instead of a Python frame, on every frame."""


@dataclass(slots=True)
class ParserStats:
    """Running counters of one parser (all since it was made).

    Attributes:
        bytes_fed: every byte passed to ``feed``.
        frames: good data frames returned.
        replies: good command replies returned.
        reply_bytes: bytes in those replies.
        checksum_errors: header candidates whose checksum was wrong.
        bytes_discarded: bytes thrown away while resynchronising.
        buffered: bytes held back as the start of a frame not complete yet.
    """

    bytes_fed: int = 0
    frames: int = 0
    replies: int = 0
    reply_bytes: int = 0
    checksum_errors: int = 0
    bytes_discarded: int = 0
    buffered: int = 0


class FrameParser:
    """Turns a TF-Luna byte stream into data frames and command replies.

    Args:
        fmt: the output format data frames are in (cm or mm). A format echo from
            the sensor (reply to ID 0x05) switches it.
    """

    def __init__(self, fmt: OutputFormat = OutputFormat.CM) -> None:
        self.fmt = fmt
        self.stats = ParserStats()
        self._buf = bytearray()

    def feed(self, data: bytes, t_mono_ns: int) -> list[Frame | CommandReply]:
        """Parse ``data``; return every complete frame and reply it finished, in order.

        Args:
            data: bytes as read from the wire, any length.
            t_mono_ns: ``time.monotonic_ns()`` when they were read; stamped on the
                frames completed by this call.
        """
        stats = self.stats
        buf = self._buf
        n = len(data)
        if not buf and not n % DATA_FRAME_LEN:
            # The usual cases, a read of whole frames: one at full rate, a batch of them
            # at ``publish_hz``. What the scan below would return, for less.
            if n == DATA_FRAME_LEN:
                if data[:2] == DATA_HEADER and (sum(data[:8]) & 0xFF) == data[8]:
                    stats.bytes_fed += DATA_FRAME_LEN
                    stats.frames += 1
                    dist, amp, temp = _FIELDS.unpack(data)
                    return [_new(Frame, (dist, amp, temp, t_mono_ns, self.fmt))]
            else:
                fmt = self.fmt
                frames: list[Frame | CommandReply] = []
                for i in range(0, n, DATA_FRAME_LEN):
                    j = i + 8
                    if (
                        data[i] != DATA_HEADER_BYTE
                        or data[i + 1] != DATA_HEADER_BYTE
                        or (sum(data[i:j]) & 0xFF) != data[j]
                    ):
                        break
                    dist, amp, temp = _FIELDS.unpack_from(data, i)
                    frames.append(_new(Frame, (dist, amp, temp, t_mono_ns, fmt)))
                else:
                    stats.bytes_fed += n
                    stats.frames += len(frames)
                    return frames
        stats.bytes_fed += n
        buf += data
        n = len(buf)
        out: list[Frame | CommandReply] = []
        i = 0
        discarded = 0
        while i < n:
            b = buf[i]
            if b == DATA_HEADER_BYTE:
                if i + 1 < n and buf[i + 1] != DATA_HEADER_BYTE:
                    i += 1
                    discarded += 1
                    continue
                if n - i < DATA_FRAME_LEN:
                    break
                if (sum(buf[i : i + 8]) & 0xFF) == buf[i + 8]:
                    dist, amp, temp = _FIELDS.unpack_from(buf, i)
                    out.append(_new(Frame, (dist, amp, temp, t_mono_ns, self.fmt)))
                    stats.frames += 1
                    i += DATA_FRAME_LEN
                    continue
                stats.checksum_errors += 1
            elif b == COMMAND_HEADER_BYTE:
                if n - i < 3:
                    break
                length = buf[i + 1]
                if REPLY_LENGTHS.get(buf[i + 2]) == length:
                    if _frame_inside(buf, i + 1, min(n, i + length)):
                        i += 1
                        discarded += 1
                        continue
                    if n - i < length:
                        break
                    end = i + length - 1
                    if (sum(buf[i:end]) & 0xFF) == buf[end]:
                        reply = CommandReply(buf[i + 2], bytes(buf[i + 3 : end]), t_mono_ns)
                        self._note_reply(reply)
                        out.append(reply)
                        i += length
                        continue
                    stats.checksum_errors += 1
            else:
                j = _next_header(buf, i + 1, n)
                discarded += j - i
                i = j
                continue
            i += 1
            discarded += 1
        if i:
            del buf[:i]
        stats.bytes_discarded += discarded
        stats.buffered = len(buf)
        return out

    def reset(self) -> None:
        """Drop the partial frame held back (after a reconnect); counters stay."""
        self.stats.bytes_discarded += len(self._buf)
        self._buf.clear()
        self.stats.buffered = 0

    def _note_reply(self, reply: CommandReply) -> None:
        stats = self.stats
        stats.replies += 1
        stats.reply_bytes += len(reply.payload) + 4
        if reply.cmd_id == CommandId.OUTPUT_FORMAT and len(reply.payload) == 1:
            try:
                self.fmt = OutputFormat(reply.payload[0])
            except ValueError:
                pass


def _frame_inside(buf: bytearray, start: int, end: int) -> bool:
    """True when a whole data frame with a good checksum lies in ``buf[start:end]``.

    A ``5A`` reply candidate spanning one is taken for garbage: otherwise a stray
    0x5A that looks like a reply header would hold a real frame back until the rest
    of its declared length arrives, which at a pause or before an unplug may be never.
    The rule depends only on the bytes, so the result stays the same in any chunking.
    """
    j = buf.find(DATA_HEADER, start, end)
    while 0 <= j <= end - DATA_FRAME_LEN:
        if (sum(buf[j : j + 8]) & 0xFF) == buf[j + 8]:
            return True
        j = buf.find(DATA_HEADER, j + 1, end)
    return False


def _next_header(buf: bytearray, start: int, end: int) -> int:
    """Index of the next byte in ``buf[start:end]`` that could start a frame, else ``end``."""
    best = end
    for h in _HEADERS:
        j = buf.find(h, start, best)
        if j >= 0:
            best = j
    return best
