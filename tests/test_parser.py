"""The streaming frame parser: exact frames in any chunking, counters that add up, no raise."""

from __future__ import annotations

from collections.abc import Sequence

from hypothesis import given, settings
from hypothesis import strategies as st

from lunad.protocol import CommandReply, Frame, FrameParser, OutputFormat, encode_frame
from lunad.protocol.commands import CommandId, decode_reply, encode_reply, set_output_format
from lunad.protocol.frame import TEMP_RAW_MAX, TEMP_RAW_MIN
from lunad.protocol.parser import MAX_BUFFERED

HEADER_BYTES = {0x59, 0x5A}


def feed_chunks(data: bytes, cuts: Sequence[int]) -> tuple[list[Frame | CommandReply], FrameParser]:
    p = FrameParser()
    out: list[Frame | CommandReply] = []
    pos = 0
    for i, cut in enumerate(sorted(set(c % (len(data) + 1) for c in cuts))):
        out += p.feed(data[pos:cut], i)
        pos = cut
    out += p.feed(data[pos:], 10**9)
    return out, p


def three_ways(data: bytes) -> list[list[tuple[int, int, int]]]:
    """Feed whole, byte by byte, and with trailing junk that must stay buffered."""
    results = []
    whole = FrameParser().feed(data, 0)
    results.append(whole)
    p = FrameParser()
    results.append([x for b in data for x in p.feed(bytes((b,)), 0)])
    p = FrameParser()
    tail = encode_frame(1, 2, 3)[:5]
    results.append(p.feed(data + tail, 0))
    assert p.stats.buffered == len(tail)
    return [[(f.dist, f.amp, f.temp_raw) for f in r if isinstance(f, Frame)] for r in results]


def test_known_frame_three_ways() -> None:
    data = bytes.fromhex("59 59 7B 00 E8 03 40 09 61")  # docs/tfluna.md section 1.5
    for frames in three_ways(data):
        assert frames == [(123, 1000, 0x0940)]
    f = FrameParser().feed(data, 7)[0]
    assert isinstance(f, Frame)
    assert f.distance_m == 1.23 and f.temp_c == 40.0 and f.t_mono_ns == 7


def test_weak_and_overexposed_frames_parse_with_no_distance() -> None:
    weak = bytes.fromhex("59 59 00 00 39 00 40 09 34")
    over = bytes.fromhex("59 59 00 00 FF FF 40 09 F9")
    frames = FrameParser().feed(weak + over, 0)
    assert all(isinstance(f, Frame) for f in frames)
    got = [(f.amp, f.distance_m) for f in frames if isinstance(f, Frame)]
    assert got == [(57, None), (0xFFFF, None)]


def test_mm_format() -> None:
    p = FrameParser(OutputFormat.MM)
    (f,) = p.feed(encode_frame(1234, 500, 2368), 0)
    assert isinstance(f, Frame) and f.distance_m == 1.234


def test_format_echo_switches_unit() -> None:
    p = FrameParser()
    out = p.feed(encode_reply(0x05, b"\x06") + encode_frame(1500, 900, 2368), 0)
    assert isinstance(out[0], CommandReply)
    assert isinstance(out[1], Frame) and out[1].distance_m == 1.5


MM_ECHO = encode_reply(CommandId.OUTPUT_FORMAT, bytes((OutputFormat.MM,)))
CM_ECHO = encode_reply(CommandId.OUTPUT_FORMAT, bytes((OutputFormat.CM,)))


def test_unsolicited_format_reply_is_returned_but_changes_no_unit() -> None:
    """Five garbage bytes ``5A 05 05 06 6A`` are a good format reply: a parser told not
    to follow format replies returns it and keeps reading centimetres."""
    assert MM_ECHO == set_output_format(OutputFormat.MM) == bytes.fromhex("5A 05 05 06 6A")
    frame = encode_frame(150, 900, 2368)
    for data in (MM_ECHO + frame, frame + MM_ECHO + frame):
        p = FrameParser(follow_format_replies=False)
        out = [x for b in data for x in p.feed(bytes((b,)), 0)]
        replies = [x for x in out if isinstance(x, CommandReply)]
        assert [decode_reply(r) for r in replies] == [OutputFormat.MM]
        assert [(f.fmt, f.distance_m) for f in out if isinstance(f, Frame)][-1] == (
            OutputFormat.CM,
            1.5,
        )
        assert p.fmt is OutputFormat.CM


def test_expected_format_reply_switches_at_its_place_in_the_stream() -> None:
    """The echo the caller waits for switches the unit between the frames around it, in
    one read too; it is spent once seen, and other echoes change nothing."""
    f = encode_frame(1500, 900, 2368)
    data = f + CM_ECHO + f + MM_ECHO + f + CM_ECHO + f
    for chunks in ([data], [data[:10], data[10:30], data[30:]]):
        p = FrameParser(follow_format_replies=False)
        p.expect_format(OutputFormat.MM)
        out = [x for c in chunks for x in p.feed(c, 0)]
        units = [x.fmt for x in out if isinstance(x, Frame)]
        assert units == [OutputFormat.CM, OutputFormat.CM, OutputFormat.MM, OutputFormat.MM]
        assert p.stats.replies == 3 and p.fmt is OutputFormat.MM
    p = FrameParser(follow_format_replies=False)
    p.expect_format(OutputFormat.MM)
    p.expect_format(None)
    p.feed(MM_ECHO, 0)
    assert p.fmt is OutputFormat.CM


def test_bad_checksum_rescans_from_next_byte() -> None:
    """A frame whose checksum is wrong costs only itself, even when a good one starts inside it."""
    good = encode_frame(200, 1000, 2368)
    # a bad candidate made of a stray 0x59 in front of a good frame: 59 59 59 ...
    data = b"\x59" + good + bytes((0x59, 0x59, 1, 2, 3, 4, 5, 6, 0)) + good
    p = FrameParser()
    frames = [f for f in p.feed(data, 0) if isinstance(f, Frame)]
    assert len(frames) == 2
    assert p.stats.checksum_errors == 2
    assert p.stats.bytes_discarded == 10


def test_cut_frame_then_good_frame() -> None:
    good = encode_frame(321, 4000, 2400)
    data = encode_frame(100, 100, 100)[:5] + good
    frames = [f for f in FrameParser().feed(data, 0) if isinstance(f, Frame)]
    assert [(f.dist, f.amp) for f in frames] == [(321, 4000)]


def test_buffer_is_bounded_by_one_partial_frame() -> None:
    p = FrameParser()
    p.feed(b"\x5a\x1e\x14" + b"A" * 20, 0)  # the start of a 30-byte full-version reply
    assert p.stats.buffered == 23
    p.feed(bytes(range(256)) * 40, 0)
    assert p.stats.buffered < MAX_BUFFERED


valid_frames = st.builds(
    encode_frame,
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(TEMP_RAW_MIN, TEMP_RAW_MAX),  # a chip temperature the sensor can report
)
plain_byte = st.integers(0, 255).filter(lambda b: b not in HEADER_BYTES)
garbage = st.lists(plain_byte, min_size=1, max_size=20).map(bytes)


@st.composite
def corrupted_frames(draw: st.DrawFn) -> bytes:
    body = b"\x59\x59" + bytes(draw(st.lists(plain_byte, min_size=6, max_size=6)))
    good_cs = sum(body) & 0xFF
    bad = draw(plain_byte.filter(lambda b: b != good_cs))
    return body + bytes((bad,))


replies = st.sampled_from(
    [
        encode_reply(0x01, bytes((9, 0, 3))),
        encode_reply(0x03, (100).to_bytes(2, "little")),
        encode_reply(0x07, b"\x01"),
        encode_reply(0x11, b"\x00"),
    ]
)
piece = st.one_of(
    valid_frames.map(lambda b: ("frame", b)),
    garbage.map(lambda b: ("garbage", b)),
    corrupted_frames().map(lambda b: ("corrupt", b)),
    replies.map(lambda b: ("reply", b)),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(piece, max_size=40), st.lists(st.integers(0, 10_000), max_size=30))
def test_any_interleaving_yields_exactly_the_valid_frames(
    pieces: list[tuple[str, bytes]], cuts: list[int]
) -> None:
    """Garbage without header bytes: every frame and reply comes out, nothing else.
    The stream ends with a header, as the next frame would start, so that a last
    frame with a 0x59 checksum byte is decided rather than held for it."""
    data = b"".join(b for _, b in pieces) + b"\x59\x59"
    out, p = feed_chunks(data, cuts)
    expected = [b for kind, b in pieces if kind in ("frame", "reply")]
    got = [
        encode_frame(x.dist, x.amp, x.temp_raw)
        if isinstance(x, Frame)
        else encode_reply(x.cmd_id, x.payload)
        for x in out
    ]
    assert got == expected
    s = p.stats
    n_corrupt = sum(kind == "corrupt" for kind, _ in pieces)
    assert s.frames == sum(kind == "frame" for kind, _ in pieces)
    assert s.replies == sum(kind == "reply" for kind, _ in pieces)
    assert s.checksum_errors == n_corrupt
    assert s.bytes_discarded == sum(len(b) for kind, b in pieces if kind in ("garbage", "corrupt"))
    assert s.buffered == 2


@settings(max_examples=300, deadline=None)
@given(st.lists(piece, max_size=40))
def test_one_read_per_piece_equals_one_parse(pieces: list[tuple[str, bytes]]) -> None:
    """A read that holds exactly one frame (the usual case at 250 Hz) takes the parser's
    short cut; it must give what one parse of the whole stream gives, counters too."""
    p = FrameParser()
    out = [x for _, b in pieces for x in p.feed(b, 0)]
    whole = FrameParser()
    data = b"".join(b for _, b in pieces)
    assert [_key(x) for x in out] == [_key(x) for x in whole.feed(data, 0)]
    assert p.stats == whole.stats


def _with_checksum(body: bytes) -> bytes:
    return body + bytes((sum(body) & 0xFF,))


nine_bytes = st.one_of(
    valid_frames,
    corrupted_frames(),
    st.binary(min_size=7, max_size=7).map(lambda b: _with_checksum(b"\x59" + b)),  # one 59
    st.binary(min_size=9, max_size=9),
    st.binary(min_size=7, max_size=7).map(lambda b: b"\x59\x59" + b),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(nine_bytes, min_size=2, max_size=6), max_size=12))
def test_reads_of_whole_frames_equal_one_parse(batches: list[list[bytes]]) -> None:
    """A read of several whole frames (a batch at ``--publish-hz``) takes the parser's
    batch short cut; a slot in it that is no good frame (a bad checksum, garbage, a
    reply cut short) must leave the result to the scan: the same frames and counters
    as one parse of the whole stream."""
    p = FrameParser()
    out = [x for batch in batches for x in p.feed(b"".join(batch), 0)]
    whole = FrameParser()
    data = b"".join(b"".join(batch) for batch in batches)
    assert [_key(x) for x in out] == [_key(x) for x in whole.feed(data, 0)]
    assert p.stats == whole.stats


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600), st.lists(st.integers(0, 10_000), max_size=40))
def test_arbitrary_bytes_never_raise_and_counters_add_up(data: bytes, cuts: list[int]) -> None:
    out, p = feed_chunks(data, cuts)
    s = p.stats
    assert s.bytes_fed == len(data)
    assert s.bytes_fed == 9 * s.frames + s.reply_bytes + s.bytes_discarded + s.buffered
    assert s.frames == sum(isinstance(x, Frame) for x in out)
    assert s.buffered < MAX_BUFFERED
    whole = FrameParser().feed(data, 0)
    assert [_key(x) for x in out] == [_key(x) for x in whole]  # chunking changes nothing


def _key(x: Frame | CommandReply) -> tuple[object, ...]:
    if isinstance(x, Frame):
        return ("f", x.dist, x.amp, x.temp_raw)
    return ("r", x.cmd_id, x.payload)


def test_stray_reply_header_does_not_hold_a_frame_back() -> None:
    """Regression (found by `lunad soak`): garbage 5A 1E 14 looks like the header of a
    30-byte reply; a real frame right after it must come out at once, not wait for 30
    bytes that may never arrive (a pause, then an unplug that resets the parser)."""
    data = b"\x5a\x1e\x14\x00" + encode_frame(200, 1500, 2368)
    p = FrameParser()
    frames = [f for f in p.feed(data, 0) if isinstance(f, Frame)]
    assert [(f.dist, f.amp) for f in frames] == [(200, 1500)]
    assert p.stats.buffered == 0 and p.stats.bytes_discarded == 4
    for frames3 in three_ways(data):
        assert frames3 == [(200, 1500, 2368)]
