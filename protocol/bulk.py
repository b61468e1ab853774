"""Vectorised decode of a whole TF-Luna byte stream, for replay and analysis.

How this works. ``FrameParser`` walks the bytes one candidate at a time: at a good
frame it takes the frame and jumps past it, unless the frame is ambiguous and a linked
rival inside it wins (the rules are in ``lunad.protocol.parser``'s docstring); anywhere
else it drops one byte. ``decode_bulk`` gives exactly the frames that ``FrameParser``
gives when fed the same bytes (in any chunking), in three steps:

1. numpy finds every *taken-if-reached candidate*: each offset where a frame starts that
   the walk takes if it gets there. Data frames are checked for all ``59 59`` offsets at
   once (one gather of 9-byte windows: checksum and temperature). Whether one is
   ambiguous comes from the next ``59 59`` pair after it, whether it is linked from the
   pair 9 bytes on; only the few that are both ambiguous and unlinked (in garbage) go
   to ``parser.verdict`` one by one. ``5A`` replies are rare and checked one by one.
2. The walk takes a candidate iff it starts at or after the end of the last one taken.
   A verdict depends on the bytes alone, never on the walk, so a candidate that starts
   at or after the end of *every* earlier candidate is taken whatever happened before
   it; in a clean stream that is all of them, found with one running maximum. Only the
   rest (overlaps, from ``59 59`` inside garbage or inside a frame) go through a short
   sequential pass, in Python.
3. The end of the stream: the parser stops at the first position it reaches where a
   candidate does not fit in the bytes left (a ``59`` as the last byte, ``59 59``
   with fewer than 9 bytes, a ``5A`` reply cut short) or waits for the bytes after it,
   and keeps the rest buffered. Those positions lie in the last ``MAX_BUFFERED`` bytes;
   frames from there on are dropped.

Counters come out as ``FrameParser.stats`` would have them after one ``feed``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lunad.protocol.commands import COMMAND_HEADER_BYTE, REPLY_LENGTHS, CommandId
from lunad.protocol.frame import (
    DATA_FRAME_LEN,
    DATA_HEADER_BYTE,
    DIST_INVALID_A01,
    TEMP_RAW_MAX,
    TEMP_RAW_MIN,
    OutputFormat,
)
from lunad.protocol.parser import DROP, MAX_BUFFERED, TAKE, verdict

_REPLY_LEN_BY_ID = np.zeros(256, dtype=np.int64)
for _cid, _length in REPLY_LENGTHS.items():
    _REPLY_LEN_BY_ID[int(_cid)] = _length
_FORMATS = {int(f) for f in OutputFormat}
_EMPTY = np.zeros(0, dtype=np.int64)


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
        checksum_errors, implausible_frames, displaced_frames, bytes_discarded,
            buffered, reply_bytes: as ``ParserStats`` after one ``feed`` of the stream.
    """

    offset: npt.NDArray[np.int64]
    dist: npt.NDArray[np.uint16]
    amp: npt.NDArray[np.uint16]
    temp_raw: npt.NDArray[np.uint16]
    fmt: npt.NDArray[np.uint8]
    reply_offsets: npt.NDArray[np.int64]
    reply_ids: npt.NDArray[np.uint8]
    checksum_errors: int
    implausible_frames: int
    displaced_frames: int
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


def decode_bulk(
    data: bytes | bytearray | memoryview,
    fmt: int = OutputFormat.CM,
    follow_format_replies: bool = True,
) -> BulkFrames:
    """Decode ``data`` as ``FrameParser(fmt, follow_format_replies=...).feed(data, t)``
    would, into arrays.

    Args:
        data: a TF-Luna byte stream, e.g. a recording's chunks concatenated.
        fmt: the output format at the start.
        follow_format_replies: whether a format reply in the stream switches it. With
            False the format stays ``fmt`` (bulk decode has no ``expect_format``).
    """
    raw = data if isinstance(data, bytes | bytearray) else bytes(data)
    a = np.frombuffer(raw, dtype=np.uint8)
    n = len(a)

    # 1. candidates -------------------------------------------------------------
    if n >= 2:
        pairs = np.flatnonzero((a[:-1] == DATA_HEADER_BYTE) & (a[1:] == DATA_HEADER_BYTE))
    else:
        pairs = _EMPTY
    n_heads = int(np.searchsorted(pairs, n - DATA_FRAME_LEN, side="right"))
    heads = pairs[:n_heads]
    windows = _windows(a, heads)
    good_cs = windows[:, :8].sum(axis=1, dtype=np.uint8) == windows[:, 8]
    temp = windows[:, 6].astype(np.uint16) | (windows[:, 7].astype(np.uint16) << 8)
    plausible = (temp >= TEMP_RAW_MIN) & (temp <= TEMP_RAW_MAX)
    d_bad = heads[~good_cs]
    d_implausible = heads[good_cs & ~plausible]
    valid = good_cs & plausible
    # Ambiguous, roughly: the next 59 59 pair starts inside (a rival could), or the frame
    # ends the data with a 59 whose follower is not in. Linked: a pair right after it.
    # ``verdict`` looks closer at the ambiguous ones that are not linked.
    after = np.append(pairs[1:], n)[:n_heads]
    ambiguous = after - heads < DATA_FRAME_LEN
    if n_heads and heads[-1] == n - DATA_FRAME_LEN and a[n - 1] == DATA_HEADER_BYTE:
        ambiguous[-1] = True
    v_heads = heads[valid]
    take = ~ambiguous[valid]
    unsure = np.flatnonzero(~take)
    d_displaced_l: list[int] = []
    waits: set[int] = set()
    if len(unsure):
        h = v_heads[unsure]
        k9 = np.minimum(h + DATA_FRAME_LEN, n - 2)
        linked = (h + DATA_FRAME_LEN + 1 < n) & (a[k9] == DATA_HEADER_BYTE)
        linked &= a[k9 + 1] == DATA_HEADER_BYTE
        take[unsure[linked]] = True
        for k, p in zip(unsure[~linked].tolist(), h[~linked].tolist(), strict=True):
            v = verdict(raw, p, p + DATA_FRAME_LEN, n)
            if v == TAKE:
                take[k] = True
            elif v == DROP:
                d_displaced_l.append(p)
            else:  # WAIT: the stream ends before the bytes that decide it
                waits.add(p)
    d_starts = v_heads[take]

    r_starts_l: list[int] = []
    r_lens_l: list[int] = []
    r_bad_l: list[int] = []
    r_displaced_l: list[int] = []
    ps = np.flatnonzero(a[: max(0, n - 2)] == COMMAND_HEADER_BYTE)
    if len(ps):
        lens = _REPLY_LEN_BY_ID[a[ps + 2]]
        ok = (lens != 0) & (a[ps + 1] == lens) & (ps + lens <= n)
        for p, length in zip(ps[ok].tolist(), lens[ok].tolist(), strict=True):
            if _frame_inside(v_heads, p, p + length):
                continue
            if sum(raw[p : p + length - 1]) & 0xFF != raw[p + length - 1]:
                r_bad_l.append(p)
                continue
            v = verdict(raw, p, p + length, n)
            if v == TAKE:
                r_starts_l.append(p)
                r_lens_l.append(length)
            elif v == DROP:
                r_displaced_l.append(p)
            else:  # WAIT
                waits.add(p)

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
        overlapped = np.flatnonzero(starts[1:] < reach[:-1]) + 1
        if len(overlapped):
            is_overlapped = np.zeros(len(starts), dtype=bool)
            is_overlapped[overlapped] = True
            flags = is_overlapped.tolist()
            s_l = starts.tolist()
            e_l = ends.tolist()
            last_end = 0
            for k in overlapped.tolist():
                if not flags[k - 1]:
                    last_end = e_l[k - 1]
                if s_l[k] >= last_end:
                    last_end = e_l[k]
                else:
                    taken[k] = False
    starts, lens, ends = starts[taken], lens[taken], ends[taken]

    # 3. where the walk stops ---------------------------------------------------------
    stop = n
    for p in range(max(0, n - MAX_BUFFERED), n):
        b = raw[p]
        if b == DATA_HEADER_BYTE:
            cut = p == n - 1 or (
                raw[p + 1] == DATA_HEADER_BYTE and (n - p < DATA_FRAME_LEN or p in waits)
            )
        elif b == COMMAND_HEADER_BYTE:
            cut = (
                n - p < 3
                or p in waits
                or (
                    _REPLY_LEN_BY_ID[raw[p + 2]] == raw[p + 1] != 0
                    and n - p < raw[p + 1]
                    and not _frame_inside(v_heads, p, n)
                )
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
    if follow_format_replies:
        for p, cid, length in zip(r_starts.tolist(), r_ids.tolist(), r_lens.tolist(), strict=True):
            if cid == CommandId.OUTPUT_FORMAT and length == 5 and raw[p + 3] in _FORMATS:
                fmts[np.searchsorted(f_starts, p) :] = raw[p + 3]

    def visited(at: npt.NDArray[np.int64] | list[int]) -> int:
        """How many of the offsets ``at`` the walk reaches (before ``stop``, outside
        every frame it took): the candidates it counted and dropped there."""
        pos = np.asarray(at, dtype=np.int64)
        pos = pos[pos < stop]
        if not len(pos) or not len(starts):
            return len(pos)
        i = np.searchsorted(starts, pos, side="right") - 1
        inside = (i >= 0) & (pos < ends[np.maximum(i, 0)])
        return int((~inside).sum())

    return BulkFrames(
        offset=f_starts.astype(np.int64, copy=False),
        dist=fields[:, 0].copy(),
        amp=fields[:, 1].copy(),
        temp_raw=fields[:, 2].copy(),
        fmt=fmts,
        reply_offsets=r_starts.astype(np.int64, copy=False),
        reply_ids=np.asarray(r_ids, dtype=np.uint8),
        checksum_errors=visited(d_bad) + visited(r_bad_l),
        implausible_frames=visited(d_implausible),
        displaced_frames=visited(d_displaced_l) + visited(r_displaced_l),
        bytes_discarded=stop - DATA_FRAME_LEN * len(f_starts) - reply_bytes,
        buffered=n - stop,
        reply_bytes=reply_bytes,
    )


def _windows(a: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]) -> npt.NDArray[np.uint8]:
    """The 9-byte windows of ``a`` at ``starts`` (each fits), as an (n, 9) array."""
    if len(starts) == 0:
        return np.zeros((0, DATA_FRAME_LEN), dtype=np.uint8)
    return np.lib.stride_tricks.sliding_window_view(a, DATA_FRAME_LEN)[starts]


def _frame_inside(good_starts: npt.NDArray[np.int64], p: int, end: int) -> bool:
    """A good data frame lies wholly in ``(p, end)``: the ``5A`` at ``p`` is no reply
    (the streaming parser's rule, ``lunad.protocol.parser._frame_inside``)."""
    k = int(np.searchsorted(good_starts, p, side="right"))
    return k < len(good_starts) and int(good_starts[k]) + DATA_FRAME_LEN <= end


def _covered(starts: npt.NDArray[np.int64], ends: npt.NDArray[np.int64], p: int) -> bool:
    """Whether offset ``p`` lies inside a frame the walk took (so it never looks at it)."""
    i = int(np.searchsorted(starts, p, side="right")) - 1
    return i >= 0 and p < int(ends[i])
