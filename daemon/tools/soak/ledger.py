"""Exact accounting: the reference stream (from the bytes written) against the
published stream.

A ``Ledger`` sees every byte the device writes to the pty (through ``PtyDevice``'s
``on_bytes_written`` hook) and runs a reference ``FrameParser`` over them. The frames
the reference finds are exactly what a correct daemon must publish, numbered from 0
like the daemon's ``seq``. This counts collisions instead of avoiding them: random
garbage (and cut or corrupted frames) can, with probability about 1/256 per header
candidate, form a frame with a good checksum, which a correct parser must publish
("false" frames) and which may swallow the real frame that follows ("eaten"). Both are
counted and reported, and the daemon is judged against the reference, so the faults
can use real random bytes, 0x59 and 0x5A included. Every published ``range`` message is
matched by ``seq`` against the reference frame (distance and amp); a gap in ``seq`` at
the main subscriber, a mismatch, a frame never published, or a frame published that
the bytes did not contain is a loss.
"""

from __future__ import annotations

import threading
from collections import deque

from lunad.protocol.commands import CommandReply
from lunad.protocol.frame import Frame
from lunad.protocol.parser import FrameParser


def _raw_m(dist: int) -> float | None:
    """``raw_m`` as the daemon publishes it for a frame's distance field (cm)."""
    if dist == 0 or dist == 0xFFFF:
        return None
    return round(dist / 100.0, 4)


class Ledger:
    """The reference stream (from the bytes written) against the published stream.

    Thread-safe: the device thread calls ``on_written``, the subscriber ``on_range``.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._parser = FrameParser(follow_format_replies=False)  # as the daemon's
        self._carry = b""
        self._pending: deque[tuple[int, int]] = deque()  # good frames written, not yet found
        self.good_sent = 0  # good frames fully written (equals PtyDevice.frames_sent)
        self.ref_count = 0  # frames a correct parser finds in the bytes written
        self.false_frames = 0  # of those, formed by garbage (not a frame the sensor sent)
        self.eaten = 0  # good frames swallowed by a false frame (a correct parser must)
        self.next_seq = 0  # last published seq + 1
        self.published = 0  # distinct range messages received
        self.gaps = 0  # frames lost as gaps in seq
        self.missing = 0  # reference frames never published (found when draining)
        self.unexpected = 0  # published frames the bytes did not contain
        self.mismatched = 0  # published seq whose distance/amp differ from the reference
        self.backwards = 0  # seq went back: the daemon restarted
        self.duplicates = 0  # last-value-cache repeats (not a loss)
        self._offset = 0  # reference index - seq, after a loss was found
        self._expected: dict[int, tuple[tuple[float | None, int], int]] = {}
        self._early: dict[int, tuple[tuple[float | None, int], int]] = {}
        self.read_lat_max_ns = 0  # bytes written -> daemon read them (its t_mono_ns)
        self.window_read_lat_max_ns = 0  # the same since ``window_start()``

    def window_start(self) -> None:
        """Start a window for ``window_read_lat_max_ns`` (a slow subscriber's stall)."""
        with self._lock:
            self.window_read_lat_max_ns = 0

    def _read_latency(self, t_write: int, t_read: int) -> None:
        if t_write and t_read:
            lat = t_read - t_write
            if lat > self.read_lat_max_ns:
                self.read_lat_max_ns = lat
            if lat > self.window_read_lat_max_ns:
                self.window_read_lat_max_ns = lat

    @property
    def lost(self) -> int:
        """Valid frames that reached the daemon and are missing from the stream."""
        return self.gaps + self.missing + self.mismatched + self.unexpected + self.backwards

    def on_written(self, data: bytes, ends: list[int], t_ns: int = 0) -> None:
        """Bytes the device wrote at ``t_ns``; ``ends``: where good frames end in ``data``.

        The parser is fed each byte once. The last 8 bytes of earlier writes are kept
        apart (``_carry``) only to read a good frame that began in an earlier write.
        A good frame the parser holds until the next bytes decide it (its checksum byte
        could start a header) is matched when it comes out, in a later write.
        """
        with self._lock:
            look = self._carry + data
            off = len(self._carry)
            pos = 0
            feed = self._parser.feed
            for e in ends:
                good = look[off + e - 9 : off + e]
                self._pending.append((good[2] | good[3] << 8, good[4] | good[5] << 8))
                self.good_sent += 1
                self._account(feed(data[pos:e], 0), t_ns)
                pos = e
            self._account(feed(data[pos:], 0), t_ns)
            self._carry = look[-8:]

    def _account(self, items: list[Frame | CommandReply], t_ns: int) -> None:
        """Match the frames the reference parser found against the good frames written:
        one that is none of them is false; good ones passed over were eaten."""
        pending = self._pending
        for f in items:
            if type(f) is not Frame:
                continue
            key = (f.dist, f.amp)
            if key in pending:
                while pending[0] != key:
                    pending.popleft()
                    self.eaten += 1
                pending.popleft()
            else:
                self.false_frames += 1
            self._reference(f, t_ns)

    def _reference(self, f: Frame, t_write: int) -> None:
        key = (_raw_m(f.dist), f.amp)
        seq = self.ref_count - self._offset
        self.ref_count += 1
        early = self._early.pop(seq, None)
        if early is not None:
            self.mismatched += early[0] != key
            self._read_latency(t_write, early[1])
        elif seq >= self.next_seq:
            self._expected[seq] = (key, t_write)

    def on_range(self, seq: int, raw_m: float | None, amp: int, t_read_ns: int = 0) -> bool:
        """A published range message (read by the daemon at ``t_read_ns``); False for a
        repeat (the last-value cache)."""
        with self._lock:
            last = self.next_seq - 1
            if seq == last:
                self.duplicates += 1
                return False
            if seq < last:
                self.backwards += 1
                return False
            if seq > self.next_seq:
                self.gaps += seq - self.next_seq
                for s in range(self.next_seq, seq):
                    self._expected.pop(s, None)
            self.next_seq = seq + 1
            self.published += 1
            key = (raw_m, amp)
            want = self._expected.pop(seq, None)
            if want is not None:
                self.mismatched += want[0] != key
                self._read_latency(want[1], t_read_ns)
            else:
                self._early[seq] = (key, t_read_ns)
            return True

    def settled(self) -> bool:
        """Every reference frame published and matched, nothing extra."""
        with self._lock:
            return self.next_seq == self.ref_count - self._offset and not self._early

    def close_books(self) -> tuple[int, int]:
        """After a drain: count what never came and what should not have; resync.

        Returns (missing, unexpected) found now.
        """
        with self._lock:
            missing = max(0, self.ref_count - self._offset - self.next_seq)
            unexpected = len(self._early)
            self.missing += missing
            self.unexpected += unexpected
            self._offset = self.ref_count - self.next_seq
            self._expected.clear()
            self._early.clear()
            return missing, unexpected

    def reset_parser(self) -> None:
        """The pty is gone (unplug): the daemon drops its partial frame, so do we."""
        with self._lock:
            self._parser.reset()
            self._carry = b""

    def summary(self) -> dict[str, int]:
        """The counters, for the report. ``undecided_frames``: good frames written that
        the reference parser has not found yet: one held until the next bytes decide it
        (its checksum byte is 0x59), or swallowed by a false frame with no good frame
        after it to show it."""
        with self._lock:
            return {
                "frames_sent": self.good_sent,
                "reference_frames": self.ref_count,
                "false_frames": self.false_frames,
                "eaten_frames": self.eaten,
                "undecided_frames": len(self._pending),
                "published": self.published,
                "lost": self.lost,
                "gaps": self.gaps,
                "missing": self.missing,
                "unexpected": self.unexpected,
                "mismatched": self.mismatched,
                "seq_backwards": self.backwards,
                "duplicates": self.duplicates,
            }
