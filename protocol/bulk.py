"""Vectorised decode of a whole TF-Luna byte stream, for replay and analysis.

How this works. ``FrameParser`` walks the bytes one candidate at a time: at a good
frame (data ``59 59`` with its checksum right, or a ``5A`` reply with a known
(ID, Len) pair and its checksum right) it takes the frame and jumps past it; anywhere
else it drops one byte. ``decode_bulk`` gives exactly the frames that ``FrameParser``
gives when fed the same bytes (in any chunking), in three steps:

1. numpy finds every *valid candidate*: each offset where a complete frame with a
   right checksum starts. Data frames are checked for all ``59 59`` offsets at once
   (one gather of 9-byte windows); ``5A`` replies are rare and checked one by one.
2. The walk takes a valid candidate iff it starts at or after the end of the last one
   taken. A candidate that starts at or after the end of *every* earlier candidate is
   taken whatever happened before it; in a clean stream that is all of them, found
   with one running maximum. Only the rest (overlaps, from ``59 59`` inside garbage or
   inside a frame) go through a short sequential pass, in Python.
3. The end of the stream: the parser stops at the first position it reaches where a
   candidate does not fit in the bytes left (a ``59`` as the last byte, ``59 59``
   with fewer than 9 bytes, a ``5A`` reply cut short) and keeps the rest buffered.
   Those positions lie in the last 30 bytes; frames from there on are dropped.

Counters come out as ``FrameParser.stats`` would have them after one ``feed``.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lunad.protocol.commands import COMMAND_HEADER_BYTE, MAX_REPLY_LEN, REPLY_LENGTHS, CommandId
from lunad.protocol.frame import DATA_FRAME_LEN, DATA_HEADER_BYTE, DIST_INVALID_A01, OutputFormat

_REPLY_LEN_BY_ID = np.zeros(256, dtype=np.int64)
for _cid, _length in REPLY_LENGTHS.items():
    _REPLY_LEN_BY_ID[int(_cid)] = _length
_FORMATS = {int(f) for f in OutputFormat}


@dataclass(frozen=True)
class BulkFrames:
    """Every data frame of a stream, as arrays (one element per frame, in order).

    Attributes:
        offset: where the frame starts in the stream (byte index of its first ``59``).
        dist: raw distance field, in the unit of ``fmt`` (cm or mm).
        amp: signal strength.
        temp_raw: raw temperature field (``temp_raw / 8 - 256`` degrees Celsius).
        fmt: output format each frame was parsed in (``OutputFormat`` values).
        reply_offsets: where each good command reply starts.
        reply_ids: the command ID of each of those replies.
        checksum_errors, bytes_discarded, buffered, reply_bytes: as ``ParserStats``
            after one ``feed`` of the whole stream.
    """

    offset: npt.NDArray[np.int64]
    dist: npt.NDArray[np.uint16]
    amp: npt.NDArray[np.uint16]
    temp_raw: npt.NDArray[np.uint16]
    fmt: npt.NDArray[np.uint8]
    reply_offsets: npt.NDArray[np.int64]
    reply_ids: npt.NDArray[np.uint8]
    checksum_errors: int
    bytes_discarded: int
    buffered: int
    reply_bytes: int

    def __len__(self) -> int:
        return len(self.dist)

    def distance_m(self) -> npt.NDArray[np.float64]:
        """Reported distance in metres; NaN where the sensor reported none (0 or 0xFFFF)."""
        out = self.dist / np.where(self.fmt == OutputFormat.CM, 100.0, 1000.0)
        out[(self.dist == 0) | (self.dist == DIST_INVALID_A01)] = np.nan
        return out

    def temp_c(self) -> npt.NDArray[np.float64]:
        """Chip temperature, degrees Celsius."""
        return self.temp_raw / 8.0 - 256.0


def decode_bulk(data: bytes | bytearray | memoryview, fmt: int = OutputFormat.CM) -> BulkFrames:
    """Decode ``data`` as ``FrameParser(fmt).feed(data, t)`` would, into arrays.

    Args:
        data: a TF-Luna byte stream, e.g. a recording's chunks concatenated.
        fmt: the output format at the start (a format reply in the stream switches it).
    """
    a = np.frombuffer(data, dtype=np.uint8)
    n = len(a)
    empty_i = np.zeros(0, dtype=np.int64)

    # 1. valid candidates -------------------------------------------------------
    if n >= DATA_FRAME_LEN:
        h = a[: n - DATA_FRAME_LEN + 1] == DATA_HEADER_BYTE
        h &= a[1 : n - DATA_FRAME_LEN + 2] == DATA_HEADER_BYTE
        heads = np.flatnonzero(h)
    else:
        heads = empty_i
    windows = _windows(a, heads)
    good = windows[:, :8].sum(axis=1, dtype=np.uint8) == windows[:, 8]
    d_starts = heads[good]
    d_bad = heads[~good]

    r_starts_l: list[int] = []
    r_lens_l: list[int] = []
    r_bad_l: list[int] = []
    d_list = d_starts.tolist()
    for p in np.flatnonzero(a[: max(0, n - 2)] == COMMAND_HEADER_BYTE).tolist():
        length = int(_REPLY_LEN_BY_ID[a[p + 2]])
        if length == 0 or a[p + 1] != length or p + length > n:
            continue
        if _frame_inside(d_list, p, p + length):
            continue
        if int(a[p : p + length - 1].sum()) & 0xFF == a[p + length - 1]:
            r_starts_l.append(p)
            r_lens_l.append(length)
        else:
            r_bad_l.append(p)

    if r_starts_l:
        starts = np.concatenate([d_starts, np.array(r_starts_l, dtype=np.int64)])
        lens = np.concatenate(
            [np.full(len(d_starts), DATA_FRAME_LEN, dtype=np.int64), np.array(r_lens_l)]
        )
        order = np.argsort(starts, kind="stable")
        starts, lens = starts[order], lens[order]
    else:
        starts = d_starts
        lens = np.full(len(d_starts), DATA_FRAME_LEN, dtype=np.int64)
    ends = starts + lens

    # 2. which the walk takes -----------------------------------------------------
    taken = np.ones(len(starts), dtype=bool)
    if len(starts) > 1:
        reach = np.maximum.accumulate(ends)
        unsure = np.flatnonzero(starts[1:] < reach[:-1]) + 1
        if len(unsure):
            is_unsure = np.zeros(len(starts), dtype=bool)
            is_unsure[unsure] = True
            flags = is_unsure.tolist()
            s_l = starts.tolist()
            e_l = ends.tolist()
            last_end = 0
            for k in unsure.tolist():
                if not flags[k - 1]:
                    last_end = e_l[k - 1]
                if s_l[k] >= last_end:
                    last_end = e_l[k]
                else:
                    taken[k] = False
    starts, lens, ends = starts[taken], lens[taken], ends[taken]

    # 3. where the walk stops ---------------------------------------------------------
    stop = n
    for p in range(max(0, n - MAX_REPLY_LEN), n):
        b = a[p]
        if b == DATA_HEADER_BYTE:
            cut = p == n - 1 or (a[p + 1] == DATA_HEADER_BYTE and n - p < DATA_FRAME_LEN)
        elif b == COMMAND_HEADER_BYTE:
            cut = n - p < 3 or (
                _REPLY_LEN_BY_ID[a[p + 2]] == a[p + 1] != 0
                and n - p < a[p + 1]
                and not _frame_inside(d_list, p, n)
            )
        else:
            continue
        if cut and not _covered(starts, ends, p):
            stop = p
            break
    if stop < n:
        keep = starts < stop
        starts, lens, ends = starts[keep], lens[keep], ends[keep]

    # frames, replies, counters -------------------------------------------------------
    # By header, not by length: a DIST_LIMIT reply is 9 bytes long, like a data frame.
    is_data = a[starts] == DATA_HEADER_BYTE
    f_starts = starts[is_data]
    r_starts = starts[~is_data]
    r_lens = lens[~is_data]
    reply_bytes = int(r_lens.sum())
    w = _windows(a, f_starts)
    fields = np.ascontiguousarray(w[:, 2:8]).view("<u2")
    fields = fields.reshape(len(f_starts), 3) if len(f_starts) else np.zeros((0, 3), "<u2")

    fmts = np.full(len(f_starts), int(fmt), dtype=np.uint8)
    r_ids = a[r_starts + 2] if len(r_starts) else np.zeros(0, dtype=np.uint8)
    cur = int(fmt)
    for p, cid, length in zip(r_starts.tolist(), r_ids.tolist(), r_lens.tolist(), strict=True):
        if cid == CommandId.OUTPUT_FORMAT and length == 5 and int(a[p + 3]) in _FORMATS:
            cur = int(a[p + 3])
            fmts[np.searchsorted(f_starts, p) :] = cur

    bad = np.concatenate([d_bad, np.array(r_bad_l, dtype=np.int64)])
    bad = bad[bad < stop]
    if len(bad) and len(starts):
        i = np.searchsorted(starts, bad, side="right") - 1
        inside = (i >= 0) & (bad < ends[np.maximum(i, 0)])
        checksum_errors = int((~inside).sum())
    else:
        checksum_errors = len(bad)

    return BulkFrames(
        offset=f_starts.astype(np.int64, copy=False),
        dist=fields[:, 0].copy(),
        amp=fields[:, 1].copy(),
        temp_raw=fields[:, 2].copy(),
        fmt=fmts,
        reply_offsets=r_starts.astype(np.int64, copy=False),
        reply_ids=np.asarray(r_ids, dtype=np.uint8),
        checksum_errors=checksum_errors,
        bytes_discarded=stop - DATA_FRAME_LEN * len(f_starts) - reply_bytes,
        buffered=n - stop,
        reply_bytes=reply_bytes,
    )


def _windows(a: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]) -> npt.NDArray[np.uint8]:
    """The 9-byte windows of ``a`` at ``starts`` (each fits), as an (n, 9) array."""
    if len(starts) == 0:
        return np.zeros((0, DATA_FRAME_LEN), dtype=np.uint8)
    return np.lib.stride_tricks.sliding_window_view(a, DATA_FRAME_LEN)[starts]


def _frame_inside(d_starts: list[int], p: int, end: int) -> bool:
    """A good data frame lies wholly in ``(p, end)``: the ``5A`` at ``p`` is no reply
    (the streaming parser's rule, ``lunad.protocol.parser._frame_inside``)."""
    k = bisect.bisect_right(d_starts, p)
    return k < len(d_starts) and d_starts[k] + DATA_FRAME_LEN <= end


def _covered(starts: npt.NDArray[np.int64], ends: npt.NDArray[np.int64], p: int) -> bool:
    """Whether offset ``p`` lies inside a frame the walk took (so it never looks at it)."""
    i = int(np.searchsorted(starts, p, side="right")) - 1
    return i >= 0 and p < int(ends[i])
