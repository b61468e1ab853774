"""The parser on garbage of every byte value: runs of 0x59 and 0x5A, reply look-alikes,
cut and corrupted frames. No real frame is lost where the stream tells it from the
garbage, and the byte count adds up whatever the bytes."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from lunad.protocol import CommandReply, Frame, FrameParser, encode_frame
from lunad.protocol.commands import REPLY_LENGTHS
from lunad.protocol.frame import TEMP_RAW_MAX, TEMP_RAW_MIN
from lunad.protocol.parser import MAX_BUFFERED

HEADER = b"\x59\x59"

field = st.one_of(st.integers(0, 0xFFFF), st.sampled_from([0x5959, 0x5900, 0x0059, 0x5A59]))
real_frames = st.builds(
    encode_frame,
    field,
    field,
    st.integers(TEMP_RAW_MIN, TEMP_RAW_MAX),  # a chip temperature the sensor can report
)


@st.composite
def reply_like(draw: st.DrawFn) -> bytes:
    """``5A Len ID payload CS``: a known (ID, Len) pair or any, the checksum right or
    not, whole or cut short."""
    if draw(st.booleans()):
        cid, length = draw(st.sampled_from(sorted(REPLY_LENGTHS.items())))
    else:
        cid, length = draw(st.integers(0, 255)), draw(st.integers(0, 40))
    body = bytes((0x5A, length, cid)) + draw(st.binary(max_size=max(0, length - 4)))
    cs = sum(body) & 0xFF if draw(st.booleans()) else draw(st.integers(0, 255))
    return (body + bytes((cs,)))[: draw(st.integers(1, len(body) + 1))]


@st.composite
def damaged_frames(draw: st.DrawFn) -> bytes:
    """A real frame cut short, or with one byte changed."""
    f = bytearray(draw(real_frames))
    if draw(st.booleans()):
        return bytes(f[: draw(st.integers(1, 8))])
    f[draw(st.integers(0, 8))] ^= draw(st.integers(1, 255))
    return bytes(f)


garbage = st.one_of(
    st.binary(min_size=1, max_size=16),
    st.integers(1, 40).map(lambda k: b"\x59" * k),
    st.integers(1, 40).map(lambda k: b"\x5a" * k),
    st.lists(st.sampled_from([0x59, 0x5A]), min_size=1, max_size=16).map(bytes),
    reply_like(),
    damaged_frames(),
    st.lists(st.one_of(reply_like(), damaged_frames()), min_size=2, max_size=4).map(b"".join),
)
cuts = st.lists(st.integers(0, 10_000), max_size=30)


@st.composite
def junk_and_frame(draw: st.DrawFn) -> tuple[bytes, bytes]:
    """A real frame and the garbage before it: none, any, or garbage whose last
    ``s`` bytes and the frame's first ``9 - s`` form a window with a right checksum
    (one free byte set to make it so) and, where its bytes are free, a plausible
    temperature: the false frame that swallowed real ones."""
    frame = draw(real_frames)
    kind = draw(st.sampled_from(["none", "garbage", "collision"]))
    if kind == "none":
        return b"", frame
    if kind == "garbage":
        return draw(garbage), frame
    s = draw(st.integers(3, 8))
    w = bytearray(HEADER + draw(st.binary(min_size=s - 2, max_size=s - 2)) + frame[: 9 - s])
    if s == 8:
        w[6:8] = draw(st.integers(TEMP_RAW_MIN, TEMP_RAW_MAX)).to_bytes(2, "little")
    k = draw(st.integers(2, min(s, 6) - 1))  # a free byte, not a temperature byte
    w[k] = (w[8] - sum(w[:8]) + w[k]) & 0xFF
    return draw(st.one_of(st.just(b""), garbage)) + bytes(w[:s]), frame


def feed_in_chunks(
    data: bytes, cut_at: list[int]
) -> tuple[list[Frame | CommandReply], FrameParser]:
    p = FrameParser()
    out: list[Frame | CommandReply] = []
    pos = 0
    for cut in sorted({c % (len(data) + 1) for c in cut_at}):
        out += p.feed(data[pos:cut], cut)
        pos = cut
    out += p.feed(data[pos:], len(data))
    return out, p


def feed_bytewise(data: bytes) -> tuple[list[Frame | CommandReply], FrameParser]:
    """One byte a read, stamped with its offset: a frame's ``t_mono_ns`` is the offset
    of its last byte, also for a frame held back for the bytes after it."""
    p = FrameParser()
    return [x for k in range(len(data)) for x in p.feed(data[k : k + 1], k)], p


def data_frames(items: list[Frame | CommandReply]) -> list[Frame]:
    """``items``, which must all be data frames (no command reply among them)."""
    assert all(isinstance(x, Frame) for x in items), items
    return [x for x in items if isinstance(x, Frame)]


def _key(x: Frame | CommandReply) -> tuple[object, ...]:
    if isinstance(x, Frame):
        return ("f", x.dist, x.amp, x.temp_raw, x.t_mono_ns)
    return ("r", x.cmd_id, x.payload, x.t_mono_ns)


def _good_data(data: bytes, q: int) -> bool:
    w = data[q : q + 9]
    return (
        len(w) == 9
        and w[:2] == HEADER
        and sum(w[:8]) & 0xFF == w[8]
        and TEMP_RAW_MIN <= int.from_bytes(w[6:8], "little") <= TEMP_RAW_MAX
    )


def _good_reply_len(data: bytes, q: int) -> int:
    """Length of a good reply at ``q`` (one the parser would consider), else 0."""
    if data[q] != 0x5A or q + 3 > len(data):
        return 0
    length = REPLY_LENGTHS.get(data[q + 2], 0)
    if data[q + 1] != length or q + length > len(data):
        return 0
    if sum(data[q : q + length - 1]) & 0xFF != data[q + length - 1]:
        return 0
    if any(_good_data(data, j) for j in range(q + 1, q + length - 8)):
        return 0  # a whole good frame inside: no reply
    return length


def shadowed(data: bytes, p: int) -> bool:
    """A good candidate other than the frame at ``p`` overlaps its start and is itself
    followed by a header: the bytes do not say which is real (the parser takes the
    earlier)."""
    for q in range(max(0, p - 29), p):
        length = 9 if _good_data(data, q) else _good_reply_len(data, q)
        if q + length > p and data[q + length : q + length + 2] == HEADER:
            return True
    return False


def overlapped(data: bytes, p: int) -> bool:
    """Another good candidate overlaps the frame at ``p``: one starting before it runs
    into it, or one starts inside it."""
    for q in range(max(0, p - 29), p + 9):
        if q != p and q < len(data):
            length = 9 if _good_data(data, q) else _good_reply_len(data, q)
            if length and (q > p or q + length > p):
                return True
    return False


@settings(max_examples=400, deadline=None)
@given(st.lists(st.one_of(real_frames, garbage), max_size=40), cuts)
def test_counters_add_up_on_any_garbage_in_any_chunking(pieces: list[bytes], cut_at: list[int]):
    data = b"".join(pieces)
    out, p = feed_in_chunks(data, cut_at)
    s = p.stats
    assert s.bytes_fed == len(data)
    assert s.bytes_fed == 9 * s.frames + s.reply_bytes + s.bytes_discarded + s.buffered
    assert s.frames == sum(isinstance(x, Frame) for x in out)
    assert s.replies == sum(isinstance(x, CommandReply) for x in out)
    assert s.buffered < MAX_BUFFERED
    whole = FrameParser()
    want = whole.feed(data, 0)
    assert [_key(x)[:-1] for x in out] == [_key(x)[:-1] for x in want]
    assert s == whole.stats


@settings(max_examples=400, deadline=None)
@given(st.lists(junk_and_frame(), min_size=1, max_size=30), cuts)
def test_no_real_frame_is_lost_where_the_stream_disambiguates(
    pieces: list[tuple[bytes, bytes]], cut_at: list[int]
) -> None:
    """Garbage between whole frames; the stream ends with the header of the frame that
    would come next. Every real frame followed by a header (the next frame's, or
    garbage's) comes out, unless a good candidate overlapping its start is followed by
    a header too: then the bytes alone cannot tell which is real. A real frame that no
    other good candidate overlaps comes out whatever follows it."""
    data = b""
    starts = []
    for junk, frame in pieces:
        data += junk
        starts.append(len(data))
        data += frame
    data += HEADER
    out, _ = feed_bytewise(data)
    got = {x.t_mono_ns - 8 for x in out if isinstance(x, Frame)}  # start offsets
    protected = [
        p
        for p in starts
        if not overlapped(data, p) or (data[p + 9 : p + 11] == HEADER and not shadowed(data, p))
    ]
    assert [p for p in protected if p not in got] == []
    if all(not junk for junk, _ in pieces):
        assert sorted(got) == starts  # a clean stream: every frame, nothing else
    chunked, _ = feed_in_chunks(data, cut_at)
    assert [_key(x)[:-1] for x in chunked] == [_key(x)[:-1] for x in out]


def test_runs_of_0x59_before_each_frame() -> None:
    """1 to 40 bytes of 0x59 before each frame: a run and the real frame's first bytes
    form a window with a right checksum before about 2 % of the frames."""
    rng = random.Random(1)
    frames = [
        encode_frame(rng.randint(20, 800), rng.randint(100, 30000), rng.randint(2100, 2600))
        for _ in range(5000)
    ]
    data = b"".join(b"\x59" * rng.randint(1, 40) + f for f in frames) + HEADER
    out, p = feed_in_chunks(data, [rng.randint(0, len(data)) for _ in range(3000)])
    assert [encode_frame(f.dist, f.amp, f.temp_raw) for f in out if isinstance(f, Frame)] == frames
    assert p.stats.implausible_frames > 0 and p.stats.displaced_frames > 0


def _collision(temp_raw: int) -> bytes:
    """A real frame whose stray-0x59-shifted window ``59 + frame[:8]`` has a right
    checksum, and a temperature (``frame[5:7]``) in range when ``temp_raw``'s low byte
    is 6..11."""
    for dist in range(150, 10_000):
        real = encode_frame(dist, 0x0800, temp_raw)
        if sum(b"\x59" + real[:7]) & 0xFF == real[7]:
            return real
    raise AssertionError("no colliding frame")


def test_a_stray_0x59_does_not_swallow_the_frame_after_it() -> None:
    """The false window is a good frame in every respect but one: it is not followed by
    a header, and the real frame it overlaps is."""
    real = _collision(0x0907)  # low byte 07: the false window reads -31 degC
    nxt = encode_frame(200, 1500, 2368)
    data = b"\x59" + real + nxt
    for chunks in ([data], [data[k : k + 1] for k in range(len(data))], [data[:10], data[10:]]):
        p = FrameParser()
        out = [x for c in chunks for x in p.feed(c, 0)]
        assert [encode_frame(f.dist, f.amp, f.temp_raw) for f in data_frames(out)] == [real, nxt]
        assert (p.stats.displaced_frames, p.stats.bytes_discarded) == (1, 1)


def test_a_false_frame_with_an_impossible_temperature_is_garbage() -> None:
    real = _collision(0x0940)  # low byte 0x40: the false window reads 1793 degC
    p = FrameParser()
    out = p.feed(b"\x59" + real, 0)
    assert [encode_frame(f.dist, f.amp, f.temp_raw) for f in data_frames(out)] == [real]
    assert p.stats.implausible_frames == 1 and p.stats.displaced_frames == 0
    p = FrameParser()
    assert p.feed(encode_frame(200, 1500, 0), 0) == []  # -256 degC
    assert (p.stats.implausible_frames, p.stats.bytes_discarded, p.stats.buffered) == (1, 9, 0)


def test_an_unambiguous_frame_comes_out_at_once_an_ambiguous_one_at_the_next_header() -> None:
    """A frame with a 0x59 checksum byte could be overlapped by one starting at that
    byte: it waits for two more bytes, and keeps the time of the read that brought it."""
    plain = encode_frame(200, 1500, 2368)
    assert plain[8] != 0x59
    p = FrameParser()
    assert [f.t_mono_ns for f in p.feed(plain, 1)] == [1]
    held = next(f for d in range(2000) if (f := encode_frame(d, 1500, 2368))[8] == 0x59)
    assert p.feed(held, 2) == [] and p.stats.buffered == 9
    assert p.feed(plain[:1], 3) == []
    out = p.feed(plain[1:], 4)
    want = [(int.from_bytes(held[2:4], "little"), 2), (200, 4)]
    assert [(f.dist, f.t_mono_ns) for f in data_frames(out)] == want
    assert p.stats.buffered == 0
    p = FrameParser()
    assert len(p.feed(held + plain, 5)) == 2  # linked within the read: no wait
    # dist 345 = 0x0159: 59 59 59 01 ... a pair at offset 1, but a frame there would
    # read its temperature from this one's last two bytes, out of range: no wait
    dl59 = encode_frame(345, 1500, 2368)
    assert dl59[1:3] == HEADER and not 1728 <= dl59[7] | dl59[8] << 8 <= 2848
    assert len(FrameParser().feed(dl59, 6)) == 1
