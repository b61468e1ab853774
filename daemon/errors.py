"""lunad's exceptions, one tree::

    LunadError
    +-- ConfigError        bad config file or flag: names the field; exit code 78
    +-- SourceOpenError    the device is absent, busy or refuses to open: retry
    +-- SourceLostError    the device went away while open (unplugged): reconnect
    +-- PublishError       the publish endpoint cannot be bound: exit code 69

Driver errors are translated where they happen, with ``raise ... from exc``.
"""

from __future__ import annotations

EX_CONFIG = 78  # sysexits.h: configuration error
EX_UNAVAILABLE = 69  # sysexits.h: a service the daemon needs is unavailable
EX_IOERR = 74  # sysexits.h: an error while doing I/O on a file
EXIT_USAGE = 2  # a bad option, or options that do not go together: argparse's own exit


class LunadError(Exception):
    """Base of every error lunad raises on purpose."""


class ConfigError(LunadError):
    """A config file or command-line value is wrong; the message names the field."""


class SourceOpenError(LunadError):
    """The source could not be opened (absent, busy, permission denied)."""


class SourceLostError(LunadError):
    """An open source stopped working (unplugged, I/O error)."""


class PublishError(LunadError):
    """The ZeroMQ endpoint cannot be bound (address in use, no permission)."""
