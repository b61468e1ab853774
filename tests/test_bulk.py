"""Bulk (numpy) decode gives exactly what the streaming parser gives, on any bytes."""

from __future__ import annotations

import random
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from lunad.protocol import CommandReply, Frame, FrameParser, OutputFormat, encode_frame
from lunad.protocol.bulk import decode_bulk
from lunad.protocol.commands import (
    REPLY_LENGTHS,
    CommandId,
    encode_reply,
    get_full_version,
    set_output_enabled,
)
from lunad.protocol.frame import TEMP_RAW_MAX, TEMP_RAW_MIN


def assert_same(data: bytes, fmt: OutputFormat = OutputFormat.CM, follow: bool = True) -> None:
    parser = FrameParser(fmt, follow_format_replies=follow)
    items = parser.feed(data, 0)
    frames = [f for f in items if isinstance(f, Frame)]
    replies = [r for r in items if isinstance(r, CommandReply)]
    got = decode_bulk(data, fmt, follow_format_replies=follow)
    assert len(got) == len(frames)
    assert list(zip(got.dist.tolist(), got.amp.tolist(), got.temp_raw.tolist(), strict=True)) == [
        (f.dist, f.amp, f.temp_raw) for f in frames
    ]
    assert got.fmt.tolist() == [int(f.fmt) for f in frames]
    assert got.reply_ids.tolist() == [r.cmd_id for r in replies]
    for off in got.offset.tolist():
        assert data[off : off + 2] == b"\x59\x59"
    s = parser.stats
    assert (
        got.checksum_errors,
        got.implausible_frames,
        got.displaced_frames,
        got.bytes_discarded,
        got.buffered,
        got.reply_bytes,
    ) == (
        s.checksum_errors,
        s.implausible_frames,
        s.displaced_frames,
        s.bytes_discarded,
        s.buffered,
        s.reply_bytes,
    )
    dm = got.distance_m()
    for f, d in zip(frames, dm.tolist(), strict=True):
        assert (f.distance_m is None and d != d) or f.distance_m == d


frame = st.builds(
    encode_frame, st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF)
)
"""Any temperature field: most are implausible, so these test the rejection."""
real_frame = st.builds(
    encode_frame,
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(TEMP_RAW_MIN, TEMP_RAW_MAX),
)
header_runs = st.lists(st.sampled_from([0x59, 0x5A]), min_size=1, max_size=12).map(bytes)


@st.composite
def reply_like(draw: st.DrawFn) -> bytes:
    """``5A Len ID ...`` with a known (ID, Len) pair, its checksum right or not."""
    cid, length = draw(st.sampled_from(sorted(REPLY_LENGTHS.items())))
    body = bytes((0x5A, length, cid)) + draw(st.binary(min_size=length - 4, max_size=length - 4))
    cs = sum(body) & 0xFF if draw(st.booleans()) else draw(st.integers(0, 255))
    return (body + bytes((cs,)))[: draw(st.integers(3, length))]


header_rich = st.lists(st.sampled_from([0x59, 0x5A, 0x00, 0x05, 0x07, 0x01, 0xFF]), max_size=12)
reply = st.sampled_from(
    [
        encode_reply(CommandId.OUTPUT_FORMAT, bytes((OutputFormat.MM,))),
        encode_reply(CommandId.OUTPUT_FORMAT, bytes((OutputFormat.CM,))),
        encode_reply(CommandId.GET_VERSION, bytes((9, 0, 3))),
        encode_reply(CommandId.GET_FULL_VERSION, b"A" * 26),
        set_output_enabled(True),
        get_full_version()[:3],  # a cut reply header: 5A 04 14
    ]
)
dist_limit_reply = st.builds(
    lambda lo, hi, silence: encode_reply(
        CommandId.DIST_LIMIT, struct.pack("<HHB", lo, hi, silence)
    ),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(0, 1),
)
"""9 bytes long like a data frame, so only its ``5A`` header tells it apart."""


@st.composite
def corrupted(draw: st.DrawFn) -> bytes:
    f = bytearray(draw(frame))
    f[draw(st.integers(2, 8))] ^= draw(st.integers(1, 255))
    return bytes(f)


piece = st.one_of(
    frame,
    real_frame,
    real_frame,
    real_frame,
    corrupted(),
    reply,
    dist_limit_reply,
    header_rich.map(bytes),
    header_runs,
    reply_like(),
    st.binary(max_size=10),
)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=400))
def test_arbitrary_bytes(data: bytes) -> None:
    assert_same(data)


@settings(max_examples=400, deadline=None)
@given(st.lists(piece, max_size=60).map(b"".join), st.integers(0, 12))
def test_frame_rich_streams(data: bytes, cut: int) -> None:
    assert_same(data)
    assert_same(data[: max(0, len(data) - cut)])  # the end falls anywhere
    assert_same(data, OutputFormat.MM)
    assert_same(data, follow=False)


def test_empty_and_tiny() -> None:
    for data in (b"", b"\x59", b"\x59\x59", b"\x5a", b"\x5a\x07", encode_frame(1, 2, 3)[:8]):
        assert_same(data)


def test_clean_stream_is_every_frame() -> None:
    data = b"".join(encode_frame(k, 2 * k, 2000 + k % 800) for k in range(1000))
    got = decode_bulk(data + b"\x59\x59")  # the next header decides a last 0x59 checksum
    assert got.dist.tolist() == list(range(1000))
    assert got.offset.tolist() == list(range(0, 9000, 9))
    assert got.bytes_discarded == got.checksum_errors == got.implausible_frames == 0
    assert got.displaced_frames == 0 and got.buffered == 2
    assert_same(data)


def test_false_frames_over_real_ones_decode_as_the_parser_does() -> None:
    """Garbage whose last bytes and a real frame's first ones form a window with a right
    checksum and a plausible temperature; the real frame followed by the next one's
    header or by garbage: both outcomes of the parser's overlap rule."""
    rng = random.Random(7)
    data = b""
    for k in range(3000):
        frame = encode_frame(rng.randint(0, 0xFFFF), rng.randint(0, 0xFFFF), 2000 + k % 800)
        w = bytearray(b"\x59\x59" + rng.randbytes(6) + frame[:1])
        w[6:8] = rng.randint(TEMP_RAW_MIN, TEMP_RAW_MAX).to_bytes(2, "little")
        w[2] = (w[8] - sum(w[:8]) + w[2]) & 0xFF
        data += rng.randbytes(rng.randint(0, 3)) + bytes(w[:8]) + frame
    got = decode_bulk(data)
    assert got.displaced_frames > 100
    assert_same(data)


def test_runs_of_0x59_before_frames_lose_nothing() -> None:
    """A run and the real frame's first bytes form a window with a right checksum
    before about 2 % of the frames; the temperature and overlap rules drop each one."""
    rng = random.Random(5)
    frames = [
        encode_frame(rng.randint(20, 800), rng.randint(100, 30000), 2368 + k % 300)
        for k in range(3000)
    ]
    data = b"".join(b"\x59" * rng.randint(1, 40) + f for f in frames) + b"\x59\x59"
    got = decode_bulk(data)
    assert list(zip(got.dist.tolist(), got.amp.tolist(), strict=True)) == [
        (int.from_bytes(f[2:4], "little"), int.from_bytes(f[4:6], "little")) for f in frames
    ]
    assert got.implausible_frames + got.displaced_frames > 0
    assert_same(data)


def test_frame_inside_a_long_cut_reply_is_not_held_back() -> None:
    # A GET_FULL_VERSION header (30 bytes long) with only 20 bytes after it, and a good
    # frame inside: the 5A is garbage, so the frame comes out now instead of waiting for
    # bytes that may never come (a pause, an unplug; found by the soak).
    data = b"\x5a\x1e\x14" + b"\x00" * 4 + encode_frame(5, 6, 2368) + b"\x00" * 4
    assert_same(data)
    assert len(decode_bulk(data)) == 1


def test_dist_limit_reply_between_frames_is_a_reply() -> None:
    # The DIST_LIMIT echo is 9 bytes, the length of a data frame: bulk decode once took
    # it for one (a phantom 51.78 m reading, and the reply not counted).
    data = (
        encode_frame(123, 1000, 2368)
        + encode_reply(CommandId.DIST_LIMIT, struct.pack("<HHB", 20, 800, 0))
        + encode_frame(124, 1000, 2368)
    )
    assert_same(data)
    got = decode_bulk(data)
    assert got.dist.tolist() == [123, 124]
    assert got.offset.tolist() == [0, 18]
    assert got.reply_offsets.tolist() == [9]
    assert got.reply_ids.tolist() == [CommandId.DIST_LIMIT]
    assert got.reply_bytes == 9
