"""Recording format, torn-tail recovery, pacing, and the replay source."""

from __future__ import annotations

import os
import random
import struct
import tempfile
import threading
import time
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lunad.daemon.config import SourceSection
from lunad.daemon.errors import LunadError, SourceOpenError
from lunad.daemon.sources.base import Chunk
from lunad.daemon.sources.recording import (
    MAGIC,
    MAX_RECORD_BYTES,
    MAX_TORN_BYTES,
    Pacer,
    Recorder,
    RecordFormatError,
    RecordingBusyError,
    Replay,
    paced,
)
from lunad.daemon.sources.replay import ReplaySource
from lunad.protocol import FrameParser, encode_frame
from lunad.protocol.client import Subscriber
from lunad.protocol.messages import I64_MAX, HealthMessage
from lunad.sim.pty_device import PtyDevice

RECORD_OVERHEAD = 16  # t_mono_ns u64 + length u32 + crc32 u32
MS = 1_000_000  # nanoseconds

CHUNKS = [
    Chunk(b"\x59\x59\x10\x00", 1_000 * MS),
    Chunk(b"", 1_010 * MS),
    Chunk(bytes(range(256)), 1_020 * MS),
]


def record(path: Path, chunks: Iterable[Chunk], desc: str = "test") -> None:
    with Recorder(path, desc) as rec:
        for chunk in chunks:
            rec(chunk)


def read_all(path: Path) -> tuple[list[Chunk], int]:
    with Replay(path) as rep:
        return list(rep), rep.torn_records


# --- format round trip --------------------------------------------------------------


def test_round_trip_and_header(tmp_path: Path) -> None:
    path = tmp_path / "a.lunarec"
    before_ns = time.time_ns()
    with Recorder(path, "serial /dev/ttyAMA0 115200 Bd", frame_rate_hz=250) as rec:
        for chunk in CHUNKS:
            rec(chunk)
        assert rec.records == 3
        assert rec.bytes == 4 + 0 + 256
    assert path.read_bytes().startswith(MAGIC)
    with Replay(path) as rep:
        assert rep.header.version == 2
        assert rep.header.source_desc == "serial /dev/ttyAMA0 115200 Bd"
        assert rep.header.frame_rate_hz == 250
        assert before_ns <= rep.header.created_unix_ns <= time.time_ns()
        assert list(rep) == CHUNKS
        assert rep.records == 3
        assert rep.torn_records == 0
        assert rep.trailing_bytes == 0


chunk_lists = st.lists(
    st.builds(Chunk, st.binary(max_size=64), st.integers(min_value=0, max_value=I64_MAX)),
    max_size=20,
)


@given(chunks=chunk_lists, desc=st.text(max_size=40))
@settings(max_examples=60, deadline=None)
def test_any_chunks_round_trip(chunks: list[Chunk], desc: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "h.lunarec"
        record(path, chunks, desc)
        with Replay(path) as rep:
            assert list(rep) == chunks
            assert rep.header.source_desc == desc
            assert rep.torn_records == 0


def test_recorder_rejects_misuse(tmp_path: Path) -> None:
    with Recorder(tmp_path / "m.lunarec") as rec:
        with pytest.raises(ValueError, match="an i64"):
            rec(Chunk(b"x", -1))
        with pytest.raises(ValueError, match="an i64"):  # a time its reader would skip
            rec(Chunk(b"x", I64_MAX + 1))
        with pytest.raises(ValueError, match="at most"):
            rec(Chunk(bytes((1 << 20) + 1), 0))
    with pytest.raises(ValueError, match="closed"):
        rec(Chunk(b"x", 0))
    with pytest.raises(ValueError, match="source_desc"):
        Recorder(tmp_path / "n.lunarec", "x" * 2000)


def test_one_writer_at_a_time(tmp_path: Path) -> None:
    """Two recorders on one file (``lunad record`` beside ``serve --record``) each
    appended at their own offset, overwriting and cutting short the other's records.
    The second is refused before it touches the file, even a tail that looks torn
    because the first is in the middle of a write; readers need no lock."""
    path = tmp_path / "one.lunarec"
    with Recorder(path, "first") as first:
        first(CHUNKS[0])
        with open(path, "ab") as f:
            f.write(b"\x00" * 5)  # the first recorder's next record, partly written
        before = path.read_bytes()
        with pytest.raises(RecordingBusyError, match="being recorded by another process"):
            Recorder(path, "second")
        with pytest.raises(RecordFormatError):  # the type callers already refuse
            Recorder(path, "second")
        assert path.read_bytes() == before
        assert read_all(path) == ([CHUNKS[0]], 1)
    with Recorder(path, "later") as later:  # close released it
        assert later.truncated_bytes == 5
        later(CHUNKS[1])
    assert read_all(path) == (CHUNKS[:2], 0)


def test_a_new_file_is_locked_from_its_creation(tmp_path: Path) -> None:
    path = tmp_path / "new.lunarec"
    with Recorder(path, "first") as first:
        with pytest.raises(RecordingBusyError):
            Recorder(path, "second")
        first(CHUNKS[0])
    assert read_all(path) == ([CHUNKS[0]], 0)


# --- power cuts and corruption ------------------------------------------------------


def test_cut_anywhere_in_last_record_keeps_earlier_ones(tmp_path: Path) -> None:
    """A cut at every byte offset of the last record: earlier records read, never raises;
    appending afterwards drops the torn tail and continues after the last good record."""
    whole = tmp_path / "whole.lunarec"
    record(whole, CHUNKS)
    data = whole.read_bytes()
    last_start = len(data) - RECORD_OVERHEAD - len(CHUNKS[-1].data)
    extra = Chunk(b"after the cut", 2_000 * MS)
    for cut in range(last_start, len(data)):
        path = tmp_path / f"cut{cut}.lunarec"
        path.write_bytes(data[:cut])
        chunks, torn = read_all(path)
        assert chunks == CHUNKS[:-1], cut
        assert torn == (1 if cut > last_start else 0), cut
        with Recorder(path) as rec:
            assert rec.truncated_bytes == cut - last_start
            rec(extra)
        assert read_all(path) == ([*CHUNKS[:-1], extra], 0), cut


@pytest.mark.parametrize("offset_from_end", [1, 256, 256 + 4, 256 + 8, 256 + 16])
def test_corrupt_last_record_is_skipped(tmp_path: Path, offset_from_end: int) -> None:
    """A flipped bit in the data, CRC, length or time of the last record."""
    path = tmp_path / "bad.lunarec"
    record(path, CHUNKS)
    data = bytearray(path.read_bytes())
    data[-offset_from_end] ^= 0x01
    path.write_bytes(bytes(data))
    with Replay(path) as rep:
        assert list(rep) == CHUNKS[:-1]
        assert rep.torn_records == 1 and not rep.damaged  # nothing good after it


def first_record_offset(whole: bytes) -> int:
    return len(whole) - sum(RECORD_OVERHEAD + len(c.data) for c in CHUNKS)


@pytest.mark.parametrize(
    "cut",
    [
        pytest.param(lambda b: b[:-5], id="last record cut short"),
        pytest.param(lambda b: b + bytes(60), id="a tail of zeros"),
        pytest.param(lambda b: b + bytes(MAX_TORN_BYTES), id="the most zeros a tear leaves"),
    ],
)
def test_a_recording_cut_short_is_a_torn_tail(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, cut: Callable[[bytes], bytes]
) -> None:
    """What a power cut leaves: an INFO line, not the damaged file's warning."""
    path = tmp_path / "cut.lunarec"
    record(path, CHUNKS)
    whole = path.read_bytes()
    path.write_bytes(cut(whole))
    with caplog.at_level("INFO"), Replay(path) as rep:
        assert list(rep) == (CHUNKS[:-1] if len(cut(whole)) < len(whole) else CHUNKS)
        assert rep.torn_records == 1 and not rep.damaged
    assert [r.levelname for r in caplog.records] == ["INFO"]
    assert "torn last record" in caplog.text


@pytest.mark.parametrize(
    ("where", "flip"),
    [
        pytest.param(RECORD_OVERHEAD, 0x01, id="data: CRC fails"),
        pytest.param(9, 0x40, id="length: 16 KiB more, past the end"),
        pytest.param(11, 0x80, id="length: beyond MAX_RECORD_BYTES"),
    ],
)
def test_a_recording_damaged_mid_file_is_told_from_one_cut_short(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, where: int, flip: int
) -> None:
    """A corrupt first record loses the rest of the file: logged at INFO as a torn
    record, it read like the harmless tail of a power cut; and appending to the file
    cut it at the corrupt record, deleting the good ones after it."""
    path = tmp_path / "mid.lunarec"
    record(path, CHUNKS)
    whole = path.read_bytes()
    damaged = bytearray(whole)
    first = first_record_offset(whole)
    damaged[first + where] ^= flip
    path.write_bytes(bytes(damaged))
    with caplog.at_level("INFO"), Replay(path) as rep:
        assert list(rep) == []
        assert rep.damaged and rep.trailing_bytes == len(whole) - first
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert f"damaged: a corrupt record at byte {first}" in caplog.text
    with pytest.raises(RecordFormatError, match="record to a new file"):
        Recorder(path)
    assert path.read_bytes() == bytes(damaged)  # untouched


def test_garbage_length_does_not_swallow_memory(tmp_path: Path) -> None:
    path = tmp_path / "len.lunarec"
    record(path, CHUNKS[:1])
    with open(path, "ab") as f:
        f.write(struct.pack("<QII", 5, 0xFFFF_FFFF, 0) + b"junk")
    with Replay(path) as rep:
        assert list(rep) == CHUNKS[:1]
        assert rep.torn_records == 1
        assert rep.damaged  # no record lunad writes claims 4 GiB: not a tear
        assert rep.trailing_bytes == RECORD_OVERHEAD + 4


TEST_HEADER_BYTES = 32 + len(b"test") + 4
"""The header ``record`` writes: the fixed part, the description "test", the CRC."""
FIVE_FRAMES = b"".join(encode_frame(300 + i, 1000, 2400) for i in range(5))
"""One read of a 250 Hz sensor: a 61-byte record."""
HOLE_AT, HOLE_BYTES = 40_000, 20_000


def records_end(chunks: Iterable[Chunk]) -> int:
    """The byte just after ``chunks``, recorded by ``record`` into a new file."""
    return TEST_HEADER_BYTES + sum(RECORD_OVERHEAD + len(c.data) for c in chunks)


def hole_in_3000_records(path: Path) -> list[Chunk]:
    """3000 reads, then 20 000 bytes zeroed at byte 40 000 (a bad block of the card):
    longer than the look-ahead after a bad record, so no good record is found after it.
    Returns the chunks still readable, those wholly before the hole."""
    chunks = [Chunk(FIVE_FRAMES, 10**9 + k * 4 * MS) for k in range(3000)]
    record(path, chunks)
    data = bytearray(path.read_bytes())
    data[HOLE_AT : HOLE_AT + HOLE_BYTES] = bytes(HOLE_BYTES)
    path.write_bytes(bytes(data))
    return chunks[: (HOLE_AT - TEST_HEADER_BYTES) // (RECORD_OVERHEAD + len(FIVE_FRAMES))]


def noise_after_the_header(path: Path) -> list[Chunk]:
    """A header, then 100 KB of noise (another file's blocks after a crash)."""
    record(path, [])
    with open(path, "ab") as f:
        f.write(random.Random(7).randbytes(100_000))
    return []


def zeros_past_a_tear(path: Path) -> list[Chunk]:
    """One byte more zeros than a torn record leaves."""
    record(path, CHUNKS)
    with open(path, "ab") as f:
        f.write(bytes(MAX_TORN_BYTES + 1))
    return CHUNKS


def a_length_no_record_has(path: Path) -> list[Chunk]:
    """A last record header claiming one byte more than ``Recorder`` writes."""
    record(path, CHUNKS)
    with open(path, "ab") as f:
        f.write(struct.pack("<QII", 5, MAX_RECORD_BYTES + 1, 0))
    return CHUNKS


@pytest.mark.parametrize(
    "damage",
    [
        pytest.param(hole_in_3000_records, id="20 000 zeros in 3000 records"),
        pytest.param(noise_after_the_header, id="100 KB of noise after the header"),
        pytest.param(zeros_past_a_tear, id="a tear's most zeros and one byte"),
        pytest.param(a_length_no_record_has, id="a length past MAX_RECORD_BYTES"),
    ],
)
def test_what_one_torn_record_cannot_leave_is_damage(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: Callable[[Path], list[Chunk]]
) -> None:
    """Damage longer than the look-ahead found no good record after it, and was taken for
    a torn last record: the replay said at INFO that a power cut had cut it short, and
    appending cut the file there, deleting (for the hole) 78 % of its good records after
    one warning. A power cut tears one record: more bytes than that, or a length no
    record has, is damage, warned about by the reader and refused by the appender."""
    path = tmp_path / "damaged.lunarec"
    kept = damage(path)
    hostile = path.read_bytes()
    good_end = records_end(kept)
    skipped = len(hostile) - good_end
    with caplog.at_level("INFO"), Replay(path) as rep:
        assert list(rep) == kept
        assert rep.damaged and rep.torn_records == 1 and rep.trailing_bytes == skipped
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert f"damaged: a corrupt record at byte {good_end} (" in caplog.text
    assert f"the {skipped} bytes from there on" in caplog.text
    assert "torn last record" not in caplog.text
    caplog.clear()
    with pytest.raises(RecordFormatError, match=f"damaged at byte {good_end} .*record to a new"):
        Recorder(path)
    assert path.read_bytes() == hostile  # untouched
    assert "dropping" not in caplog.text


def test_lunad_record_and_serve_refuse_a_hole_they_cut_the_file_at(
    device: Callable[..., PtyDevice], tmp_path: Path, endpoint: str, helpers: Any
) -> None:
    """A hole past the look-ahead, through the real commands: ``lunad record --out``
    and ``lunad serve --record`` warned of "a torn last record (143045 bytes)", cut the
    file at the hole and recorded on, the good records after it gone. Both now refuse it as the
    damaged file it is, with one line and exit 78, and leave it byte for byte."""
    dev = device(rate_hz=100, output_enabled=False)
    path = tmp_path / "hole.lunarec"
    hole_in_3000_records(path)
    for said in helpers.recording_refused(dev.path, endpoint, path):
        assert "damaged at byte" in said and "record to a new file" in said


@pytest.mark.parametrize("cut", [1, 4096], ids=["one byte short", "only its header"])
def test_a_cut_through_the_longest_read_is_still_a_tear(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, cut: int
) -> None:
    """A record holds one read of the port, at most 4096 bytes: a power cut through the
    longest is a torn record (INFO; appending cuts it off) under the bound on a tear."""
    longest = Chunk(bytes(range(256)) * 16, 2_000 * MS)
    path = tmp_path / "long.lunarec"
    record(path, [*CHUNKS, longest])
    path.write_bytes(path.read_bytes()[:-cut])
    with caplog.at_level("INFO"), Replay(path) as rep:
        assert list(rep) == CHUNKS
        assert rep.torn_records == 1 and not rep.damaged
    assert [r.levelname for r in caplog.records] == ["INFO"]
    assert "torn last record" in caplog.text
    with Recorder(path) as rec:
        assert rec.truncated_bytes == RECORD_OVERHEAD + len(longest.data) - cut
    assert read_all(path) == (CHUNKS, 0)


def record_at(t_mono_ns: int, data: bytes) -> bytes:
    """One record laid out as ``Recorder``'s table says, for a time it refuses to write."""
    head = struct.pack("<QI", t_mono_ns, len(data))
    return head + struct.pack("<I", zlib.crc32(data, zlib.crc32(head))) + data


@pytest.mark.parametrize("t_mono_ns", [I64_MAX + 1, 18_446_744_073_219_551_615, 2**64 - 1])
def test_a_time_past_the_messages_i64_is_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, t_mono_ns: int
) -> None:
    """A record whose CRC checks but whose t_mono_ns no i64 holds was replayed, and the
    daemon published that time, outside the message contract. It is skipped, counted and
    warned about; its CRC vouches for its length, so the records after it are read, and
    appending goes on after it rather than cutting it off as torn."""
    path = tmp_path / "t.lunarec"
    record(path, CHUNKS[:1])
    with open(path, "ab") as f:
        f.write(record_at(t_mono_ns, b"\x59\x59\x10\x00"))
    with Recorder(path) as rec:
        assert rec.truncated_bytes == 0
        for chunk in CHUNKS[1:]:
            rec(chunk)
    with caplog.at_level("INFO"), Replay(path) as rep:
        assert list(rep) == CHUNKS
        assert rep.skipped_records == 1
        assert rep.torn_records == 0 and not rep.damaged
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    first = records_end(CHUNKS[:1])
    assert f"skipped 1 records (the first at byte {first}) whose t_mono_ns" in caplog.text


def test_the_largest_i64_time_is_kept(tmp_path: Path) -> None:
    path = tmp_path / "max.lunarec"
    record(path, [Chunk(b"x", I64_MAX)])
    with Replay(path) as rep:
        assert list(rep) == [Chunk(b"x", I64_MAX)]
        assert rep.skipped_records == 0


def test_a_replay_publishes_no_time_outside_the_contract(
    start_daemon: Any, endpoint: str, tmp_path: Path
) -> None:
    """``lunad serve --replay`` published "t_mono_ns":18446744073219551615, which no
    subscriber decodes (an i64). The record is skipped: every message decodes, the last
    health counts the good frames only, and the log says what was skipped."""
    path = tmp_path / "t.lunarec"
    with Recorder(path, "test", frame_rate_hz=250) as rec:
        for k in range(30):
            rec(Chunk(FIVE_FRAMES, 10**12 + (k + 1) * 20 * MS))
    with open(path, "ab") as f:
        f.write(record_at(18_446_744_073_219_551_615, FIVE_FRAMES))
    with Recorder(path) as rec:  # well under the daemon's send limit of 1000 messages
        for k in range(30, 60):
            rec(Chunk(FIVE_FRAMES, 10**12 + (k + 1) * 20 * MS))
    d = start_daemon("--replay", str(path), "--speed", "max", "--publish", endpoint)
    last: HealthMessage | None = None
    with Subscriber(endpoint) as sub:
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and (last is None or last.state != "stopped"):
            msg = sub.recv(timeout_s=1.0)
            if isinstance(msg, HealthMessage):
                last = msg
        bad_messages = sub.bad_messages
    assert last is not None and last.state == "stopped", d.log
    assert last.frames == 60 * 5 and bad_messages == 0, d.log
    assert "skipped 1 records" in d.log and "Traceback" not in d.log


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"\x59\x59\x10\x00" * 20, "not a lunad recording"),
        (b"", "empty"),
        (MAGIC + b"\x01", "cut short"),
    ],
)
def test_bad_header_is_a_clear_error(tmp_path: Path, content: bytes, match: str) -> None:
    path = tmp_path / "other.bin"
    path.write_bytes(content)
    with pytest.raises(RecordFormatError, match=match) as info:
        Replay(path)
    assert str(path) in str(info.value)
    assert isinstance(info.value, LunadError)
    assert isinstance(info.value, ValueError)


def test_newer_version_and_corrupt_header(tmp_path: Path) -> None:
    path = tmp_path / "v.lunarec"
    record(path, CHUNKS)
    good = path.read_bytes()
    path.write_bytes(good[:8] + struct.pack("<H", 3) + good[10:])
    with pytest.raises(RecordFormatError, match="version 3; this lunad reads 1 and 2"):
        Replay(path)
    path.write_bytes(good[:32] + b"T" + good[33:])  # first description byte
    with pytest.raises(RecordFormatError, match="checksum"):
        Replay(path)
    path.write_bytes(good[:30] + b"\xfa" + good[31:])  # the frame rate
    with pytest.raises(RecordFormatError, match="checksum"):
        Replay(path)


def test_version_1_files_still_replay_and_take_appends(tmp_path: Path) -> None:
    """Format 2 added the frame rate; a recording made in format 1 still reads,
    with no rate (a replay then spaces frames by ``--rate``), and appending keeps it 1."""
    import zlib

    v2 = tmp_path / "v2.lunarec"
    record(v2, CHUNKS[:2], "old")
    records = v2.read_bytes()[32 + len("old") + 4 :]
    body = struct.pack("<8sHHqqH", MAGIC, 1, 0, 5, 6, 3) + b"old"
    v1 = tmp_path / "v1.lunarec"
    v1.write_bytes(body + struct.pack("<I", zlib.crc32(body)) + records)
    with Replay(v1) as rep:
        assert (rep.header.version, rep.header.frame_rate_hz) == (1, 0)
        assert (rep.header.created_unix_ns, rep.header.source_desc) == (5, "old")
        assert list(rep) == CHUNKS[:2]
    with Recorder(v1, "new", frame_rate_hz=250) as rec:
        rec(CHUNKS[2])
    with Replay(v1) as rep:
        assert (rep.header.version, rep.header.frame_rate_hz, rep.header.source_desc) == (
            1,
            0,
            "old",
        )
        assert list(rep) == CHUNKS
    src = ReplaySource(v1, speed=None)
    try:
        assert src.frame_rate_hz is None
    finally:
        src.close()
    with Recorder(tmp_path / "r.lunarec", frame_rate_hz=100):
        pass
    src = ReplaySource(tmp_path / "r.lunarec", speed=None)
    try:
        assert src.frame_rate_hz == 100
    finally:
        src.close()


def test_recorder_refuses_to_append_to_a_foreign_file(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_bytes(b"my notes, not a recording\n")
    with pytest.raises(RecordFormatError, match="not a lunad recording"):
        Recorder(path)
    assert path.read_bytes() == b"my notes, not a recording\n"


@pytest.mark.parametrize("keep", [0, 5, 20, 33])
def test_recorder_restarts_a_torn_header(tmp_path: Path, keep: int) -> None:
    path = tmp_path / "t.lunarec"
    record(path, [], "first")
    path.write_bytes(path.read_bytes()[:keep])
    record(path, CHUNKS[:1], "second")
    with Replay(path) as rep:
        assert rep.header.source_desc == "second"
        assert list(rep) == CHUNKS[:1]


def test_append_keeps_earlier_records_and_header(tmp_path: Path) -> None:
    path = tmp_path / "app.lunarec"
    record(path, CHUNKS[:2], "first recording")
    with Recorder(path, "second recording") as rec:
        rec(CHUNKS[2])
        assert rec.records == 1
        assert rec.truncated_bytes == 0
    with Replay(path) as rep:
        assert rep.header.source_desc == "first recording"
        assert list(rep) == CHUNKS


def test_fsync_interval_zero_syncs_every_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    synced: list[int] = []
    real_fsync = os.fsync

    def recording_fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    with Recorder(tmp_path / "s.lunarec", fsync_interval_s=0.0) as rec:
        synced.clear()
        rec(CHUNKS[0])
        rec(CHUNKS[1])
        assert len(synced) == 2
    assert len(synced) == 3  # and once on close


# --- pacing --------------------------------------------------------------------------


class FakeClock:
    """A monotonic clock that only moves when ``sleep`` is called."""

    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def chunks_at(*ms: int) -> list[Chunk]:
    return [Chunk(bytes([i]), t * MS) for i, t in enumerate(ms)]


def test_paced_none_never_sleeps() -> None:
    clock = FakeClock()
    chunks = chunks_at(0, 500, 5000)
    assert list(paced(chunks, None, clock=clock, sleep=clock.sleep)) == chunks
    assert clock.sleeps == []


def test_paced_speed_two_halves_every_gap() -> None:
    clock = FakeClock()
    chunks = chunks_at(0, 100, 300, 600)
    out = list(paced(chunks, 2.0, clock=clock, sleep=clock.sleep))
    assert out == chunks
    assert clock.sleeps == pytest.approx([0.05, 0.1, 0.15])
    assert clock.now - 100.0 == pytest.approx(0.3)


def test_paced_shortens_long_gaps_and_ignores_backward_steps() -> None:
    clock = FakeClock()
    chunks = chunks_at(0, 10_000, 10_100, 50, 150)  # a pause, then a reboot
    out = list(paced(chunks, 1.0, max_gap_s=1.0, clock=clock, sleep=clock.sleep))
    assert out == chunks
    assert clock.sleeps == pytest.approx([1.0, 0.1, 0.1])


def test_paced_does_not_drift_when_the_consumer_is_slow() -> None:
    clock = FakeClock()
    for _chunk in paced(chunks_at(0, 100, 200, 300), 1.0, clock=clock, sleep=clock.sleep):
        clock.now += 0.15  # the consumer takes longer than the gap
    assert clock.sleeps == []  # always behind schedule, so never waits


def test_paced_stops_on_event() -> None:
    stop = threading.Event()
    clock = FakeClock()

    def sleep(seconds: float) -> None:
        clock.sleep(seconds)
        stop.set()

    out = list(paced(chunks_at(0, 100, 200), 1.0, stop=stop, clock=clock, sleep=sleep))
    assert out == chunks_at(0)
    stop.clear()
    stop.set()
    assert list(paced(chunks_at(0, 1), None, stop=stop)) == []


def test_paced_default_sleep_is_cut_short_by_stop() -> None:
    stop = threading.Event()
    timer = threading.Timer(0.05, stop.set)
    timer.start()
    t0 = time.monotonic()
    out = list(paced(chunks_at(0, 60_000), 1.0, max_gap_s=None, stop=stop))
    timer.join()
    assert out == chunks_at(0)
    assert time.monotonic() - t0 < 30.0  # the 60 s gap was interrupted


@pytest.mark.parametrize("speed", [0.0, -1.0, float("inf"), float("nan")])
def test_bad_speed_is_rejected(speed: float) -> None:
    with pytest.raises(ValueError, match="speed"):
        list(paced(chunks_at(0), speed))
    with pytest.raises(ValueError, match="speed"):
        Pacer(speed)


def test_a_new_speed_paces_the_rest_from_where_the_replay_is() -> None:
    """Recording time played at the old speed stays played; what is left of the gap to
    the pending chunk, and every gap after it, takes 1 / speed of its recorded time."""
    now = [100.0]
    pacer = Pacer(1.0, max_gap_s=None, clock=lambda: now[0])
    ms = 1_000_000
    assert pacer.due(0) == 100.0
    assert pacer.due(1000 * ms) == 101.0
    now[0] = 100.6  # 0.6 s of the 1 s gap played: 0.4 s of it left, at 4x 0.1 s
    pacer.set_speed(4.0)
    assert pacer.last_due_s == pytest.approx(100.7)
    assert pacer.due(3000 * ms) == pytest.approx(101.2)
    pacer.set_speed(0.5)  # before the pending chunk's due time
    assert pacer.last_due_s == pytest.approx(100.6 + (3.0 - 0.6) / 0.5)
    with pytest.raises(ValueError, match="speed"):
        pacer.set_speed(0.0)


# --- replay source -------------------------------------------------------------------


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "rec.lunarec"
    record(path, chunks_at(0, 10, 20), "serial loop://")
    return path


def test_replay_source_yields_recorded_times_and_exhausts(recording: Path) -> None:
    with ReplaySource(recording, speed=None) as src:
        got = [src.read(1.0) for _ in range(3)]
        assert got == chunks_at(0, 10, 20)
        assert src.exhausted
        t0 = time.monotonic()
        assert src.read(None) is None
        assert time.monotonic() - t0 < 1.0
        assert str(src) == f"replay {recording} at max speed"


def test_replay_source_paces_within_timeout(tmp_path: Path) -> None:
    path = tmp_path / "slow.lunarec"
    record(path, chunks_at(0, 60_000))
    with ReplaySource(path, speed=1.0, max_gap_s=None) as src:
        assert str(src) == f"replay {path} at 1x"
        assert src.read(0.0) == chunks_at(0)[0]
        t0 = time.monotonic()
        assert src.read(0.02) is None  # the next chunk is a minute away
        assert time.monotonic() - t0 < 5.0
        assert not src.exhausted


def test_replay_source_cancel_wakes_a_pacing_wait(tmp_path: Path) -> None:
    path = tmp_path / "slow.lunarec"
    record(path, chunks_at(0, 60_000))
    with ReplaySource(path, speed=1.0, max_gap_s=None) as src:
        assert src.read(None) is not None
        timer = threading.Timer(0.05, src.cancel)
        timer.start()
        t0 = time.monotonic()
        assert src.read(None) is None
        timer.join()
        assert time.monotonic() - t0 < 30.0
        src.cancel()  # a pending wake-up makes the next read return at once
        assert src.read(None) is None


def test_replay_source_fast_speed_in_order(recording: Path) -> None:
    with ReplaySource(recording, speed=1000.0) as src:
        got = []
        while not src.exhausted:
            chunk = src.read(1.0)
            if chunk is not None:
                got.append(chunk)
        assert got == chunks_at(0, 10, 20)


def test_replay_source_ignores_writes_and_closes_twice(recording: Path) -> None:
    src = ReplaySource(recording, speed=None)
    src.write(b"\x5a\x04\x01\x5f")
    assert src.ignored_writes == 1
    src.close()
    src.close()
    src.cancel()
    assert src.read(0.0) is None


def test_replay_source_from_config_and_errors(recording: Path, tmp_path: Path) -> None:
    cfg = SourceSection(kind="replay", path=str(recording), speed=2.0)
    with ReplaySource.from_config(cfg) as src:
        assert str(src).endswith("at 2x")
    with pytest.raises(SourceOpenError, match=r"\[source\] path"):
        # No path, on purpose (a SourceSection of kind replay refuses that itself):
        # from_config's own check.
        ReplaySource.from_config(SimpleNamespace(path=None, speed=1.0))  # type: ignore[arg-type]
    with pytest.raises(SourceOpenError, match="missing"):
        ReplaySource(tmp_path / "missing.lunarec")
    with pytest.raises(ValueError, match="speed"):
        ReplaySource(recording, speed=0.0)


@pytest.mark.parametrize(("header_hz", "taken"), [(100, 100), (1, 1), (0, None), (300, None)])
def test_replay_source_takes_a_header_rate_the_sensor_can_run_at(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, header_hz: int, taken: int | None
) -> None:
    """A rate of 500/n Hz is the live run's; 0 says none (format 1 writes none); 300 Hz,
    which no TF-Luna runs at, is a header lunad did not write: not taken, and said."""
    path = tmp_path / "r.lunarec"
    with Recorder(path, "test", frame_rate_hz=header_hz) as rec:
        rec(Chunk(encode_frame(200, 1500, 2368), 1))
    with caplog.at_level("WARNING"), ReplaySource(path) as src:
        assert src.frame_rate_hz == taken
    said = "its header gives 300 frames a second, a rate the sensor cannot run at"
    assert (said in caplog.text) == (header_hz == 300)


def test_replay_source_reports_a_torn_tail(recording: Path) -> None:
    recording.write_bytes(recording.read_bytes()[:-3])
    with ReplaySource(recording, speed=None) as src:
        got = [src.read(0.0), src.read(0.0)]
        assert got == chunks_at(0, 10)
        assert src.exhausted
        assert src.torn_records == 1


def test_replay_feeds_the_parser_exactly_as_live(tmp_path: Path) -> None:
    """The same bytes and times, cut differently by reads, parse to identical frames."""
    stream = b"".join(encode_frame(100 + i, 1000 + i, 2400) for i in range(50)) + b"\x59junk"
    live = [Chunk(stream[i : i + 7], 1_000_000 + i * 7_000) for i in range(0, len(stream), 7)]
    path = tmp_path / "live.lunarec"
    live_parser = FrameParser()
    live_out = []
    with Recorder(path, "test") as rec:
        for chunk in live:
            rec(chunk)
            live_out += live_parser.feed(chunk.data, chunk.t_mono_ns)
    replay_parser = FrameParser()
    replay_out = []
    with ReplaySource(path, speed=None) as src:
        while (read := src.read(0.0)) is not None:
            replay_out += replay_parser.feed(read.data, read.t_mono_ns)
    assert replay_out == live_out
    assert len(live_out) == 50
    assert replay_parser.stats == live_parser.stats
