"""The ZeroMQ socket robot code subscribes to, with a last-value cache, safe to expose
to peers that are not honest subscribers.

How this works: the socket is an XPUB (a PUB that also hears subscriptions) with
``XPUB_VERBOSE``, so every new subscription reaches us, even for a topic someone
already has. libzmq adds each subscription to its own trie as it reads it from the
peer, so a subscriber gets live messages whether or not ``pump`` has run; what ``pump``
adds is the last-value cache: for a new subscription it re-sends the last message of
every cached topic the subscription matches, so a late subscriber gets the latest
``range`` and ``health`` at once instead of waiting (the zguide's "last value cache"
pattern, without its extra proxy hop on the hot path). So that the loop hears a
subscription even while it blocks in a read, a waker thread sleeps in ``select`` on the
``ZMQ_FD`` of the XPUB, of its connection monitor and of its ZAP handler (it makes no
ZeroMQ call, so the sockets stay single-threaded) and calls the loop's wake-up; ``pump``
receives until each socket is empty (a receive that finds nothing processes the
socket's commands, which re-arms its edge-triggered descriptor) or until its bound,
then lets the waker wait again. A ``send`` processes commands too, so it reads
``ZMQ_EVENTS`` and sets ``pending`` itself when it took in frames.

The cache. An XPUB cannot address one subscriber, so a replay goes to every subscriber
of the topic, and those already connected receive a duplicate with the same ``seq``
(``lunad.protocol.client.Subscriber`` drops it). Each topic is therefore replayed at
most once per ``REPLAY_INTERVAL_S``: a subscription inside the interval defers the
replay to its end (the waker wakes the loop then), and a live message of the topic
sent meanwhile cancels it (the newcomer got a fresher value). However fast a peer
repeats subscriptions, an honest subscriber gets at most one duplicate per topic per
interval. Not chosen:
``XPUB_MANUAL`` and ``XPUB_MANUAL_LAST_VALUE`` (which would send the replay to the new
subscriber alone) pair each subscription the application receives with its peer
through a queue in libzmq 4.3.5 that frames which are not subscriptions shift: one
``b"\\x07hello"`` from an attacker makes the daemon attach the next honest subscriber's
subscription to the attacker's connection (tried: the honest SUB got nothing, the
attacker its messages). Nor do they save memory: ``xpub.cpp`` still stores every topic a
peer sends, in ``_manual_subscriptions`` (20 000 random 20-byte topics cost 23 MiB
either way). ``ZMQ_XPUB_WELCOME_MSG`` is one fixed frame per connection, not a cached
two-frame message.

Peers. libzmq keeps every topic a connected peer subscribes to (about 48 bytes per
byte of a random topic) and queues every frame it sent for ``recv`` without a bound,
and it reads a peer for as long as the peer keeps sending. The publisher cannot cap
that per peer; it ends peers instead (tests/test_publisher_attacks.py measures each):

- admission: libzmq attaches a connection, and reads its peer's frames, only after
  ``pump`` has admitted it as its ZAP handler (RFC 27; NULL mechanism, no
  credentials). A connection from an address (TCP) or process (ipc) that flooded
  within ``FLOOD_PENALTY_S`` is reset instead (a libzmq SUB refused through ZAP would
  never connect again; one reset retries by itself).
- CURVE (``curve``, TCP only): the socket is a CURVE server, so the stream is
  encrypted and only a peer that holds the secret key of one of the public keys in the
  ``clients`` directory gets past ZAP; any other key is refused there (status 400, a
  log line with its Z85 text), which is what is wanted: a libzmq SUB so refused does
  not try again. The directory is re-read when it changes (``_Allowlist``): while
  handshakes come, at most every ``ALLOWLIST_CHECK_S``, in the loop like the rest of
  ``pump``; a connection already admitted stays until it ends. A plain (NULL) peer
  fails the ZMTP handshake before ZAP is asked, as does a client that pins another
  server key. The handshake's frames are longer than ``MAX_INBOUND_FRAME_BYTES``
  allows, so a CURVE socket takes ``CURVE_INBOUND_FRAME_BYTES``.
- at most ``MAX_PEERS`` connections, counted from the monitor's accept and disconnect
  events, which give each connection's descriptor; one past the cap is ended at once.
  The newest goes, so subscribers already connected keep working, and a ZeroMQ SUB
  retries by itself until a place frees. ``HANDSHAKE_IVL_MS`` frees a place taken by
  a client that never completes ZMTP. A sensor replug thus always finds a descriptor.
- floods: a peer with more than ``FLOOD_UNREAD_BYTES`` unread in its socket
  (``FIONREAD``) sends faster than the daemon reads, which no honest subscriber does.
  ``pump`` looks while frames come (at once when a subscription matches no cached
  topic), and so does the waker while the loop is inside a receive: libzmq applies a
  peer's frames within the receive that processes commands, for as long as they keep
  coming. Such a peer is reset (TCP) or shut down (ipc), and libzmq frees its topics.
- topics the daemon does not publish: while subscriptions that match no cached topic
  arrive, each TCP peer is charged what it sends (``TCP_INFO``), and one past
  ``FOREIGN_BYTES_MAX`` is reset too. Over ipc, where the kernel counts no bytes per
  connection, ZAP gives each connection a user id of its own (RFC 27), which libzmq
  attaches to every frame the connection sends (the ``User-Id`` property), so ``pump``
  charges each such subscription to the connection that sent it; past
  ``FOREIGN_BYTES_MAX`` the connections of that process are shut. That caps libzmq's
  trie per connection even for a peer paced never to fall behind.
- ``MAX_INBOUND_FRAME_BYTES`` (``ZMQ_MAXMSGSIZE``): libzmq drops a peer whose frame is
  longer, before it allocates it. ``INBOUND_HWM`` and ``INBOUND_SOCKET_BUFFER_BYTES``
  keep what a peer has in flight small.
- ``pump`` handles at most ``PUMP_EVENTS`` frames and ``MONITOR_EVENTS`` connection
  events (each) per call, then returns and has the loop woken for the rest, so the read
  loop's stop, reload and watchdog never wait on peers. Frames that are not
  subscriptions (``b"\\x07hello"``, unsubscriptions) cost one receive each.

Not bounded: a flooder sharing an address (TCP) or process (ipc) with a new subscriber
delays that subscriber's admission until ``FLOOD_PENALTY_S`` after its last flood.
Peers holding every place lock new subscribers out until one leaves. Memory libzmq
frees stays in the process's heap for reuse: the resident size shows the peak.

Sends never block the read loop (``NOBLOCK``). At the high-water mark ZeroMQ drops
messages per subscriber without telling the sender; subscribers see those losses as
gaps in ``seq``. ``dropped_sends`` counts what the socket refused outright.
ZMQ_CONFLATE is not used: it breaks multipart messages.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import logging
import os
import select
import socket
import stat
import struct
import termios
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from time import monotonic_ns
from typing import cast

import zmq
from zmq.utils import z85

from lunad.daemon.config import (
    MAX_CLIENT_KEYS,
    CurveFiles,
    is_ipv6_endpoint,
    non_loopback_host,
)
from lunad.daemon.errors import PublishError
from lunad.protocol.curve_keys import read_key_file, z85_key
from lunad.protocol.messages import as_cached

log = logging.getLogger("lunad.publisher")

LINGER_MS = 200  # on close, how long queued messages may still go out
_EVENTS = int(zmq.EVENTS)  # plain ints: pyzmq's enum arithmetic costs on every call
_POLLIN = int(zmq.POLLIN)
_NOBLOCK = int(zmq.NOBLOCK)
_MORE = int(zmq.NOBLOCK | zmq.SNDMORE)
WAKER_HANDSHAKE_S = 1.0  # the waker re-arms after a pump, or after this at the latest
SUBSCRIBE = 1  # first byte of an XPUB subscription message (zmq_socket(3))
NS = 1_000_000_000

PUMP_EVENTS = 64
"""Frames one ``pump`` reads at most: about 100 us of work, so a frame period (4 ms at
250 Hz) is never spent on peers, and more than libzmq moves into its queue between two
passes of the loop while a peer floods (``INBOUND_HWM`` per peer per send)."""
MONITOR_EVENTS = 256
"""Connection events one ``pump`` reads at most: each is a few microseconds (one more
to shut a connection past the cap), and a burst of connections must be answered before
it uses up the process's descriptors."""
REPLAY_INTERVAL_S = 0.5
"""Each cached topic is replayed at most this often, seconds: what a flood of
subscriptions can cost an honest subscriber in duplicates (two a second per topic),
and the longest a newcomer waits for the cached value when another subscribed just
before it."""
MAX_INBOUND_FRAME_BYTES = 128
"""``ZMQ_MAXMSGSIZE``: the longest frame an honest subscriber sends is a subscription to
``health/`` and a 64-character sensor name (72 bytes; 81 as a ZMTP 3.1 SUBSCRIBE
command), its READY command about 30. A longer frame ends the connection before
libzmq allocates it (a 1 MB topic cost 45 MiB of trie), and a random topic a peer may
still send costs at most about 6 KiB of trie (48 bytes per byte)."""
CURVE_INBOUND_FRAME_BYTES = 512
"""``ZMQ_MAXMSGSIZE`` of a CURVE socket: libzmq applies it to the handshake's commands
too, and a libzmq SUB's INITIATE is about 275 bytes (HELLO 200), so 128 would refuse
every client (measured: 272 fails, 276 passes). 512 leaves room for a client's
metadata. A subscription costs 33 bytes more when encrypted (an 81-byte SUBSCRIBE is
a 114-byte MESSAGE), and only admitted peers get to send one."""
ALLOWLIST_CHECK_S = 1.0
"""How often, at most, the CURVE client-key directory is looked at for changes while
peers connect, seconds: one ``stat`` per entry, and the keys read again only when one
changed. A key removed from it is refused to connections that start this long later."""
REFUSAL_LOG_INTERVAL_S = 1.0
"""A refused CURVE key is logged at most this often, seconds; refusals in between are
counted in the next line, so a peer retrying without end cannot fill the journal."""
PEER_REFUSAL_LOG_INTERVAL_S = 60.0
"""Connections shut at once (past ``MAX_PEERS``, or from a flood's origin) are logged at
most this often, seconds, with how many since the last such line: a subscriber turned
away is otherwise told nothing, and its owner looks for the fault in its own key or
group."""
INBOUND_HWM = 8
"""``ZMQ_RCVHWM``, messages per peer: about what libzmq moves from a peer into its own
unbounded queue each time it processes commands while the loop keeps up. An honest
subscriber sends a few subscriptions."""
INBOUND_SOCKET_BUFFER_BYTES = 16 * 1024
"""``ZMQ_RCVBUF`` (``SO_RCVBUF``, which Linux doubles) of each connection: what a peer can
have waiting in the kernel. Subscriptions need a few hundred bytes; a fixed size stops
TCP's autotuning from growing a flooding peer's queue to megabytes."""
FLOOD_UNREAD_BYTES = 4096
"""Bytes a peer has sent that libzmq has not read yet (``FIONREAD``) that mark a flood:
an honest subscriber's handshake and subscriptions are a few hundred bytes, read at once."""
FLOOD_CHECK_S = 0.01
"""How often, at most, every peer's unread bytes are looked at while peers send,
seconds (one ``ioctl`` per peer, about 1 us each). ``pump`` also looks at once when a
subscription matches no cached topic (libzmq stores each such topic for its peer)."""
DISCARD_READS = 4
"""Reads of ``INBOUND_SOCKET_BUFFER_BYTES`` that empty a shut ipc peer's queue (twice
that size, as Linux doubles it), so that libzmq reads the end of the stream next."""
MAX_PEERS = 64
"""Connections served at once: well under the 1024-descriptor soft limit, so the
sensor's port, a recording and a reopen always find one. Nothing in libzmq caps this."""
HANDSHAKE_IVL_MS = 5000
"""``ZMQ_HANDSHAKE_IVL``: a connection that has not completed the ZMTP handshake by
then is closed (libzmq's default is 30 s), freeing its place under ``MAX_PEERS``."""
FLOOD_PENALTY_S = 1.0
"""After a peer is shut for a flood, further connections from its address (TCP) or
process (ipc) are reset as they come for this long, seconds: each new connection takes
in about one 8 KiB read before a sweep can end it, so a flooder reconnecting at once
would otherwise outrun ``pump``. Subscribers already connected are not touched."""
PENALTIES_MAX = 1024  # addresses remembered at most; the oldest go first
USER_ID_PROPERTY = "User-Id"  # the frame property that carries ZAP's user id (zmq_msg_gets(3))
FOREIGN_BYTES_MAX = 16 * 1024
"""Bytes a TCP peer may send, over its connection's life, in the moments when
subscriptions to topics that match no cached one are arriving (``TCP_INFO``'s bytes
received, charged between checks at most ``FOREIGN_WINDOW_S`` apart); over ipc, the
bytes of such subscriptions a connection sent (its ZAP user id). An honest
subscriber sends a few subscriptions and at most heartbeats; a peer sending distinct
topics slowly enough never to be behind is cut here, after about 130 topics of 120
bytes (some 800 KiB of libzmq's trie) or 700 of 20."""
FOREIGN_WINDOW_S = 1.0
"""Checks further apart than this, seconds, take a new starting point instead of
charging what came between (an honest subscriber's heartbeats over an hour are not a
flood)."""
ZAP_ENDPOINT = "inproc://zeromq.zap.01"  # where libzmq asks, in the socket's context (RFC 27)
MONITOR_HWM = 10_000
"""Connection events the monitor pipe holds before libzmq drops them (it sends them
without blocking); a few dozen bytes each."""
_PEER_EVENTS = int(zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED)
_ACCEPTED = int(zmq.EVENT_ACCEPTED)
_DISCONNECTED = int(zmq.EVENT_DISCONNECTED)
_UNREAD = struct.Struct("i")
_SERVED, _REFUSED, _FLOODING = 0, 1, 2  # a peer's state in Publisher._peers
_TCP_INFO: int | None = getattr(socket, "TCP_INFO", None)  # Linux only
_TCP_INFO_LEN = 232  # bytes asked for: struct tcp_info of Linux 5.x and 6.x, or what it has
_BYTES_RECEIVED = struct.Struct("=Q")  # tcp_info.tcpi_bytes_received (Linux >= 4.1)
_BYTES_RECEIVED_OFFSET = 128
_UCRED = struct.Struct("3i")  # struct ucred: pid, uid, gid (SO_PEERCRED)
_SO_PEERCRED: int | None = getattr(socket, "SO_PEERCRED", None)  # Linux only
_AF_UNSPEC_ADDRESS = bytes(16)  # a struct sockaddr whose family is AF_UNSPEC (0)


def _libc_connect() -> Callable[[int, bytes, int], int] | None:
    """The C library's ``connect``: Python's cannot pass AF_UNSPEC to a TCP socket."""
    try:
        return cast(Callable[[int, bytes, int], int], ctypes.CDLL(None).connect)
    except (OSError, AttributeError):
        return None


_LIBC_CONNECT = _libc_connect()


def _claim_ipc_path(path: Path, endpoint: str) -> None:
    """Make ``path`` free for our ipc socket, or refuse: libzmq unlinks whatever is
    there before it binds, so a regular file would be deleted and another live
    daemon's socket taken over (its subscribers silently moved to us).

    A socket file nobody listens on (left by a daemon that died) is removed.

    Raises:
        PublishError: the path is not a socket, or a live process listens on it.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise PublishError(f"cannot bind {endpoint}: {exc}") from exc
    if not stat.S_ISSOCK(st.st_mode):
        raise PublishError(
            f"cannot bind {endpoint}: {path} exists and is not a socket; refusing to replace it"
        )
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(1.0)
        probe.connect(str(path))
    except ConnectionRefusedError:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()  # stale: nobody listens
        return
    except OSError as exc:
        raise PublishError(f"cannot bind {endpoint}: {exc}") from exc
    finally:
        probe.close()
    raise PublishError(f"cannot bind {endpoint}: another process is listening on {path}")


def _server_keys(path: Path, endpoint: str) -> tuple[bytes, bytes]:
    """The (public, secret) Z85 keys of the CURVE server's secret key file ``path``.

    The config checked the file already; it is read again here, as it may have changed
    since. A file other users can read is used, with a warning: its key no longer
    proves that the publisher is this daemon.

    Raises:
        PublishError: the file is not a usable secret key file.
    """
    try:
        public, secret = read_key_file(path, secret=True)
    except ValueError as exc:
        raise PublishError(f"cannot bind {endpoint} with CURVE: {exc}") from None
    if secret is None:  # read_key_file(secret=True) raises first; for the type checker
        raise PublishError(f"cannot bind {endpoint} with CURVE: {path} holds no secret key")
    with contextlib.suppress(OSError):
        if os.stat(path).st_mode & (stat.S_IRWXG | stat.S_IRWXO):
            log.warning(
                "CURVE: %s can be read by other users than its owner: whoever reads it "
                "can pose as this daemon; chmod 0600 it",
                path,
            )
    return public, secret


def _zap_origin(address: bytes, ipc: bool) -> str:
    """``_origin``'s form of a ZAP request's address: libzmq gives a TCP peer's address,
    and ``localhost:uid:gid:pid`` for an ipc one."""
    text = address.decode("ascii", "replace")
    if ipc:
        parts = text.rsplit(":", 3)
        return f"pid {parts[3]}" if len(parts) == 4 else text
    return text


@contextlib.contextmanager
def _borrowed(fd: int) -> Iterator[socket.socket | None]:
    """A socket object on a duplicate of libzmq's descriptor ``fd`` (None when it is
    closed), so that libzmq's descriptor stays libzmq's to close."""
    try:
        dup = os.dup(fd)
    except OSError:
        yield None
        return
    try:
        s = socket.socket(fileno=dup)
    except OSError:
        os.close(dup)
        yield None
        return
    with s:
        yield s


def _origin(fd: int) -> tuple[int, str] | None:
    """The inode of the socket on ``fd`` and where its peer is: the address of a TCP
    peer, the process id of an ipc one (``SO_PEERCRED``); None when ``fd`` is closed."""
    try:
        with _borrowed(fd) as s:
            if s is None:
                return None
            ino = os.fstat(s.fileno()).st_ino
            if s.family != socket.AF_UNIX:
                return ino, str(s.getpeername()[0])
            if _SO_PEERCRED is None:
                return ino, "ipc"
            cred = s.getsockopt(socket.SOL_SOCKET, _SO_PEERCRED, _UCRED.size)
            return ino, f"pid {_UCRED.unpack(cred)[0]}"
    except OSError:
        return None


def _bytes_received(fd: int) -> int | None:
    """What the TCP peer on ``fd`` has sent so far, bytes (``tcpi_bytes_received``), or
    None where the kernel does not say (not Linux, older than 4.1, closed)."""
    if _TCP_INFO is None:
        return None
    try:
        with _borrowed(fd) as s:
            if s is None:
                return None
            info = s.getsockopt(socket.IPPROTO_TCP, _TCP_INFO, _TCP_INFO_LEN)
    except OSError:
        return None
    if len(info) < _BYTES_RECEIVED_OFFSET + _BYTES_RECEIVED.size:
        return None
    return int(_BYTES_RECEIVED.unpack_from(info, _BYTES_RECEIVED_OFFSET)[0])


@dataclass(slots=True)
class _Peer:
    """One accepted connection, as the publisher tracks it."""

    ino: int  # its socket's inode: the descriptor number may be reused
    origin: str  # its address (TCP) or process (ipc)
    state: int = _SERVED  # or _REFUSED or _FLOODING, once shut by the publisher
    charged: int = 0  # bytes sent while foreign subscriptions came (FOREIGN_BYTES_MAX)
    received: int | None = None  # tcpi_bytes_received at the last charge


class _Allowlist:
    """The client public keys a CURVE publisher admits: the ``*.key`` files of one
    directory, each read with ``read_key_file``; a file that is not a key file is
    logged and skipped.

    ``refresh`` looks at the directory at most every ``ALLOWLIST_CHECK_S`` and reads
    the keys again when an entry's name, inode, size or time changed. It fails closed:
    a directory that cannot be listed, or holds more than ``MAX_CLIENT_KEYS`` entries,
    admits nobody (one error line each time that changes).
    """

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.keys: dict[bytes, str] = {}
        """Admitted keys (32 bytes) -> the file's name, for the log."""
        self._signature: object = None
        self._next_check_ns = 0

    def refresh(self, now: int, force: bool = False) -> None:
        """Re-read the keys if the directory changed since the last look."""
        if not force and now < self._next_check_ns:
            return
        self._next_check_ns = now + int(ALLOWLIST_CHECK_S * NS)
        signature, files, problem = self._scan()
        if signature == self._signature:
            return
        self._signature = signature
        if problem is not None:
            self.keys = {}
            log.error("CURVE: %s; admitting no client until that is fixed", problem)
            return
        keys: dict[bytes, str] = {}
        for path in files:
            try:
                public, _ = read_key_file(path)
            except ValueError as exc:
                log.warning("CURVE: skipping a client key: %s", exc)
                continue
            raw = z85_key(public)
            if raw is not None:
                keys[raw] = path.name
        self.keys = keys
        if keys:
            log.info(
                "CURVE: admitting %d client key(s) from %s: %s",
                len(keys),
                self.directory,
                ", ".join(sorted(keys.values())),
            )
        else:
            log.warning("CURVE: no client key in %s: every connection is refused", self.directory)

    def _scan(self) -> tuple[object, list[Path], str | None]:
        """The directory's signature, its ``*.key`` files (sorted), and what makes it
        unusable (None when it is usable)."""
        where = self.directory
        entries: list[tuple[str, int, int, int]] = []
        files: list[Path] = []
        try:
            with os.scandir(where) as it:
                for entry in it:
                    if len(entries) >= MAX_CLIENT_KEYS:
                        return (
                            "too many",
                            [],
                            f"{where} holds more than {MAX_CLIENT_KEYS} entries",
                        )
                    if not entry.name.endswith(".key"):
                        entries.append((entry.name, 0, 0, 0))
                        continue
                    try:
                        st = entry.stat()
                    except OSError:
                        entries.append((entry.name, -1, -1, -1))
                    else:
                        entries.append((entry.name, st.st_ino, st.st_size, st.st_mtime_ns))
                    files.append(Path(entry.path))
        except OSError as exc:
            return ("unlisted", exc.errno), [], f"{where} cannot be listed: {exc.strerror or exc}"
        return sorted(entries), sorted(files), None


class Publisher:
    """A bound XPUB socket sending two-frame messages (topic, JSON).

    Counters (since the socket was bound): ``sent``, ``dropped_sends``,
    ``subscriptions`` (subscription frames received, from anyone), ``replays``
    (cached messages re-sent), ``junk_frames`` (frames that are not subscriptions),
    ``refused_peers`` (connections shut at once: past ``MAX_PEERS``, or from where a
    flood came within ``FLOOD_PENALTY_S``), ``flooding_peers`` (connections shut for
    ``FLOOD_UNREAD_BYTES``) and ``refused_keys`` (CURVE handshakes refused: a key not
    in the client directory); ``peers`` is the number served.

    With ``curve`` (a ``tcp://`` endpoint only) the socket is a CURVE server with the
    key pair in ``curve.secret_key`` that admits the client keys in ``curve.clients``.
    Without it, a TCP endpoint other machines may reach is bound with one warning: the
    stream is then clear text to whoever can connect.

    Raises:
        PublishError: the endpoint cannot be bound, or the CURVE secret key cannot be
            read.
    """

    def __init__(
        self,
        endpoint: str,
        sndhwm: int = 1000,
        stale_after_s: float = 0.5,
        curve: CurveFiles | None = None,
    ) -> None:
        self.endpoint = endpoint
        self._stale_after_ms = int(stale_after_s * 1000)
        """A cached range older than this is replayed as a ``stale`` dropout."""
        self._sent_ns: dict[bytes, int] = {}
        """When each cached topic's message was sent live (monotonic ns)."""
        self._socket_path: Path | None = None
        """The ipc socket file this publisher bound, removed at close."""
        self.dropped_sends = 0
        self.sent = 0
        self.subscriptions = 0
        self.replays = 0
        self.junk_frames = 0
        self.refused_peers = 0
        self.flooding_peers = 0
        self.refused_keys = 0
        self._refusals_unlogged = 0
        self._next_refusal_log_ns = 0
        self._peers_refused_unlogged = [0, 0]  # past MAX_PEERS, penalized for a flood
        self._next_peer_refusal_log_ns = 0
        self._allowlist: _Allowlist | None = None
        """The client keys admitted; None without CURVE (every peer is admitted)."""
        server_keys: tuple[bytes, bytes] | None = None
        if curve is not None:
            if not endpoint.startswith("tcp://"):
                raise PublishError(f"cannot bind {endpoint} with CURVE: tcp:// endpoints only")
            server_keys = _server_keys(curve.secret_key, endpoint)
            self._allowlist = _Allowlist(curve.clients)
        self._last: dict[bytes, bytes] = {}
        self._replayed_ns: dict[bytes, int] = {}
        """When each cached topic was last replayed (monotonic ns)."""
        self._deferred: set[bytes] = set()
        """Cached topics a subscription asked for inside their replay interval."""
        self._replay_due_ns: int | None = None
        """When the first deferred replay is due (monotonic ns): the waker wakes the loop."""
        self._peers: dict[int, _Peer] = {}
        """Connected peers by libzmq's descriptor. The loop and the waker both change
        it, under ``_peers_lock``."""
        self._last_charge_ns: int | None = None
        self._penalties: dict[str, int] = {}
        """Where floods came from -> until when (monotonic ns) its connections are refused."""
        self._ipc_charges: dict[bytes, int] = {}
        """ZAP user id of an ipc connection -> bytes of subscriptions to topics the daemon
        does not publish that it sent (``_charge_ipc``); at most ``PENALTIES_MAX``."""
        self._zap_requests = 0  # handshakes answered: numbers each connection's user id
        self._peers_lock = threading.Lock()
        self._next_sweep_ns = 0
        self._wake: Callable[[], None] | None = None
        self._pumped = threading.Event()
        self._closing = False
        self.pending = True
        """Set by the waker, by ``send`` and by ``pump`` when it stopped at a bound:
        ``pump`` has something to do."""
        self._waker: threading.Thread | None = None
        self._waker_stop_r, self._waker_stop_w = -1, -1
        self._monitor: zmq.Socket[bytes] | None = None
        self._zap: zmq.Socket[bytes] | None = None
        self._ipc = endpoint.startswith("ipc://")
        if self._ipc:
            path = Path(endpoint.removeprefix("ipc://"))
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise PublishError(f"cannot bind {endpoint}: {exc}") from exc
            _claim_ipc_path(path, endpoint)
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.XPUB)
        self._sock.setsockopt(zmq.SNDHWM, sndhwm)
        self._sock.setsockopt(zmq.RCVHWM, INBOUND_HWM)
        self._sock.setsockopt(zmq.RCVBUF, INBOUND_SOCKET_BUFFER_BYTES)
        self._sock.setsockopt(
            zmq.MAXMSGSIZE,
            MAX_INBOUND_FRAME_BYTES if server_keys is None else CURVE_INBOUND_FRAME_BYTES,
        )
        if server_keys is not None:
            self._sock.setsockopt(zmq.CURVE_SERVER, 1)
            self._sock.setsockopt(zmq.CURVE_PUBLICKEY, server_keys[0])
            self._sock.setsockopt(zmq.CURVE_SECRETKEY, server_keys[1])
        self._sock.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_IVL_MS)
        self._sock.setsockopt(zmq.LINGER, LINGER_MS)
        self._sock.setsockopt(zmq.XPUB_VERBOSE, 1)
        self._zap = self._ctx.socket(zmq.ROUTER)
        self._zap.setsockopt(zmq.LINGER, 0)
        self._zap.bind(ZAP_ENDPOINT)
        self._sock.setsockopt(zmq.ZAP_DOMAIN, b"lunad")  # any domain has ZAP asked
        self._send = super(zmq.Socket, self._sock).send
        """pyzmq's backend ``send``, past the Python layer of ``zmq.Socket.send``,
        which only adds the routing_id and group arguments of draft sockets."""
        self._events = self._sock.getsockopt
        monitor_addr = f"inproc://lunad-publisher-monitor-{id(self):x}"
        self._sock.monitor(monitor_addr, _PEER_EVENTS)
        self._monitor = self._ctx.socket(zmq.PAIR)
        self._monitor.setsockopt(zmq.RCVHWM, MONITOR_HWM)
        self._monitor.setsockopt(zmq.LINGER, 0)
        self._monitor.connect(monitor_addr)
        self._sock.setsockopt(zmq.IPV6, int(is_ipv6_endpoint(endpoint)))
        try:
            self._sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.close()
            raise PublishError(f"cannot bind {endpoint}: {exc}") from exc
        if self._ipc:
            self._socket_path = Path(endpoint.removeprefix("ipc://"))
        if self._allowlist is not None and server_keys is not None:
            log.info(
                "CURVE: %s is a CURVE server with public key %s",
                endpoint,
                server_keys[0].decode("ascii"),
            )
            self._allowlist.refresh(monotonic_ns(), force=True)
        elif (host := non_loopback_host(endpoint)) is not None:
            log.warning(
                "publishing on %s (host %s) in clear text, without CURVE: the stream is "
                "readable by any host that can reach it, and any host that can redirect "
                "the traffic can pose as this daemon; set [publish] curve_secret_key and "
                "curve_clients (docs/security.md, section 2)",
                endpoint,
                host,
            )

    @property
    def peers(self) -> int:
        """Connections served now (accepted and not shut by the publisher)."""
        return sum(1 for peer in list(self._peers.values()) if peer.state == _SERVED)

    def send(self, topic: bytes, payload: bytes) -> bool:
        """Queue one message and cache it as the topic's last value.

        Returns False (and counts it) when the socket refused the message.

        A send processes the socket's commands, so it takes in what peers sent and
        clears ``ZMQ_FD`` before the waker may have seen it; asking ``ZMQ_EVENTS``
        afterwards (about 1 us) sets ``pending`` for what it took in, so a peer
        sending while the daemon publishes is read on the loop's next pass, not left
        to grow libzmq's queue until the next health message.
        """
        self._last[topic] = payload
        self._sent_ns[topic] = monotonic_ns()
        if self._deferred:
            self._deferred.discard(topic)  # this message reaches the newcomer instead
        send = self._send
        try:
            send(topic, _MORE)
            send(payload, _NOBLOCK)  # a PUB that took the first part takes the rest
        except zmq.Again:
            self.dropped_sends += 1
            return False
        finally:
            if cast(int, self._events(_EVENTS)) & _POLLIN:
                self.pending = True
        self.sent += 1
        return True

    def pump(self) -> int:
        """Answer new subscriptions with the cached last values; returns how many came.

        The loop calls it when ``pending`` is set and with every health message as a
        fallback, so frames do not pay for it. One call reads at most
        ``MONITOR_EVENTS`` connection events and ``PUMP_EVENTS`` frames, then returns;
        what is left waits for the next call, which the loop is woken for.
        """
        sock = self._sock
        self.pending = False
        now = monotonic_ns()
        self._read_monitor()
        self._answer_zap()
        recv = sock.recv
        ipc = self._ipc
        last = self._last
        wanted: set[bytes] = set()
        n = frames = foreign = 0
        while frames < PUMP_EVENTS:
            try:
                frame = recv(_NOBLOCK, copy=not ipc)
            except zmq.Again:
                break
            frames += 1
            msg = frame.bytes if isinstance(frame, zmq.Frame) else frame
            if not msg or msg[0] != SUBSCRIBE:
                self.junk_frames += 1
                continue
            n += 1
            prefix = msg[1:]
            ours = False
            for topic in last:
                if topic.startswith(prefix):
                    wanted.add(topic)
                    ours = True
            if not ours:
                foreign += 1
                if isinstance(frame, zmq.Frame):
                    self._charge_ipc(frame, len(msg))
        else:
            self._more_queued()
        self.subscriptions += n
        if wanted or self._deferred:
            self._replay(wanted, now)
        if not self._deferred:
            self._replay_due_ns = None  # a live message may have stood in for them
        if frames:
            self._sweep(now, foreign=foreign > 0)
        self._pumped.set()
        return n

    def _charge_ipc(self, frame: zmq.Frame, size: int) -> None:
        """Charge ``size`` bytes of a subscription to a topic the daemon does not
        publish to the ipc connection that sent ``frame`` (its ZAP user id); past
        ``FOREIGN_BYTES_MAX``, shut every connection of that process and penalize it.

        A process, not one connection, because the user id cannot be matched to a
        descriptor: ZAP gives the peer's process id, the monitor the descriptor.
        """
        try:
            user = str(frame.get(USER_ID_PROPERTY)).encode()
        except zmq.ZMQError:  # admitted before ZAP answered with an id: cannot happen
            return
        charges = self._ipc_charges
        charged = charges.pop(user, 0) + size  # re-inserted last: the oldest go first
        if charged <= FOREIGN_BYTES_MAX:
            charges[user] = charged
            while len(charges) > PENALTIES_MAX:
                del charges[next(iter(charges))]
            return
        origin = user.decode("ascii", "replace").rsplit("#", 1)[0]
        now = monotonic_ns()
        with self._peers_lock:
            for fd, peer in list(self._peers.items()):
                if peer.state == _SERVED and peer.origin == origin:
                    self._cut(fd, _FLOODING)
                    self.flooding_peers += 1
            self._penalize(origin, now)

    def _more_queued(self) -> None:
        """``pump`` stopped at a bound: have the loop call it again on its next pass.

        The waker may not see the rest (a receive that returned a message need not
        have read ``ZMQ_FD``), so the loop is woken too; a woken read still returns
        the sensor's bytes first.
        """
        self.pending = True
        if self._wake is not None:
            self._wake()

    def _replay(self, wanted: set[bytes], now: int) -> None:
        """Re-send the cached value of each topic in ``wanted`` and of each deferred
        one whose interval is over; defer the rest (``REPLAY_INTERVAL_S``)."""
        interval = int(REPLAY_INTERVAL_S * NS)
        deferred = self._deferred
        deferred |= wanted
        for topic in list(deferred):
            if now - self._replayed_ns.get(topic, -interval) < interval:
                continue
            deferred.discard(topic)
            self._replayed_ns[topic] = now
            age_ms = (now - self._sent_ns.get(topic, now)) // 1_000_000
            kind = topic.split(b"/", 1)[0].decode("ascii", "replace")
            try:
                payload = as_cached(kind, self._last[topic], age_ms, self._stale_after_ms)
            except ValueError:  # not a range message this contract knows: as it was
                payload = self._last[topic]
            try:
                self._send(topic, _MORE)
                self._send(payload, _NOBLOCK)
            except zmq.Again:
                self.dropped_sends += 1
                continue
            self.replays += 1
        if deferred:
            due = min(self._replayed_ns[topic] for topic in deferred) + interval
            if self._replay_due_ns is None or due < self._replay_due_ns:
                self._replay_due_ns = due
                self._kick_waker()

    def _kick_waker(self) -> None:
        """Have the waker look at ``_replay_due_ns`` again."""
        if self._waker_stop_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._waker_stop_w, b"k")

    def _read_monitor(self) -> None:
        """Track connections from the monitor's events; shut those past ``MAX_PEERS``."""
        mon = self._monitor
        if mon is None:
            return
        peers = self._peers
        for _ in range(MONITOR_EVENTS):
            try:
                head = mon.recv(_NOBLOCK)
                mon.recv(_NOBLOCK)  # the endpoint; a multipart message arrives whole
            except zmq.Again:
                break
            event, fd = struct.unpack("=Hi", head)
            with self._peers_lock:
                if event == _DISCONNECTED:
                    peers.pop(fd, None)
                elif event == _ACCEPTED:
                    found = _origin(fd)
                    if found is None:
                        continue  # already closed again; its DISCONNECTED follows
                    ino, origin = found
                    penalized = monotonic_ns() < self._penalties.get(origin, 0)
                    refuse = penalized or self.peers >= MAX_PEERS
                    peers[fd] = _Peer(ino, origin, state=_REFUSED if refuse else _SERVED)
                    if refuse:
                        self._cut(fd, _REFUSED)
                        self.refused_peers += 1
                        self._peers_refused_unlogged[penalized] += 1
        else:
            self._more_queued()
        if any(self._peers_refused_unlogged):
            self._log_refused_peers()

    def _log_refused_peers(self) -> None:
        """Say, at most every ``PEER_REFUSAL_LOG_INTERVAL_S``, how many connections were
        shut at once since the last such line, and why."""
        now = monotonic_ns()
        with self._peers_lock:  # the loop and the waker both read the monitor
            if now < self._next_peer_refusal_log_ns:
                return
            self._next_peer_refusal_log_ns = now + int(PEER_REFUSAL_LOG_INTERVAL_S * NS)
            full, flood = self._peers_refused_unlogged
            self._peers_refused_unlogged = [0, 0]
        why = []
        if full:
            why.append(f"{full} past the {MAX_PEERS} it serves at once")
        if flood:
            why.append(f"{flood} from where a flood came, for {FLOOD_PENALTY_S:g} s")
        log.warning(
            "%s: shut %d new connection(s) at once since the last such line (%s); %d served",
            self.endpoint,
            full + flood,
            "; ".join(why),
            self.peers,
        )

    def _answer_zap(self) -> None:
        """Admit each connection waiting in its handshake (ZAP, RFC 27), unless its
        address (TCP) or process (ipc) is penalized for a flood.

        libzmq attaches a connection, and so reads what its peer sends, only once this
        has answered; by then ``_read_monitor`` has usually seen it accepted, and reset
        it if penalized. A penalized one not yet seen gets no answer: the monitor's
        event comes next, or ``HANDSHAKE_IVL_MS`` ends it. No connection is refused
        through ZAP for a flood, because a libzmq SUB refused so (an ERROR command)
        never connects again, while one reset reconnects by itself. That is why a
        CURVE key not in the allowlist is refused through ZAP (``_curve_status``).
        """
        zap = self._zap
        if zap is None:
            return
        for _ in range(MONITOR_EVENTS):
            try:
                request = zap.recv_multipart(_NOBLOCK)
            except zmq.Again:
                break
            # routing id, b"", version, request id, domain, address, identity, mechanism,
            # then the credentials: CURVE's is the client's public key (32 bytes)
            if len(request) < 8:
                continue
            origin = _zap_origin(request[5], self._ipc)
            now = monotonic_ns()
            with self._peers_lock:
                if now < self._penalties.get(origin, 0):
                    continue
            allowlist = self._allowlist
            status = b"200" if allowlist is None else self._curve_status(allowlist, request, now)
            text = b"OK" if status == b"200" else b"key not allowed"
            self._zap_requests += 1
            user = f"{origin}#{self._zap_requests}".encode()  # one per connection: _charge_ipc
            reply = [request[0], b"", b"1.0", request[3], status, text, user, b""]
            with contextlib.suppress(zmq.ZMQError):
                zap.send_multipart(reply)
        else:
            self._more_queued()

    def _curve_status(self, allowlist: _Allowlist, request: list[bytes], now: int) -> bytes:
        """The ZAP status for a handshake on a CURVE socket: 200 for a CURVE peer whose
        public key is in ``allowlist``, 400 for any other (logged, ``refused_keys``)."""
        allowlist.refresh(now)
        key = request[8] if len(request) > 8 else b""
        if request[7] == b"CURVE" and len(key) == 32 and key in allowlist.keys:
            return b"200"
        self.refused_keys += 1
        self._refusals_unlogged += 1
        if now >= self._next_refusal_log_ns:
            self._next_refusal_log_ns = now + int(REFUSAL_LOG_INTERVAL_S * NS)
            shown = (
                z85.encode(key).decode("ascii")
                if len(key) == 32
                else f"{request[7].decode('ascii', 'replace')} mechanism, no key"
            )
            more = self._refusals_unlogged - 1
            log.info(
                "CURVE: refused %s from %s: key not in %s%s",
                shown,
                request[5].decode("ascii", "replace"),
                allowlist.directory,
                f" ({more} more refused since the last such line)" if more else "",
            )
            self._refusals_unlogged = 0
        return b"400"

    def _sweep(self, now: int, foreign: bool = False) -> None:
        """End every peer with more than ``FLOOD_UNREAD_BYTES`` waiting in its socket;
        at most every ``FLOOD_CHECK_S``, unless subscriptions to ``foreign`` topics just
        came. Then also charge each TCP peer what it sent (``FOREIGN_BYTES_MAX``).

        Both the loop (``pump``) and the waker call it. The waker's calls matter
        while the loop is inside a receive: libzmq applies what a peer sent to its
        trie inside the receive that processes commands, and goes on for as long as
        the peer keeps its pipe full, so only a shutdown from outside ends it.
        """
        with self._peers_lock:
            if not foreign and now < self._next_sweep_ns:
                return
            self._next_sweep_ns = now + int(FLOOD_CHECK_S * NS)
            charge = foreign and not self._ipc and _TCP_INFO is not None
            window = False  # charge what came since the last check, or only start counting
            if charge:
                last, self._last_charge_ns = self._last_charge_ns, now
                window = last is not None and now - last <= int(FOREIGN_WINDOW_S * NS)
            buf = bytearray(_UNREAD.size)
            for fd, peer in list(self._peers.items()):
                if peer.state != _SERVED:
                    continue
                try:
                    same = os.fstat(fd).st_ino == peer.ino
                    if same:
                        fcntl.ioctl(fd, termios.FIONREAD, buf)
                except OSError:
                    same = False
                if not same:  # closed, and its event lost: it takes no place any more
                    self._peers.pop(fd, None)
                    continue
                flooding = _UNREAD.unpack(buf)[0] > FLOOD_UNREAD_BYTES
                if charge and not flooding:
                    received = _bytes_received(fd)
                    if received is not None:
                        if window and peer.received is not None:
                            peer.charged += received - peer.received
                        peer.received = received
                        flooding = peer.charged > FOREIGN_BYTES_MAX
                if flooding:
                    self._cut(fd, _FLOODING)
                    self.flooding_peers += 1
                    self._penalize(peer.origin, now)

    def _penalize(self, origin: str, now: int) -> None:
        """Refuse ``origin``'s connections for ``FLOOD_PENALTY_S``. Hold ``_peers_lock``."""
        penalties = self._penalties
        penalties.pop(origin, None)  # re-inserted last: the dict keeps the oldest first
        penalties[origin] = now + int(FLOOD_PENALTY_S * NS)
        while len(penalties) > PENALTIES_MAX:
            del penalties[next(iter(penalties))]

    def _cut(self, fd: int, why: int) -> None:
        """End the connection on libzmq's descriptor ``fd``; libzmq then reads the end
        of the stream, closes it and frees what the peer stored. Hold ``_peers_lock``.

        TCP: a ``connect`` to AF_UNSPEC resets the connection and drops what the peer
        had queued (a shutdown leaves both: libzmq would read the whole queue, and a
        half-closed peer can keep sending). ipc: a shutdown, which stops the peer's
        sends, and reads that empty the queue.

        It works on a duplicate, checked to be the socket (inode) the monitor
        reported, so a descriptor number reused meanwhile is left alone, and libzmq's
        own descriptor stays libzmq's to close.
        """
        peer = self._peers[fd]
        try:
            dup = os.dup(fd)
        except OSError:
            self._peers.pop(fd, None)
            return
        try:
            if os.fstat(dup).st_ino != peer.ino:
                self._peers.pop(fd, None)
                return
            peer.state = why
            with socket.socket(fileno=dup) as s:
                dup = -1  # the socket object closes it
                if s.family in (socket.AF_INET, socket.AF_INET6) and _LIBC_CONNECT:
                    _LIBC_CONNECT(s.fileno(), _AF_UNSPEC_ADDRESS, len(_AF_UNSPEC_ADDRESS))
                    return
                s.shutdown(socket.SHUT_RDWR)
                for _ in range(DISCARD_READS):
                    if not s.recv(INBOUND_SOCKET_BUFFER_BYTES, socket.MSG_DONTWAIT):
                        break
        except OSError:
            pass
        finally:
            if dup >= 0:
                os.close(dup)

    def start_waker(self, wake: Callable[[], None]) -> None:
        """Call ``wake`` (from a thread) whenever a socket may have something for ``pump``.

        The waker also wakes the loop when a deferred replay is due, and until the
        loop has pumped it sweeps for floods every ``FLOOD_CHECK_S`` (``_sweep``); a
        loop that pumps at once costs no sweep.
        """
        self._wake = wake
        fds = [cast(int, self._sock.getsockopt(zmq.FD))]
        for sock in (self._monitor, self._zap):
            if sock is not None:
                fds.append(cast(int, sock.getsockopt(zmq.FD)))
        self._waker_stop_r, self._waker_stop_w = os.pipe()
        os.set_blocking(self._waker_stop_w, False)  # a kick never blocks the loop
        fds.append(self._waker_stop_r)
        handshake_ns = int(WAKER_HANDSHAKE_S * NS)

        stop_r = self._waker_stop_r

        def run() -> None:
            while True:
                due = self._replay_due_ns
                timeout = None if due is None else max(0.0, (due - monotonic_ns()) / NS)
                ready, _, _ = select.select(fds, [], [], timeout)
                if stop_r in ready:
                    try:
                        got = os.read(stop_r, 4096)
                    except OSError:
                        return
                    if b"x" in got:
                        return
                    if len(ready) == 1:
                        continue  # a kick: a replay was deferred, time the select anew
                elif not ready and (due is None or monotonic_ns() < due):
                    continue
                self._pumped.clear()
                if self._closing:
                    return  # close() may have set _pumped just before that clear; no pump will come
                self.pending = True
                wake()
                woken = monotonic_ns()
                while not self._pumped.wait(FLOOD_CHECK_S):
                    now = monotonic_ns()
                    if self._closing or now - woken >= handshake_ns:
                        break
                    self._sweep(now)

        self._waker = threading.Thread(target=run, name="lvc-waker", daemon=True)
        self._waker.start()

    def close(self) -> None:
        """Stop the waker, close the sockets and their context; safe to call twice."""
        if self._waker is not None:
            self._closing = True
            os.write(self._waker_stop_w, b"x")
            self._pumped.set()  # release a waker waiting for the loop's handshake
            self._waker.join(timeout=2.0)
            self._waker = None
        for fd in (self._waker_stop_r, self._waker_stop_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._waker_stop_r = self._waker_stop_w = -1
        if self._monitor is not None:
            with contextlib.suppress(zmq.ZMQError):
                self._sock.monitor(None, 0)
            self._monitor.close()
            self._monitor = None
        if self._zap is not None:
            self._zap.close()
            self._zap = None
        self._sock.close()
        self._ctx.term()
        if self._socket_path is not None:  # ours: we bound it (a clobbered one is refused)
            with contextlib.suppress(OSError):
                self._socket_path.unlink()
            self._socket_path = None
