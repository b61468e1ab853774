"""Reading and checking ZeroMQ CURVE keys: Z85 text and ZPL key files.

The daemon (its config, publisher and ``lunad keys``) and the subscriber client both
take CURVE keys from files that a person names, so both read them here, with the same
checks and the same messages: a key file is read only if it is a regular file of at
most ``MAX_KEY_FILE_BYTES`` (a FIFO would block its reader without a word, a device be
read without end), and each key must be 40 Z85 characters. Each caller puts its own
context in front of the message (the config field, or the client's argument).

``zmq`` is imported inside the functions, so that importing this module (the daemon's
config does) does not load it.
"""

from __future__ import annotations

import os
import struct

from lunad.protocol.file_kind import file_kind

MAX_KEY_FILE_BYTES = 4096
"""Longest CURVE key file read, bytes: a ZPL certificate as ``zmq.auth`` writes it is
300 to 400 bytes. A larger file is not a key file, and the
type and size are checked before reading, so that a FIFO or a device is never read."""
Z85_KEY_CHARS = 40  # a CURVE key (32 bytes) in Z85 text


def z85_key(text: bytes | str) -> bytes | None:
    """The 32 bytes of a CURVE key written as 40 Z85 characters, or None."""
    from zmq.utils.z85 import decode

    if len(text) != Z85_KEY_CHARS:
        return None
    try:
        return decode(text)
    except (ValueError, KeyError, struct.error):  # not ASCII / not Z85 / above 2**32
        return None


def read_key_file(path: str | os.PathLike[str], secret: bool = False) -> tuple[bytes, bytes | None]:
    """The Z85 public key of the ZPL certificate ``path``, and its secret key (None when
    the file has none; with ``secret``, that is an error).

    The file is opened once, without blocking, and read only if what was opened is a
    regular file of at most ``MAX_KEY_FILE_BYTES`` (a FIFO would block its reader, a
    device be read without end; checking the open file, not the path, leaves no moment
    for the path to be swapped). Its ``public-key`` and ``secret-key`` lines are read as
    ``zmq.auth.load_certificate`` reads them, and each key must be 40 Z85 characters
    (32 bytes); with ``secret``, the public key must be the secret key's.

    Raises:
        ValueError: why the file is not a usable key file, in one line that starts
            with the path.
    """
    from zmq import curve_public

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except FileNotFoundError:
        raise ValueError(f"{path} does not exist") from None
    except OSError as exc:
        raise ValueError(f"{path} cannot be read: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        kind = file_kind(st.st_mode)
        if kind is not None:
            raise ValueError(f"{path} is {kind}, not a regular file")
        text = os.read(fd, MAX_KEY_FILE_BYTES + 1)  # one byte more tells a larger file
    except OSError as exc:
        raise ValueError(f"{path} cannot be read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(text) > MAX_KEY_FILE_BYTES:
        raise ValueError(
            f"{path} is larger than {MAX_KEY_FILE_BYTES} bytes; a key file is a few hundred"
        )
    public, secret_key = _zpl_keys(text)
    if public is None:
        raise ValueError(f"{path} is not a key file: it has no public-key line")
    if z85_key(public) is None:
        raise ValueError(f"{path}: its public-key is not {Z85_KEY_CHARS} Z85 characters")
    if secret_key is not None and z85_key(secret_key) is None:
        raise ValueError(f"{path}: its secret-key is not {Z85_KEY_CHARS} Z85 characters")
    if secret:
        if secret_key is None:
            raise ValueError(
                f"{path} holds no secret key (a public .key file? the secret one ends in "
                ".key_secret)"
            )
        if curve_public(secret_key) != public:
            raise ValueError(f"{path}: its public-key is not the one of its secret-key")
    return public, secret_key


def _zpl_keys(text: bytes) -> tuple[bytes | None, bytes | None]:
    """The ``public-key`` and ``secret-key`` values of a ZPL certificate's text (the
    format ``zmq.auth`` writes): the first line starting with each name, its value
    after ``=`` stripped of blanks and quotes; comment lines skipped."""
    public: bytes | None = None
    secret: bytes | None = None
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith(b"#"):
            continue
        if public is None and line.startswith(b"public-key"):
            public = line.split(b"=", 1)[1].strip(b" \t'\"") if b"=" in line else b""
        elif secret is None and line.startswith(b"secret-key"):
            secret = line.split(b"=", 1)[1].strip(b" \t'\"") if b"=" in line else b""
    return public, secret
