"""Where bytes come from: the ``Source`` interface (``base``) and its backends, one
module each (``serial``, ``i2c``, ``replay``), and the recording format that ``lunad
record`` writes and a replay reads (``recording``). Every source yields ``Chunk``s of
UART-format bytes. The backends are not imported here: ``open_source`` imports the one
a config names, and with it its driver (pyserial, smbus2), only when it is used.
"""

from lunad.daemon.sources.base import BACKENDS, Chunk, Source, open_source
from lunad.daemon.sources.recording import (
    FILE_SUFFIX,
    FORMAT_VERSION,
    FSYNC_INTERVAL_S,
    MAGIC,
    MAX_DESC_BYTES,
    MAX_RECORD_BYTES,
    READS_VERSIONS,
    Pacer,
    Recorder,
    RecordFormatError,
    RecordingBusyError,
    RecordingHeader,
    Replay,
    check_speed,
    paced,
)

__all__ = [
    "BACKENDS",
    "FILE_SUFFIX",
    "FORMAT_VERSION",
    "FSYNC_INTERVAL_S",
    "MAGIC",
    "MAX_DESC_BYTES",
    "MAX_RECORD_BYTES",
    "READS_VERSIONS",
    "Chunk",
    "Pacer",
    "RecordFormatError",
    "Recorder",
    "RecordingBusyError",
    "RecordingHeader",
    "Replay",
    "Source",
    "check_speed",
    "open_source",
    "paced",
]
