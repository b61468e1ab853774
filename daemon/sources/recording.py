"""Record raw source chunks to a file and replay them, as a writer/reader pair.

How this works: the ``Recorder`` appends each ``Chunk`` (the bytes of one source read
and its ``t_mono_ns``) as one length-prefixed, CRC-checked record; ``Replay`` iterates
them back; ``paced`` spaces them out in real time from their timestamp deltas (python-
can's ``Printer``/``LogReader``/``MessageSync`` split, ``can/io/generic.py``). Because
the raw bytes and their original read times are kept, replay runs the same parser and
filter on the same inputs and publishes the same readings as the live run did.

Power cuts are expected on a robot: a record is written with one ``write`` call, so a cut
leaves at most one torn record at the end. The reader stops quietly before it (counted in
``torn_records``); opening the file for append truncates it first. Bytes after the last
good record that cannot be one torn record (``_tail_damage``: good records after them,
more than ``MAX_TORN_BYTES`` of them, or a length no record has) are a damaged file: the
reader warns, and appending is refused rather than cutting the file there. The format
table is in ``Recorder``'s docstring.

One file takes one writer: a ``Recorder`` holds an exclusive ``flock`` on its file until it
is closed, and a second one (another ``lunad record``, or ``lunad serve --record`` on the
same file) is refused. Two writers appending at their own offsets would overwrite and cut
short each other's records while both reported success. Readers take no lock.
"""

from __future__ import annotations

import errno
import fcntl
import io
import logging
import math
import os
import struct
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from lunad.daemon.errors import LunadError
from lunad.daemon.sources.base import Chunk
from lunad.protocol.file_kind import file_kind
from lunad.protocol.messages import I64_MAX

log = logging.getLogger(__name__)

MAGIC = b"LUNAREC\n"  # '\n' catches a text-mode (CRLF) transfer, as PNG's signature does
FORMAT_VERSION = 2
READS_VERSIONS = (1, 2)
FILE_SUFFIX = ".lunarec"
_HEADER = struct.Struct("<8sHHqqH")  # magic, version, flags, unix ns, mono ns, desc length
_RATE = struct.Struct("<H")  # version 2: the sensor's frame rate, Hz (0: not known)
_CRC = struct.Struct("<I")
_RECORD = struct.Struct("<QII")  # t_mono_ns, length, crc32
_RECORD_HEAD = struct.Struct("<QI")  # the start of _RECORD the CRC covers: t_mono_ns, length
_RECORD_CRC_SPAN = _RECORD_HEAD.size
MAX_DESC_BYTES = 1024
MAX_RECORD_BYTES = 1 << 20
"""Longest chunk accepted (1 MiB); a larger length on read is taken as corruption, so a
garbage length field cannot make the reader swallow the rest of the file."""
FSYNC_INTERVAL_S = 1.0


class _ReadableFile(Protocol):
    """The file calls the readers make; both ``io.FileIO`` and ``io.BufferedReader`` fit."""

    def read(self, size: int = -1, /) -> bytes | None: ...
    def seek(self, offset: int, whence: int = os.SEEK_SET, /) -> int: ...
    def tell(self) -> int: ...


class RecordFormatError(LunadError, ValueError):
    """The file is not a lunad recording this version can read or append to; the message
    names it."""


class RecordingBusyError(RecordFormatError):
    """Another ``Recorder`` (usually in another process) is writing to the file.

    A ``RecordFormatError`` so that every caller which refuses a file it cannot record to
    refuses this one the same way (``lunad serve --record``: exit 78).
    """


class _TornHeaderError(RecordFormatError):
    """The file is empty or ends inside its header: a cut while it was being created."""


@dataclass(frozen=True, slots=True)
class RecordingHeader:
    """What the file header says about a recording.

    ``created_unix_ns`` and ``created_mono_ns`` were read together when the file was
    created, so ``created_unix_ns + (t_mono_ns - created_mono_ns)`` dates a record made
    in the same boot.
    """

    version: int
    created_unix_ns: int
    created_mono_ns: int
    source_desc: str
    frame_rate_hz: int = 0
    """The frame rate the recording run was configured for (``--rate``), Hz: the rate it
    set the sensor to, and timed frames by even with ``--no-configure``; 0 when not
    known (version 1, or a recording of something else). A replay spaces a read's
    frames by it, as the live run did."""


def _encode_header(header: RecordingHeader) -> bytes:
    desc = header.source_desc.encode()
    body = _HEADER.pack(
        MAGIC, header.version, 0, header.created_unix_ns, header.created_mono_ns, len(desc)
    )
    body += _RATE.pack(header.frame_rate_hz) + desc
    return body + _CRC.pack(zlib.crc32(body))


def _read_header(f: _ReadableFile, path: Path) -> RecordingHeader:
    """Parse and check the header at the start of ``f``; leaves ``f`` after it.

    Raises:
        RecordFormatError: wrong magic, other version, corrupt header; its subclass
            ``_TornHeaderError`` for an empty file or one that ends inside the header.
    """
    fixed = f.read(_HEADER.size) or b""
    if not fixed:
        raise _TornHeaderError(f"{path}: empty file, no recording header")
    if not MAGIC.startswith(fixed[: len(MAGIC)]):
        raise RecordFormatError(f"{path}: not a lunad recording (bad magic {fixed[:8]!r})")
    if len(fixed) < _HEADER.size:
        raise _TornHeaderError(f"{path}: header cut short ({len(fixed)} bytes), no records")
    _magic, version, _flags, unix_ns, mono_ns, desc_len = _HEADER.unpack(fixed)
    if version not in READS_VERSIONS:
        raise RecordFormatError(
            f"{path}: recording format version {version}; this lunad reads "
            + " and ".join(map(str, READS_VERSIONS))
        )
    extra = _RATE.size if version >= 2 else 0
    rest = f.read(extra + desc_len + _CRC.size) or b""
    if len(rest) < extra + desc_len + _CRC.size:
        raise _TornHeaderError(f"{path}: header cut short, no records")
    body = rest[: extra + desc_len]
    (crc,) = _CRC.unpack(rest[extra + desc_len :])
    if zlib.crc32(fixed + body) != crc:
        raise RecordFormatError(f"{path}: header checksum mismatch (corrupt file)")
    rate = _RATE.unpack(body[:extra])[0] if extra else 0
    desc = body[extra:].decode(errors="replace")
    return RecordingHeader(version, unix_ns, mono_ns, desc, rate)


def _check_regular(mode: int, path: Path) -> None:
    """Refuse anything but a regular file: a recording is one that ``Recorder`` wrote.

    A FIFO would block the reader (or the writer's header check) without a word, and a
    device would be read without end.

    Raises:
        RecordFormatError: naming what ``path`` is instead.
    """
    kind = file_kind(mode)
    if kind is not None:
        raise RecordFormatError(f"{path}: is {kind}, not a regular file")


def _open_regular(path: Path, flags: int) -> int:
    """A descriptor of ``path`` opened with ``flags``, only if it is a regular file.

    The type is checked before opening, so that no device is opened at all (a tty's open
    can toggle its modem lines), and again on the descriptor, opened non-blocking so that
    a FIFO put in the file's place in between cannot block the open; the descriptor is
    blocking again when returned.

    Raises:
        RecordFormatError: ``path`` is not a regular file.
        OSError: it cannot be opened.
    """
    _check_regular(os.stat(path).st_mode, path)
    fd = os.open(path, flags | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    try:
        _check_regular(os.fstat(fd).st_mode, path)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


@dataclass(slots=True)
class _ScanState:
    """Where the good records end, and what follows them (filled in by ``_records``)."""

    good_end: int
    torn_records: int = 0
    trailing_bytes: int = 0
    damage: str = ""
    """Why the bytes after the good records cannot be a last record cut short by a power
    cut (``_tail_damage``): the file is damaged there, and its rest is lost. Empty when
    they can be, or when there are none."""
    skipped_records: int = 0
    """Whole records (their CRC checks) stepped over for a ``t_mono_ns`` past
    ``I64_MAX``."""
    first_skipped_at: int = 0
    """Byte offset of the first of those records."""


def _records(f: _ReadableFile, state: _ScanState) -> Iterator[Chunk]:
    """Yield the records of ``f`` from its position; stop at EOF or before a bad record.

    A bad record (short, oversized length, wrong CRC) ends the scan: its length can no
    longer be trusted, so nothing after it can be found. ``state`` records how far the
    good part goes, how many bytes were left unread, and whether they can be a torn last
    record (``_tail_damage``).

    A record whose CRC checks but whose ``t_mono_ns`` is past ``I64_MAX`` (2**63 - 1 ns)
    is not yielded: the message contract carries the time as an i64, and no monotonic
    clock lunad reads gets there (292 years of uptime), so it is damage that happened to
    keep its CRC, or a file lunad did not write. It is counted in
    ``state.skipped_records`` and the scan goes on after it, since its CRC vouches for
    its length: the rest of the file is kept, as a header whose frame rate the sensor
    cannot run at has that field left out and the rest read (``ReplaySource``).
    """
    pos = state.good_end
    while True:
        head = f.read(_RECORD.size) or b""
        if not head:
            return
        if len(head) == _RECORD.size:
            t_mono_ns, length, crc = _RECORD.unpack(head)
            if length <= MAX_RECORD_BYTES:
                data = f.read(length) or b""
                if (
                    len(data) == length
                    and zlib.crc32(data, zlib.crc32(head[:_RECORD_CRC_SPAN])) == crc
                ):
                    start, pos = pos, pos + _RECORD.size + length
                    state.good_end = pos
                    if t_mono_ns <= I64_MAX:
                        yield Chunk(data, t_mono_ns)
                    else:
                        if not state.skipped_records:
                            state.first_skipped_at = start
                        state.skipped_records += 1
                    continue
        f.seek(pos)
        tail = f.read(1 + RESYNC_WINDOW_BYTES + _RECORD.size + MAX_RESYNC_RECORD_BYTES) or b""
        f.seek(0, os.SEEK_END)
        state.torn_records = 1
        state.trailing_bytes = f.tell() - pos
        state.damage = _tail_damage(tail, state.trailing_bytes)
        return


RESYNC_WINDOW_BYTES = 16 * 1024
"""How far past a bad record ``_records`` looks for a good one, to tell a file damaged
in the middle from one cut short: a record holds one read of the port (at most
``READ_MAX_BYTES``, 4096 bytes, daemon/sources/serial.py), so the next one starts
within this. Bounded, with
``MAX_RESYNC_RECORD_BYTES``, so that a hostile file costs at most this many offsets,
once, at the end of its good records: 5 ms here on random bytes, 11 ms on zeros
(every offset a record of length 0, its CRC worked out)."""
MAX_RESYNC_RECORD_BYTES = 8 * 1024
"""The longest record the look-ahead takes as found: twice the longest read of a port."""
MAX_TORN_BYTES = _RECORD.size + MAX_RESYNC_RECORD_BYTES
"""The most bytes a power cut leaves after the last good record (8208): it tears one
record, and a record holds one read of a port, at most half of
``MAX_RESYNC_RECORD_BYTES``. A longer tail is damage however quiet it looks (zeros or
noise past the look-ahead may hide good records), so appending refuses it rather than
delete it; and every offset of a tail this short has been searched for a good record
(``RESYNC_WINDOW_BYTES`` is longer). ``Recorder`` takes chunks of up to
``MAX_RECORD_BYTES``, which lunad's sources never make: a cut through one longer than
this reads as damage, and the file is refused for appending, not cut."""


def _holds_a_record(tail: bytes) -> bool:
    """Whether a whole record whose CRC checks starts at one of the first
    ``RESYNC_WINDOW_BYTES`` offsets of ``tail`` (the bytes after a bad record's first).
    A power cut leaves nothing readable after the record it cut (a tail of zeros or
    of the cut record's own bytes); a damaged file goes on with good records."""
    size = _RECORD.size
    for at in range(min(len(tail) - size + 1, RESYNC_WINDOW_BYTES)):
        _t, length, crc = _RECORD.unpack_from(tail, at)
        end = at + size + length
        if length > MAX_RESYNC_RECORD_BYTES or end > len(tail):
            continue
        head = tail[at : at + _RECORD_CRC_SPAN]
        if zlib.crc32(tail[at + size : end], zlib.crc32(head)) == crc:
            return True
    return False


def _tail_damage(tail: bytes, trailing_bytes: int) -> str:
    """Why the ``trailing_bytes`` after the last good record, of which ``tail`` holds the
    first (from the bad record's first byte), cannot be a torn last record; "" when they
    can be.

    A power cut tears one record, the last: it leaves at most ``MAX_TORN_BYTES`` (a start
    of that record, or zeros the filesystem had not yet written over), no good record
    after them, and a length, if the bytes get that far, that ``Recorder`` could have
    written. Anything else is a file damaged there. The reader (INFO for a tear, WARNING
    for damage) and the appender (which cuts off a tear and refuses damage, so as not to
    delete good records it cannot see) both decide by this.
    """
    if _holds_a_record(tail[1:]):
        return "good records follow a corrupt one"
    if trailing_bytes > MAX_TORN_BYTES:
        return f"more than the {MAX_TORN_BYTES} bytes one torn record leaves"
    if len(tail) >= _RECORD_HEAD.size:
        _t_mono_ns, length = _RECORD_HEAD.unpack_from(tail)
        if length > MAX_RECORD_BYTES:
            return f"a record there claims {length} bytes; none holds more than {MAX_RECORD_BYTES}"
    return ""


_NO_LOCKS = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS)
"""``flock`` errors of a filesystem without locks (some FUSE and network ones)."""


def _lock(f: io.FileIO, path: Path) -> None:
    """Take the writer's lock on ``f``; it holds until ``f`` is closed.

    A filesystem without locks gets a warning and no lock: recording there is what lunad
    did before it locked, and refusing it would lose the recording.

    Raises:
        RecordingBusyError: another open file holds the lock.
    """
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise RecordingBusyError(
            f"{path}: is being recorded by another process (or already by this one)"
        ) from None
    except OSError as exc:
        if exc.errno not in _NO_LOCKS:
            raise
        log.warning("%s: cannot lock it (%s); recording without the lock", path, exc.strerror)


def _fsync_dir(path: Path) -> None:
    """Make a new file's directory entry durable (its data fsync does not cover it)."""
    try:
        fd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:  # some filesystems (FUSE, network) refuse it; data is still written
        log.debug("%s: cannot fsync its directory: %s", path, exc)


class Recorder:
    """Appends chunks to a recording: ``with Recorder(path) as rec: rec(chunk)``.

    File format, version 2 (all integers little-endian; CRC-32 as ``zlib.crc32``).
    Version 1, which ``Replay`` still reads, has no frame rate: its description starts
    at offset 30.

    ======  =============  ===============================================================
    offset  type           field
    ======  =============  ===============================================================
    **file header**, once
    0       8 bytes        magic ``b"LUNAREC\\n"``
    8       u16            format version, 2
    10      u16            flags, 0 (reserved)
    12      i64            ``created_unix_ns``: wall clock when the file was created
    20      i64            ``created_mono_ns``: ``time.monotonic_ns()`` at the same moment
    28      u16            ``n``: length of the source description
    30      u16            ``frame_rate_hz``: the rate the sensor was set to, 0 if unknown
    32      n bytes        source description, UTF-8 (e.g. ``serial /dev/ttyAMA0 115200 Bd``)
    32+n    u32            CRC-32 of the 32+n bytes before it
    **record**, repeated to the end of the file
    +0      u64            ``t_mono_ns``: ``time.monotonic_ns()`` when the bytes were read,
                           at most 2**63 - 1 (the messages' i64; a larger one is skipped)
    +8      u32            ``length``: number of data bytes, at most 1 MiB
    +12     u32            CRC-32 of the 12 bytes at +0, then of the data
    +16     length bytes   data: raw bytes exactly as the source returned them
    ======  =============  ===============================================================

    The file is append-only. Opening an existing recording checks its header, truncates
    a torn last record (left by a power cut, at most ``MAX_TORN_BYTES``; logged) and
    appends after the last good one. A file damaged after its last good record (good
    records after a corrupt one, more bytes than one torn record leaves, or a length no
    record has: ``_tail_damage``) is refused (``RecordFormatError``) and left as it is,
    since cutting it there could delete good records. The header keeps
    the first recorder's version, description, creation time and frame rate. Records
    appended after a reboot restart the monotonic clock, so ``t_mono_ns`` may step
    back; ``paced`` treats that as no gap. The recorder holds an exclusive ``flock`` on
    the file until ``close``: a second writer is refused before it reads or changes
    anything.

    Durability: each record is one unbuffered ``write``, so a crash of the process loses
    nothing already passed to the recorder. ``fsync`` runs at most once per
    ``fsync_interval_s`` (checked when a record is written) and on close, so a power cut
    loses about a second of data at most, plus whatever arrived before an idle spell
    that the kernel had not yet written back (about 30 s by default). Syncing every
    record instead would issue 100+ flushes a second to an SD card, wearing it and
    stalling the caller for tens of milliseconds each time.

    Args:
        path: the recording; created if missing, appended to if it exists.
        source_desc: one line naming the source, stored in a new file's header.
        frame_rate_hz: the rate the sensor was set to send at, Hz (0: unknown), stored
            in a new file's header: a read of several frames replays with them that
            far apart (``Daemon._read_each``), whatever ``--rate`` the replay is given.
        fsync_interval_s: seconds between fsyncs; 0 syncs every record.

    Raises:
        RecordFormatError: ``path`` exists and is not a regular file holding a recording
            this version writes; its subclass ``RecordingBusyError`` when another
            recorder holds the file.
        ValueError: ``source_desc`` is longer than 1024 bytes in UTF-8.
        OSError: the file cannot be opened or written.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        source_desc: str = "",
        *,
        frame_rate_hz: int = 0,
        fsync_interval_s: float = FSYNC_INTERVAL_S,
    ) -> None:
        self.path = Path(path)
        if len(source_desc.encode()) > MAX_DESC_BYTES:
            raise ValueError(f"source_desc longer than {MAX_DESC_BYTES} bytes in UTF-8")
        if not 0 <= frame_rate_hz <= 0xFFFF:
            raise ValueError(f"frame_rate_hz must fit a u16, got {frame_rate_hz}")
        self._frame_rate_hz = frame_rate_hz
        self.fsync_interval_s = fsync_interval_s
        self.records = 0
        """Records written by this Recorder (not counting what earlier recorders appended)."""
        self.bytes = 0
        """Data bytes written by this Recorder (record headers not counted)."""
        self.truncated_bytes = 0
        """Bytes of a torn tail removed when appending to an existing file."""
        self._file: io.FileIO | None = None
        try:
            f = open(self.path, "xb", buffering=0)
        except FileExistsError:
            self._file = self._open_existing(source_desc)
        else:
            try:
                _lock(f, self.path)
                self._write_header(f, source_desc)
            except BaseException:
                f.close()
                raise
            self._file = f
        self._last_sync = time.monotonic()

    def _write_header(self, f: io.FileIO, source_desc: str) -> None:
        header = RecordingHeader(
            FORMAT_VERSION, time.time_ns(), time.monotonic_ns(), source_desc, self._frame_rate_hz
        )
        f.write(_encode_header(header))
        os.fsync(f.fileno())
        _fsync_dir(self.path)

    def _open_existing(self, source_desc: str) -> io.FileIO:
        f = open(_open_regular(self.path, os.O_RDWR), "r+b", buffering=0)
        try:
            _lock(f, self.path)
            try:
                _read_header(f, self.path)
            except _TornHeaderError:
                # A cut while the header was being written: there are no records to keep.
                if os.fstat(f.fileno()).st_size:
                    log.warning("%s: header incomplete, starting it afresh", self.path)
                f.seek(0)
                f.truncate()
                self._write_header(f, source_desc)
                return f
            state = _ScanState(good_end=f.tell())
            for _ in _records(f, state):
                pass
            if state.damage:  # cutting it here could delete good records after it
                raise RecordFormatError(
                    f"{self.path}: damaged at byte {state.good_end} ({state.damage}); "
                    f"appending would drop the {state.trailing_bytes} bytes from there on: "
                    "record to a new file"
                )
            if state.trailing_bytes:
                log.warning(
                    "%s: dropping a torn last record (%d bytes) before appending",
                    self.path,
                    state.trailing_bytes,
                )
                f.truncate(state.good_end)
                self.truncated_bytes = state.trailing_bytes
            f.seek(state.good_end)
            return f
        except BaseException:
            f.close()
            raise

    def __call__(self, chunk: Chunk) -> None:
        """Append ``chunk`` as one record.

        Raises:
            ValueError: the chunk is longer than 1 MiB, or its time is negative or past
                2**63 - 1 ns (the messages' i64, which ``Replay`` skips past).
            OSError: the write failed (disk full, card removed); the file keeps every
                earlier record and at most one torn one.
        """
        f = self._file
        if f is None:
            raise ValueError(f"{self.path}: recorder is closed")
        data = chunk.data
        if len(data) > MAX_RECORD_BYTES:
            raise ValueError(f"chunk of {len(data)} bytes; at most {MAX_RECORD_BYTES}")
        if not 0 <= chunk.t_mono_ns <= I64_MAX:
            raise ValueError(f"t_mono_ns {chunk.t_mono_ns} is not in 0..2**63 - 1 (an i64)")
        head = _RECORD_HEAD.pack(chunk.t_mono_ns, len(data))
        record = head + _CRC.pack(zlib.crc32(data, zlib.crc32(head))) + data
        view = memoryview(record)
        while view:  # a regular file takes it all at once unless the disk fills up
            written = f.write(view)
            if not written:
                raise OSError(f"{self.path}: write accepted no bytes")
            view = view[written:]
        self.records += 1
        self.bytes += len(data)
        now = time.monotonic()
        if now - self._last_sync >= self.fsync_interval_s:
            os.fsync(f.fileno())
            self._last_sync = now

    def close(self) -> None:
        """fsync and close; safe to call twice."""
        f, self._file = self._file, None
        if f is not None:
            try:
                os.fsync(f.fileno())
            finally:
                f.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class Replay:
    """Reads a recording back as ``Chunk``s with their recorded ``t_mono_ns``.

    ``for chunk in Replay(path)`` yields every good record once, in file order, and
    stops before a torn or corrupt record (``torn_records`` becomes 1 and
    ``trailing_bytes`` says how much was skipped). A power cut can only tear the last
    record, and that is logged at INFO; what cannot be one torn record (``damaged``:
    see ``_tail_damage``) means the file was damaged, logged as a WARNING, and the rest
    of it is lost because the lengths after it cannot be trusted. A record whose CRC
    checks but whose ``t_mono_ns`` is past 2**63 - 1 ns is skipped and reading goes on
    after it (``skipped_records``; one WARNING at the end).

    Raises:
        RecordFormatError: (from the constructor) the file is not a regular file, or
            its header is missing, corrupt, or of another format version.
        OSError: the file cannot be opened.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.records = 0
        self.bytes = 0
        self._file: io.BufferedReader | None = open(_open_regular(self.path, os.O_RDONLY), "rb")
        try:
            self.header = _read_header(self._file, self.path)
        except BaseException:
            self.close()
            raise
        self._state = _ScanState(good_end=self._file.tell())

    @property
    def torn_records(self) -> int:
        """1 when reading stopped before a torn or corrupt record, else 0."""
        return self._state.torn_records

    @property
    def damaged(self) -> bool:
        """The bad record was not a last one cut short: the file was damaged."""
        return bool(self._state.damage)

    @property
    def skipped_records(self) -> int:
        """Whole records not yielded for a ``t_mono_ns`` past 2**63 - 1 ns."""
        return self._state.skipped_records

    @property
    def trailing_bytes(self) -> int:
        """Bytes after the last good record that could not be read."""
        return self._state.trailing_bytes

    def __iter__(self) -> Iterator[Chunk]:
        f = self._file
        if f is None:
            return
        for chunk in _records(f, self._state):
            self.records += 1
            self.bytes += len(chunk.data)
            yield chunk
        state = self._state
        if state.skipped_records:
            log.warning(
                "%s: skipped %d records (the first at byte %d) whose t_mono_ns is past "
                "2**63 - 1 ns, the messages' i64: not a time lunad records",
                self.path,
                state.skipped_records,
                state.first_skipped_at,
            )
        if state.damage:
            log.warning(
                "%s: damaged: a corrupt record at byte %d (%s); the %d bytes from there on "
                "(%.0f %% of the file) cannot be read and were skipped",
                self.path,
                state.good_end,
                state.damage,
                state.trailing_bytes,
                100.0 * state.trailing_bytes / max(1, state.good_end + state.trailing_bytes),
            )
        elif state.torn_records:
            log.info(
                "%s: stopped before a torn last record at byte %d (%d bytes skipped: a "
                "recording cut short, as by a power cut)",
                self.path,
                state.good_end,
                state.trailing_bytes,
            )

    def close(self) -> None:
        """Close the file; safe to call twice."""
        f, self._file = self._file, None
        if f is not None:
            f.close()

    def __enter__(self) -> Replay:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def check_speed(speed: float | None) -> float | None:
    """``speed`` if it is a usable replay speed (finite, > 0) or None (as fast as possible).

    Raises:
        ValueError: zero, negative, infinite or NaN.
    """
    if speed is not None and not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"replay speed must be a positive number or None (max), got {speed}")
    return speed


def _paced(speed: float | None) -> float:
    """``speed`` for a ``Pacer``: a usable factor, not None (as fast as possible).

    Raises:
        ValueError: None, zero, negative, infinite or NaN.
    """
    checked = check_speed(speed)
    if checked is None:
        raise ValueError("Pacer needs a speed; use no pacing for as-fast-as-possible")
    return checked


class Pacer:
    """Turns recorded times into the monotonic clock times at which to release them.

    The first chunk is due at the first ``due`` call; each later one is due after the
    recorded gap since the previous chunk, divided by ``speed``. Gaps longer than
    ``max_gap_s`` (recording time) are shortened to it, and a backward step (a recording
    appended after a reboot) counts as no gap. Due times are absolute, so time the
    consumer spends on a chunk does not add up into drift.

    Args:
        speed: replay rate relative to real time (2.0 = twice as fast); must be > 0.
        max_gap_s: longest recorded gap kept, in seconds; None keeps every gap.
        clock: seconds on a monotonic clock (injectable for tests).
    """

    def __init__(
        self,
        speed: float,
        max_gap_s: float | None = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        speed = _paced(speed)
        if max_gap_s is not None and max_gap_s < 0:
            raise ValueError(f"max_gap_s must be >= 0, got {max_gap_s}")
        self.speed = speed
        self._max_gap_ns = None if max_gap_s is None else round(max_gap_s * 1e9)
        self._clock = clock
        self._start_s: float | None = None
        self._prev_ns = 0
        self._offset_ns = 0

    def due(self, t_mono_ns: int) -> float:
        """Clock time (seconds) when the chunk recorded at ``t_mono_ns`` should go out.

        Call once per chunk, in recording order.
        """
        if self._start_s is None:
            self._start_s = self._clock()
        else:
            gap_ns = max(0, t_mono_ns - self._prev_ns)
            if self._max_gap_ns is not None:
                gap_ns = min(gap_ns, self._max_gap_ns)
            self._offset_ns += gap_ns
        self._prev_ns = t_mono_ns
        return self.last_due_s

    @property
    def last_due_s(self) -> float:
        """Clock time (seconds) the last ``due`` call gave, at the speed now in force."""
        assert self._start_s is not None, "due() not called yet"
        return self._start_s + self._offset_ns / 1e9 / self.speed

    def set_speed(self, speed: float) -> None:
        """Pace the chunks after now at ``speed``, from where the replay is.

        The recording time already played at the old speed stays played: the clock's
        start moves so that the rest of the recording, from the point reached now (at
        most the last chunk given a due time), takes ``1 / speed`` of its recorded time.

        Raises:
            ValueError: ``speed`` is zero, negative or not finite.
        """
        speed = _paced(speed)
        if self._start_s is not None:
            now = self._clock()
            played_ns = min(self._offset_ns, max(0.0, (now - self._start_s) * 1e9 * self.speed))
            self._start_s = now - played_ns / 1e9 / speed
        self.speed = speed


def paced(
    chunks: Iterable[Chunk],
    speed: float | None = 1.0,
    max_gap_s: float | None = 1.0,
    *,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], object] | None = None,
) -> Iterator[Chunk]:
    """Yield ``chunks`` at ``speed`` times the pace they were recorded at.

    Chunks keep their recorded ``t_mono_ns``; only when they are released changes.

    Args:
        chunks: usually a ``Replay``.
        speed: 1.0 real time, 2.0 twice as fast; None as fast as possible.
        max_gap_s: recorded gaps longer than this many seconds are shortened to it, so
            a pause in the recording does not stall the replay; None keeps them.
        stop: when set, the generator ends at once, even in the middle of a wait.
        clock: monotonic seconds; tests inject a fake one together with ``sleep``.
        sleep: waits the given seconds; defaults to ``stop.wait`` (so ``stop`` cuts it
            short) or ``time.sleep`` without ``stop``.

    Raises:
        ValueError: ``speed`` is zero, negative or not finite, or ``max_gap_s`` < 0.
    """
    check_speed(speed)
    pacer = None if speed is None else Pacer(speed, max_gap_s, clock)
    if sleep is None:
        sleep = stop.wait if stop is not None else time.sleep
    for chunk in chunks:
        if stop is not None and stop.is_set():
            return
        if pacer is not None:
            delay_s = pacer.due(chunk.t_mono_ns) - clock()
            if delay_s > 0:
                sleep(delay_s)
                if stop is not None and stop.is_set():
                    return
        yield chunk
