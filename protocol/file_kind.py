"""What kind of file a path names, for the errors that refuse anything but a regular
file: a config, a recording or a CURVE key file that is a FIFO blocks its reader
without a word, and a device is read without end.

It lives in ``lunad.protocol`` because the subscriber client reads key files too, and
the client library is used by robot code without the daemon; the daemon imports it
from here."""

from __future__ import annotations

import stat

_FILE_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str | None:
    """None for a regular file (``st_mode``), else what it is ("a FIFO")."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _FILE_KINDS if test(mode)), "not a file")
