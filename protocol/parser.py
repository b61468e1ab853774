"""Streaming parser for the TF-Luna UART byte stream.

How this works: the caller feeds whatever bytes it read, in any chunking, with the
monotonic read time. The parser scans for a header: ``59 59`` starts a 9-byte data
frame, ``5A`` a command reply whose (ID, Len) pair must be a known one. A candidate
is a *good frame* when its checksum is right and, for a data frame, its temperature
field lies in the range a real chip reports (``TEMP_RAW_MIN..TEMP_RAW_MAX``); a reply
is no candidate when a whole good data frame lies inside its declared length. Anything
else drops exactly one byte and the scan resumes from the next byte, so garbage never
costs the good frame that follows it (docs/tfluna.md section 10; pyubx2 skips a whole
declared length and can lose a frame starting inside it). Bytes that start no frame
are counted as discarded.

Overlapping candidates. Garbage that holds 0x59 can form a good frame that overlaps a
real one: a stray 59 before ``59 59 ...`` makes a window one byte early, whose checksum
is right one time in 256. Taken, it would swallow the real frame with no trace. Real
frames follow one another, so the parser prefers the reading in which they do:

- A candidate is *linked* when the two bytes after it are a data header ``59 59``.
- A *rival* of a candidate is a good data frame starting inside it and running past its
  end (a whole one inside a reply already makes the reply garbage, see above).
- A candidate is *ambiguous* when a rival could start inside it, as far as the bytes in
  tell: a ``59 59`` pair in its last 8 bytes (or its last byte 59 with the next byte
  not in yet) whose frame's checksum and temperature, if in, are right.
- An unambiguous candidate is taken at once. This is nearly every real frame, so a
  clean stream pays no latency. An ambiguous one waits for the two bytes after it;
  linked, it is taken. Otherwise it is dropped (one byte, and the scan resumes) when a
  rival is linked, and taken when none is; deciding that may need a rival's 9 bytes and
  the 2 after them, up to 10 bytes past the candidate's end.
- When both or neither are linked, the earlier is taken. A clean stream never loses a
  frame: each of its frames is linked, and no earlier candidate overlaps it.

So a real frame followed by the next one's header is lost only to a false candidate
that overlaps its start and is itself linked: after a stray 59, a checksum match on
the false window, a plausible temperature in it and a 0x59 checksum byte on the real
frame, under 1 in 10**6 of frames. A real frame followed by garbage that is no header
can still lose to an earlier false candidate over it. A real frame whose checksum byte
is 0x59 (1 in 256; rarely, one with ``59 59`` in its fields) waits for the first two
bytes of the next frame, one frame period. The rules depend only on the bytes, never
on where a read ended, so the result is the same in any chunking.

Invariant (property-tested): ``bytes_fed == 9 * frames + reply_bytes + bytes_discarded
+ buffered``. The buffer holds at most one undecided candidate and the bytes that decide
it (< ``MAX_BUFFERED`` = 40 bytes). Nothing in here raises on wire data, reads a clock,
or logs.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

from lunad.protocol.commands import (
    COMMAND_HEADER_BYTE,
    MAX_REPLY_LEN,
    REPLY_LENGTHS,
    CommandId,
    CommandReply,
)
from lunad.protocol.frame import (
    DATA_FRAME_LEN,
    DATA_HEADER,
    DATA_HEADER_BYTE,
    TEMP_RAW_MAX,
    TEMP_RAW_MIN,
    Frame,
    OutputFormat,
)

MAX_BUFFERED: Final = MAX_REPLY_LEN + DATA_FRAME_LEN + 1
"""Bound on ``ParserStats.buffered``: a 30-byte reply candidate waits for at most the 10
bytes after it (a rival starting in its last byte, the rival's other 8, the 2 after)."""

_HEADERS = (DATA_HEADER_BYTE, COMMAND_HEADER_BYTE)
_FIELDS = struct.Struct("<2xHHHx")  # Dist, Amp, Temp of one 9-byte data frame (M05 p.24)
_new = tuple.__new__
"""Builds a ``Frame`` from a tuple without the ``NamedTuple``'s generated Python
``__new__``: one C call instead of a Python frame, on every frame."""

TAKE: Final = 1
DROP: Final = 0
WAIT: Final = -1
"""What ``verdict`` says of a good candidate: take it, drop one byte, or wait for more."""


@dataclass(slots=True)
class ParserStats:
    """Running counters of one parser (all since it was made).

    Attributes:
        bytes_fed: every byte passed to ``feed``.
        frames: good data frames returned.
        replies: good command replies returned.
        reply_bytes: bytes in those replies.
        checksum_errors: header candidates whose checksum was wrong.
        implausible_frames: data frame candidates with a right checksum and a
            temperature outside ``TEMP_PLAUSIBLE_MIN_C..TEMP_PLAUSIBLE_MAX_C``: garbage.
        displaced_frames: good candidates dropped for a linked rival starting inside
            them (see the module docstring): garbage that overlapped a real frame.
        bytes_discarded: bytes thrown away while resynchronising.
        buffered: bytes held back: a frame not complete yet, or one waiting for the
            bytes after it to decide it.
    """

    bytes_fed: int = 0
    frames: int = 0
    replies: int = 0
    reply_bytes: int = 0
    checksum_errors: int = 0
    implausible_frames: int = 0
    displaced_frames: int = 0
    bytes_discarded: int = 0
    buffered: int = 0


class FrameParser:
    """Turns a TF-Luna byte stream into data frames and command replies.

    Args:
        fmt: the output format data frames are in (cm or mm).
        follow_format_replies: True: any good reply to ID 0x05 (output format) switches
            ``fmt``, at its place in the stream. False: only the reply the caller said
            it is waiting for with ``expect_format`` does. Five bytes of garbage
            (``5A 05 05 06 6A``) are such a reply, so a caller that owns the sensor's
            settings should pass False.
    """

    def __init__(
        self, fmt: OutputFormat = OutputFormat.CM, *, follow_format_replies: bool = True
    ) -> None:
        self.fmt = fmt
        self.follow_format_replies = follow_format_replies
        self.stats = ParserStats()
        self._buf = bytearray()
        self._expected_fmt: OutputFormat | None = None
        self._reads: list[tuple[int, int]] = []
        """(end, t_mono_ns) of each earlier read with bytes still buffered; ``end``
        indexes ``_buf``. A frame held back is stamped with its last byte's read."""

    def expect_format(self, fmt: OutputFormat | None) -> None:
        """Switch ``fmt`` at the sensor's echo of ``fmt`` (with ``follow_format_replies``
        False). Call it right after sending ``commands.set_output_format(fmt)``: frames
        before the echo keep the old unit, frames after it get the new one, in the same
        read too. The first echo of ``fmt`` spends it; ``None`` withdraws it.
        """
        self._expected_fmt = None if fmt is None else OutputFormat(fmt)

    def feed(self, data: bytes, t_mono_ns: int) -> list[Frame | CommandReply]:
        """Parse ``data``; return every frame and reply now decided, in order.

        Args:
            data: bytes as read from the wire, any length.
            t_mono_ns: ``time.monotonic_ns()`` when they were read; stamped on the
                frames whose last byte came in this read (a frame held back for the
                bytes after it keeps the time of the read that completed it).
        """
        stats = self.stats
        buf = self._buf
        n = len(data)
        if n and not buf and not n % DATA_FRAME_LEN:
            # The usual cases, a read of whole frames: one at full rate, a batch of them
            # at ``publish_hz``. What the scan below would return, for less: each frame
            # but the last is linked by the header after it; the last must be unambiguous.
            if n == DATA_FRAME_LEN:
                # rfind: a header at 0 and no 59 59 pair after it
                if (
                    data.rfind(DATA_HEADER) == 0
                    and (sum(data[:8]) & 0xFF) == data[8] != DATA_HEADER_BYTE
                ):
                    dist, amp, temp = _FIELDS.unpack(data)
                    if TEMP_RAW_MIN <= temp <= TEMP_RAW_MAX:
                        stats.bytes_fed += DATA_FRAME_LEN
                        stats.frames += 1
                        return [_new(Frame, (dist, amp, temp, t_mono_ns, self.fmt))]
            elif data[n - 1] != DATA_HEADER_BYTE and data.find(DATA_HEADER, n - 8) < 0:
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
                    if not TEMP_RAW_MIN <= temp <= TEMP_RAW_MAX:
                        break
                    frames.append(_new(Frame, (dist, amp, temp, t_mono_ns, fmt)))
                else:
                    stats.bytes_fed += n
                    stats.frames += len(frames)
                    return frames
        stats.bytes_fed += n
        old = len(buf)  # bytes before this index came in earlier reads
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
                end = i + DATA_FRAME_LEN
                if (sum(buf[i : end - 1]) & 0xFF) != buf[end - 1]:
                    stats.checksum_errors += 1
                elif not TEMP_RAW_MIN <= (buf[i + 6] | buf[i + 7] << 8) <= TEMP_RAW_MAX:
                    stats.implausible_frames += 1
                else:
                    if buf.find(DATA_HEADER, i + 1, end + 1) >= 0 or (
                        end == n and buf[end - 1] == DATA_HEADER_BYTE
                    ):
                        v = verdict(buf, i, end, n)
                        if v == WAIT:
                            break
                        if v == DROP:
                            stats.displaced_frames += 1
                            i += 1
                            discarded += 1
                            continue
                    dist, amp, temp = _FIELDS.unpack_from(buf, i)
                    t = t_mono_ns if end > old else self._read_time(end)
                    out.append(_new(Frame, (dist, amp, temp, t, self.fmt)))
                    stats.frames += 1
                    i = end
                    continue
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
                    end = i + length
                    if (sum(buf[i : end - 1]) & 0xFF) == buf[end - 1]:
                        v = verdict(buf, i, end, n)
                        if v == WAIT:
                            break
                        if v == TAKE:
                            t = t_mono_ns if end > old else self._read_time(end)
                            reply = CommandReply(buf[i + 2], bytes(buf[i + 3 : end - 1]), t)
                            self._note_reply(reply)
                            out.append(reply)
                            i = end
                            continue
                        stats.displaced_frames += 1
                    else:
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
        if buf:
            reads = [(e - i, t) for e, t in self._reads if e > i]
            if n > old:
                reads.append((n - i, t_mono_ns))
            self._reads = reads
        elif self._reads:
            self._reads = []
        stats.bytes_discarded += discarded
        stats.buffered = len(buf)
        return out

    def reset(self) -> None:
        """Drop the bytes held back (after a reconnect); counters stay."""
        self.stats.bytes_discarded += len(self._buf)
        self._buf.clear()
        self._reads = []
        self.stats.buffered = 0

    def _read_time(self, end: int) -> int:
        """``t_mono_ns`` of the earlier read that brought ``_buf[end - 1]``."""
        return next(t for e, t in self._reads if e >= end)

    def _note_reply(self, reply: CommandReply) -> None:
        stats = self.stats
        stats.replies += 1
        stats.reply_bytes += len(reply.payload) + 4
        if reply.cmd_id == CommandId.OUTPUT_FORMAT and len(reply.payload) == 1:
            try:
                fmt = OutputFormat(reply.payload[0])
            except ValueError:
                return
            if fmt is self._expected_fmt:
                self._expected_fmt = None
            elif not self.follow_format_replies:
                return
            self.fmt = fmt


def good_data_frame(buf: bytes | bytearray, j: int) -> bool:
    """Whether ``buf[j : j + 9]`` (all there) is a data frame the parser would take on
    its own: header ``59 59``, a right checksum, a plausible temperature."""
    return (
        buf[j] == DATA_HEADER_BYTE
        and buf[j + 1] == DATA_HEADER_BYTE
        and (sum(buf[j : j + 8]) & 0xFF) == buf[j + 8]
        and TEMP_RAW_MIN <= (buf[j + 6] | buf[j + 7] << 8) <= TEMP_RAW_MAX
    )


def verdict(buf: bytes | bytearray, start: int, end: int, n: int) -> int:
    """``TAKE``, ``DROP`` or ``WAIT`` for the good candidate ``buf[start:end]``, with
    ``n`` bytes of ``buf`` in (the rules are in the module docstring).

    ``WAIT`` only while a byte it needs is not in, so that the answer, once given,
    is the same in any chunking. ``decode_bulk`` decides with this same function.
    """
    j = buf.find(DATA_HEADER_BYTE, max(start + 1, end - (DATA_FRAME_LEN - 1)), end)
    while j >= 0 and not _may_be_good(buf, j, n):
        j = buf.find(DATA_HEADER_BYTE, j + 1, end)
    if j < 0:
        return TAKE  # unambiguous: no good rival can start inside
    if n < end + 2:
        return WAIT
    if buf[end] == DATA_HEADER_BYTE and buf[end + 1] == DATA_HEADER_BYTE:
        return TAKE  # linked
    while j >= 0:
        if _may_be_good(buf, j, n):
            k = j + DATA_FRAME_LEN
            if n < k + 2:
                return WAIT
            if buf[k] == DATA_HEADER_BYTE and buf[k + 1] == DATA_HEADER_BYTE:
                return DROP  # a linked rival
        j = buf.find(DATA_HEADER_BYTE, j + 1, end)
    return TAKE


def _may_be_good(buf: bytes | bytearray, j: int, n: int) -> bool:
    """Whether the 59 at ``j`` can start a good data frame, judged on the bytes in
    (``n``): a rival ruled out now stays ruled out, so a candidate it made ambiguous
    is taken without waiting. A frame whose dist low byte is 0x59 has such a pair at
    offset 1, and its rival's temperature (the frame's last two bytes) rules it out."""
    if j + DATA_FRAME_LEN <= n:
        return good_data_frame(buf, j)
    if j + 1 < n and buf[j + 1] != DATA_HEADER_BYTE:
        return False
    return j + 8 > n or TEMP_RAW_MIN <= (buf[j + 6] | buf[j + 7] << 8) <= TEMP_RAW_MAX


def _frame_inside(buf: bytearray, start: int, end: int) -> bool:
    """True when a whole good data frame lies in ``buf[start:end]``.

    A ``5A`` reply candidate spanning one is taken for garbage: otherwise a stray
    0x5A that looks like a reply header would hold a real frame back until the rest
    of its declared length arrives, which at a pause or before an unplug may be never.
    The rule depends only on the bytes, so the result stays the same in any chunking.
    """
    j = buf.find(DATA_HEADER, start, end)
    while 0 <= j <= end - DATA_FRAME_LEN:
        if good_data_frame(buf, j):
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
