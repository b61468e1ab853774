"""Daemon configuration: a TOML file validated by pydantic, command-line flags on top.

Every mistake becomes one ``ConfigError`` whose message names the field (as written
in the TOML file, and the flag that sets it) and what is allowed, so ``lunad serve``
can print it and exit with code 78 before opening anything. An example file with
every key commented is ``systemd/lunad.toml.example``.

The files the config names for ZeroMQ CURVE ([publish] ``curve_secret_key`` and
``curve_clients``) are checked here too, so that a wrong path or a key file that is not
one stops the start with the field's name rather than at the bind. Key files are read
by ``lunad.protocol.curve_keys.read_key_file``, the one reader of them, shared with the
publisher, ``lunad keys`` and the subscriber client.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import math
import os
import re
import stat
import tomllib
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, get_args, get_origin

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from lunad.daemon.errors import ConfigError
from lunad.filters import FilterConfig
from lunad.protocol.commands import (
    BAUD_RATES,
    FRAME_RATES_HZ,
    I2C_ADDRESS_MAX,
    I2C_ADDRESS_MIN,
)
from lunad.protocol.curve_keys import read_key_file
from lunad.protocol.file_kind import file_kind
from lunad.protocol.frame import OutputFormat
from lunad.protocol.messages import SensorName

DEFAULT_ENDPOINT = "tcp://127.0.0.1:7781"
DEFAULT_DEVICE = "/dev/serial0"
PORT_MAX = 65535  # TCP ports are 16 bits; libzmq takes a larger number modulo 2**16
_TCP_RE = re.compile(r"tcp://(?P<host>\[[^\]\s]*\]|[^\s\[\]]+):(?P<port>[^\s:\]]*)")
_TCP_HOST_RE = re.compile(r"\*|[A-Za-z0-9_.-]+")
"""A TCP host to bind: ``*`` (every interface), an IPv4 address, an interface or host
name. An IPv6 address is written in brackets and checked by ``ipaddress``."""
_IPC_RE = re.compile(r"ipc://\S+")
ENDPOINT_FORMS = "tcp://HOST:PORT, tcp://[IPV6]:PORT or ipc:///PATH"

MAX_CONFIG_BYTES = 1 << 20
"""Longest config file read, bytes (1 MiB). The example with every key and its comment
is about 5 kB; a larger file is not a config, and an endless one (``/dev/zero``) would
grow memory without bound while it was read."""

HEALTH_INTERVAL_MIN_S = 0.05
"""Shortest ``health_interval_s``: 20 messages a second, more than any monitor reads.
Each health message is a wake-up, an encode and a send of the loop that also reads the
sensor: at 1e-9 s it sends some 21,000 a second and reads no frames at all."""
HEALTH_INTERVAL_MAX_S = 60.0  # the contract says "about once a second"; a minute at most
PUBLISH_HZ_MIN = 0.01
"""Lowest ``publish_hz``: one message per 100 s. A lower rate has no use (a reading that
old is stale), and the period 1/rate overflows the loop's nanosecond arithmetic at 1e-300."""
PUBLISH_HZ_MAX = 250.0  # the sensor's fastest frame rate: faster would fold nothing
MAX_CLIENT_KEYS = 256
"""Most entries ``curve_clients`` may hold (a robot fleet has a few keys): the publisher
re-reads the directory while peers connect, so its size bounds that work. A directory
holding more is refused at start, and admits nobody if it grows past this later."""
MAX_SHOWN_CHARS = 80
"""A wrong value is quoted in an error up to this many characters: the line stays one
line whatever a file holds (a 1 MiB string, an integer of 5000 digits)."""

FLAGS: dict[str, str] = {
    "sensor.name": "--name",
    "sensor.frame_rate_hz": "--rate",
    "sensor.configure": "--no-configure",
    "sensor.output_format": "--output-format",
    "source.kind": "--device/--bus/--replay",
    "source.device": "--device",
    "source.baud": "--baud",
    "source.bus": "--bus",
    "source.address": "--address",
    "source.path": "--replay",
    "source.speed": "--speed",
    "source.record": "--record",
    "publish.endpoint": "--publish",
    "publish.publish_hz": "--publish-hz",
    "publish.curve_secret_key": "--curve-secret-key",
    "publish.curve_clients": "--curve-clients",
    "log_level": "--log-level",
}
"""Which command-line flag overrides which config field (for error messages)."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    _table: ClassVar[str] = ""
    """The section's table in the file (``sensor``), for the dotted names of its fields."""

    @field_validator("*", mode="before")
    @classmethod
    def _typed_as_toml(cls, v: Any, info: ValidationInfo) -> Any:
        """TOML has numbers and booleans of its own, and pydantic would convert what is
        not one: ``true`` to 1 (1 Hz, 1 message), and in a file the string ``"250"`` to
        250 or ``"off"`` to False, where another key's ``"4.5"`` is refused. Strings
        are taken for numbers and booleans only from command-line flags (``flags`` in
        the validation context: their dotted names), which are strings."""
        if info.field_name is None:
            return v
        annotation = cls.model_fields[info.field_name].annotation
        if isinstance(v, bool) and _is_kind(annotation, (int, float)):
            raise ValueError("must be a number, not true or false")
        if isinstance(v, str):
            flags = info.context.get("flags", ()) if info.context else ()
            if f"{cls._table}.{info.field_name}" not in flags:
                if _is_kind(annotation, (int, float)):
                    raise ValueError("must be a number, not a string: write it without quotes")
                if _is_kind(annotation, (bool,)):
                    raise ValueError("must be true or false, not a string: no quotes")
        return v


def _is_kind(annotation: Any, kinds: tuple[type, ...]) -> bool:
    """True for one of ``kinds`` (``int``, ``float``, ``bool``), and those made optional
    or ``Annotated``."""
    if annotation in kinds:
        return True
    return any(
        _is_kind(a, kinds)
        for a in get_args(annotation)[: 1 if get_origin(annotation) is Annotated else None]
    )


class SensorSection(_Section):
    """[sensor]: what this sensor is called and how to set it up at start."""

    _table: ClassVar[str] = "sensor"

    name: SensorName = "tfluna"
    frame_rate_hz: int = 100
    configure: bool = True
    output_format: Literal["cm", "mm"] = "cm"
    """The distance unit of the UART frames: start-up sets it (command 0x05) and the
    parser reads frames in it. ``mm`` gives the same distances in millimetres (set
    [filter] ``resolution_m`` to the step the sensor then shows). A replay reads its
    recording in it, so give a replay the live run's. Over I2C the distance registers
    are centimetres whatever this says, so I2C takes ``cm`` only."""

    @property
    def frame_format(self) -> OutputFormat:
        """``output_format`` as the protocol's value, for the parser and the command."""
        return OutputFormat.MM if self.output_format == "mm" else OutputFormat.CM

    @field_validator("frame_rate_hz")
    @classmethod
    def _rate(cls, v: int) -> int:
        if v == 0 or v not in FRAME_RATES_HZ:
            raise ValueError("must be 500/n Hz for an integer n: 250, 166, 125, 100, ..., 1")
        return v


def _serial_url_handler_missing(scheme: str) -> str | None:
    """Why ``serial.serial_for_url`` cannot open a URL with ``scheme``, or None when it
    can: it imports ``protocol_<scheme>`` from each of ``serial.protocol_handler_packages``,
    and so does this (a handler whose own dependency is missing, such as cp2110's
    ``hid``, cannot open either)."""
    import importlib

    import serial

    why = "pyserial has no handler for it"
    for package in serial.protocol_handler_packages:
        try:
            importlib.import_module(f".protocol_{scheme}", package)
        except ModuleNotFoundError as exc:
            if exc.name not in (f"{package}.protocol_{scheme}", package):
                why = f"its handler needs the module {exc.name!r}, which is not installed"
        except ImportError as exc:
            why = f"its handler cannot be imported ({exc})"
        else:
            return None
    return why


def _serial_url_problem(url: str) -> str | None:
    """Why pyserial cannot open ``url`` whatever is at its other end, or None: its host,
    port or options do not parse. Opening parses them first (the handler's
    ``from_url``), so such a URL fails every retry, every 2 s for ever. A ``spy://``
    URL's own URL is checked too; ``hwgrep://`` is not, as what it matches depends on
    what is plugged in."""
    import serial

    scheme = url.split("://", 1)[0].lower()
    if scheme == "hwgrep":
        return None
    try:
        port = serial.serial_for_url(url, do_not_open=True)
        inner = port.from_url(url) if hasattr(port, "from_url") else None
    except (serial.SerialException, ValueError) as exc:
        return f"the URL does not parse: {exc}"
    except (TypeError, KeyError):  # pyserial's own faults on a missing port or option
        return (
            f"the URL does not parse: expected {scheme}://HOST:PORT (a port 0-65535) and"
            " only the options pyserial's handler knows"
        )
    if scheme == "spy" and isinstance(inner, str) and "://" in inner:
        return _serial_url_problem(inner)
    return None


SPEED_MIN = 0.01
"""The slowest replay, times real time: a frame of a 250 Hz recording every 0.4 s. At
1e-9 (a typo) a replay sends nothing for years and only says its sensor is silent."""
SPEED_MAX = 1000.0
"""The fastest paced replay, times real time; ``max`` is as fast as it can."""


class SourceSection(_Section):
    """[source]: where the bytes come from.

    ``kind`` picks the backend: ``serial`` reads ``device`` at ``baud``; ``i2c`` reads
    ``bus`` (a number for /dev/i2c-N, or ``sim`` for the simulated bus) at ``address``;
    ``replay`` plays the recording at ``path`` at ``speed`` x real time (``max``, stored
    as None: as fast as possible). ``record`` names a file that gets every byte read,
    with its read time (``lunad serve --record``; see ``lunad.daemon.sources.recording``).
    ``rate_hz`` is [sensor] ``frame_rate_hz``, copied here by ``load_config`` for
    backends that pace themselves (I2C); it is not a key of its own.
    """

    _table: ClassVar[str] = "source"

    kind: Literal["serial", "i2c", "replay"] = "serial"
    device: Annotated[str, Field(min_length=1)] = DEFAULT_DEVICE
    baud: int = 115200
    bus: Annotated[str, Field(pattern=r"^(\d+|sim)$")] = "1"
    address: int = 0x10
    path: Annotated[str, Field(min_length=1)] | None = None
    speed: float | None = 1.0
    record: Annotated[str, Field(min_length=1)] | None = None
    rate_hz: int = 100

    @field_validator("address", mode="before")
    @classmethod
    def _address(cls, v: Any) -> Any:
        if isinstance(v, str):
            try:
                return int(v, 0)
            except ValueError:
                raise ValueError("must be an I2C address like 0x10") from None
        return v

    @field_validator("address")
    @classmethod
    def _address_range(cls, v: int) -> int:
        if not I2C_ADDRESS_MIN <= v <= I2C_ADDRESS_MAX:  # said in hex, as addresses are
            raise ValueError(
                f"must be an I2C address from {I2C_ADDRESS_MIN:#04x} to {I2C_ADDRESS_MAX:#04x}"
                f" (M05 p.13), got {v:#04x}"
            )
        return v

    @field_validator("speed", mode="before")
    @classmethod
    def _speed_max(cls, v: Any) -> Any:
        return None if v == "max" else v

    @field_validator("speed")
    @classmethod
    def _speed(cls, v: float | None) -> float | None:
        if v is not None and not SPEED_MIN <= v <= SPEED_MAX:
            raise ValueError(f"must be a factor from {SPEED_MIN:g} to {SPEED_MAX:g}, or max")
        return v

    @property
    def description(self) -> str:
        """The source in the words the log, health and a recording's header use:
        ``serial /dev/ttyAMA0``, ``i2c bus 1 address 0x10``, ``replay field.lunarec``."""
        if self.kind == "serial":
            return f"serial {self.device}"
        if self.kind == "i2c":
            return f"i2c bus {self.bus} address {self.address:#04x}"
        return f"replay {self.path}"

    @property
    def timed_by_its_frames(self) -> bool:
        """Whether the frame clock times frames by the rate they come at (a serial
        sensor, and a replay, whose recorded read times are the live run's), not the
        rate asked for (an I2C sensor, which the source triggers at that rate)."""
        return self.kind != "i2c"

    @model_validator(mode="after")
    def _replay_needs_path(self) -> SourceSection:
        if self.kind == "replay" and not self.path:
            raise ValueError("replay needs path (--replay FILE)")
        if (
            self.kind == "replay"
            and self.path
            and self.record
            and _same_path(self.path, self.record)
        ):
            raise ValueError(
                f"record (--record) is the recording being replayed, {self.path}: "
                "it would replay its own output without end"
            )
        return self

    @field_validator("device")
    @classmethod
    def _device(cls, v: str) -> str:
        """A path, or a URL pyserial knows (``serial_for_url``): an unknown scheme can
        never open, and would be retried every 2 s for ever."""
        if "://" not in v:
            return v
        scheme = v.split("://", 1)[0].lower()  # as serial_for_url splits it
        if not scheme.isidentifier():
            why = "a device path cannot contain '://'"
        elif (missing := _serial_url_handler_missing(scheme)) is not None:
            why = f"URL scheme {scheme!r}: {missing}"
        elif (problem := _serial_url_problem(v)) is not None:
            why = problem
        else:
            return v
        raise ValueError(
            f"{why}; give a device path such as /dev/serial0, or a pyserial URL such "
            "as socket://HOST:PORT, rfc2217://HOST:PORT or spy:///dev/ttyAMA0"
        )

    @field_validator("baud")
    @classmethod
    def _baud(cls, v: int) -> int:
        if v not in BAUD_RATES:
            raise ValueError(f"must be one of {', '.join(map(str, BAUD_RATES))}")
        return v


@dataclasses.dataclass(frozen=True)
class CurveFiles:
    """Where a CURVE publisher's keys are: the server's secret key file (ZPL, as
    ``zmq.auth.create_certificates`` and ``lunad keys server`` write it) and the
    directory of the client public keys (``*.key``) it admits."""

    secret_key: Path
    clients: Path


class PublishSection(_Section):
    """[publish]: the ZeroMQ PUB socket.

    ``curve_secret_key`` and ``curve_clients`` (both or neither, tcp:// only) make the
    socket a CURVE server: the stream is encrypted, and only clients whose public key is
    in ``curve_clients`` are admitted (docs/security.md).
    """

    _table: ClassVar[str] = "publish"

    endpoint: str = DEFAULT_ENDPOINT
    health_interval_s: float = 1.0
    sndhwm: Annotated[int, Field(ge=1, le=1_000_000)] = 1000
    publish_hz: float | None = None
    curve_secret_key: Annotated[str, Field(min_length=1)] | None = None
    curve_clients: Annotated[str, Field(min_length=1)] | None = None

    @property
    def curve(self) -> CurveFiles | None:
        """The CURVE key files, or None when the socket is not a CURVE server."""
        if self.curve_secret_key is None or self.curve_clients is None:
            return None
        return CurveFiles(Path(self.curve_secret_key), Path(self.curve_clients))

    @field_validator("curve_secret_key")
    @classmethod
    def _curve_secret_key(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                read_key_file(v, secret=True)
            except ValueError as exc:
                raise ValueError(
                    f"must be the server's secret key file (`lunad keys server DIR` writes "
                    f"DIR/server.key_secret): {exc}"
                ) from None
        return v

    @field_validator("curve_clients")
    @classmethod
    def _curve_clients(cls, v: str | None) -> str | None:
        if v is not None:
            problem = key_dir_problem(v)
            if problem is not None:
                raise ValueError(
                    f"must be the directory of the client public keys (*.key) to admit: {problem}"
                )
        return v

    @model_validator(mode="after")
    def _curve_pair(self) -> PublishSection:
        """Both CURVE settings or neither, and only on TCP: half a CURVE configuration
        would publish in clear text, or admit nobody, without saying so; an ipc socket
        is guarded by its file's permissions and CURVE there is a mistake."""
        secret, clients = self.curve_secret_key, self.curve_clients
        if (secret is None) != (clients is None):
            missing, given = (
                ("curve_clients", "curve_secret_key")
                if clients is None
                else ("curve_secret_key", "curve_clients")
            )
            raise ValueError(
                f"{missing} ({FLAGS['publish.' + missing]}) is not set but {given} "
                f"({FLAGS['publish.' + given]}) is: CURVE needs both, the server's secret "
                "key and the directory of client keys it admits"
            )
        if secret is not None and not self.endpoint.startswith("tcp://"):
            raise ValueError(
                "curve_secret_key (--curve-secret-key) and curve_clients (--curve-clients) "
                f"work on tcp:// endpoints only, and endpoint (--publish) is {self.endpoint}: "
                "an ipc socket is guarded by its file's permissions (group lunad, "
                "docs/security.md); remove the CURVE settings or publish on tcp://"
            )
        return self

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, v: str) -> str:
        problem = endpoint_problem(v)
        if problem is not None:
            raise ValueError(problem)
        return v

    @field_validator("health_interval_s")
    @classmethod
    def _health_interval(cls, v: float) -> float:
        if not HEALTH_INTERVAL_MIN_S <= v <= HEALTH_INTERVAL_MAX_S:  # NaN fails too
            raise ValueError(
                f"must be {HEALTH_INTERVAL_MIN_S:g}..{HEALTH_INTERVAL_MAX_S:g} s: every health "
                "message wakes the loop that reads the sensor, and more often than "
                f"{1 / HEALTH_INTERVAL_MIN_S:g} a second it would send health instead of readings"
            )
        return v

    @field_validator("publish_hz")
    @classmethod
    def _publish_hz(cls, v: float | None) -> float | None:
        if v is not None and not PUBLISH_HZ_MIN <= v <= PUBLISH_HZ_MAX:  # NaN fails too
            raise ValueError(
                f"must be {PUBLISH_HZ_MIN:g}..{PUBLISH_HZ_MAX:g} messages a second: above "
                f"{PUBLISH_HZ_MAX:g} is faster than the sensor's fastest frame rate, below "
                f"{PUBLISH_HZ_MIN:g} a message is over {1 / PUBLISH_HZ_MIN:g} s apart"
            )
        return v


def endpoint_problem(endpoint: str) -> str | None:
    """What is wrong with ``endpoint`` as an address for the daemon to bind, or None.

    Taken: ``tcp://HOST:PORT`` with HOST ``*``, an IPv4 address, an interface or host
    name, or an IPv6 address in brackets (``tcp://[::1]:7781``, ``tcp://[::]:7781``),
    and ``ipc:///PATH``. Refused, although libzmq would bind them: a wildcard port
    (``tcp://HOST:*``) binds a port the kernel picks, which no subscriber can know;
    ``inproc://`` reaches only sockets inside the daemon's own process; a relative ipc
    path is the daemon's working directory's.
    """
    if endpoint.startswith("inproc://"):
        return (
            "inproc:// reaches only sockets inside the daemon's own process, so no "
            f"subscriber could connect; use {ENDPOINT_FORMS}"
        )
    if endpoint.startswith("ipc://"):
        if not _IPC_RE.fullmatch(endpoint):
            return f"must look like {ENDPOINT_FORMS}"
        if not endpoint.startswith("ipc:///"):
            return (
                "the ipc path is relative: the daemon would bind it in its own working "
                "directory (/ under systemd), which subscribers do not share; give it "
                "whole, as in ipc:///run/lunad/front.sock"
            )
        return None
    m = _TCP_RE.fullmatch(endpoint)
    if m is None:
        return f"must look like {ENDPOINT_FORMS}"
    host, port = m["host"], m["port"]
    if port == "*":
        return (
            "the TCP port is a wildcard (*): the kernel would pick one, which no subscriber "
            f"can know; give a port 1..{PORT_MAX}"
        )
    if not port.isdigit():
        return f"must look like {ENDPOINT_FORMS}"
    if host.startswith("["):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            return f"{host} is not an IPv6 address; brackets hold one, as in tcp://[::1]:7781"
    elif ":" in host:
        return f"an IPv6 address goes in brackets, as in tcp://[::1]:7781; got {host}"
    elif not _TCP_HOST_RE.fullmatch(host):
        return f"must look like {ENDPOINT_FORMS}"
    return tcp_port_problem(endpoint)


def non_loopback_host(endpoint: str) -> str | None:
    """The host of a ``tcp://`` endpoint that other machines may reach, or None.

    None for ipc and for a TCP host on loopback: 127.0.0.0/8 (also as
    ``[::ffff:127.0.0.1]``), ``[::1]`` and ``localhost``. Anything else (``*``,
    ``0.0.0.0``, ``[::]``, a LAN address, an interface or host name) can be reached from
    the network, as far as the daemon can tell.
    """
    m = _TCP_RE.fullmatch(endpoint)
    if m is None:
        return None
    host = m["host"]
    bare = host[1:-1] if host.startswith("[") else host
    if bare.lower() == "localhost":
        return None
    try:
        address = ipaddress.ip_address(bare)
    except ValueError:
        return host
    mapped = getattr(address, "ipv4_mapped", None)
    if address.is_loopback or (mapped is not None and mapped.is_loopback):
        return None
    return host


def key_dir_problem(path: str | os.PathLike[str]) -> str | None:
    """What makes ``path`` unusable as a directory of client keys, or None: it must be a
    directory that can be listed and holds at most ``MAX_CLIENT_KEYS`` entries."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return f"{path} does not exist"
    except OSError as exc:
        return f"{path} cannot be read: {exc.strerror or exc}"
    if not stat.S_ISDIR(mode):
        return f"{path} is {file_kind(mode) or 'a regular file'}, not a directory"
    try:
        with os.scandir(path) as entries:
            count = sum(1 for _ in zip(range(MAX_CLIENT_KEYS + 1), entries, strict=False))
    except OSError as exc:
        return f"{path} cannot be listed: {exc.strerror or exc}"
    if count > MAX_CLIENT_KEYS:
        return f"{path} holds more than {MAX_CLIENT_KEYS} entries; it is for a few client keys"
    return None


def is_ipv6_endpoint(endpoint: str) -> bool:
    """True for ``tcp://[IPV6]:PORT``: its socket needs ``zmq.IPV6`` set to bind or
    connect (libzmq refuses an IPv6 address with "No such device" otherwise)."""
    m = _TCP_RE.fullmatch(endpoint)
    if m is None or not m["host"].startswith("["):
        return False
    try:
        ipaddress.IPv6Address(m["host"][1:-1])
    except ValueError:
        return False
    return True


def tcp_port_problem(endpoint: str) -> str | None:
    """What is wrong with a ``tcp://`` endpoint's port, or None.

    libzmq takes a port above 65535 modulo 2**16, and 0 as "any", without complaint:
    a daemon would publish, or a subscriber wait, silently on some other port.
    """
    if endpoint.startswith("tcp://"):
        port = endpoint.rpartition(":")[2]
        if port.isdigit() and not 1 <= int(port) <= PORT_MAX:
            return f"the TCP port must be 1..{PORT_MAX}"
    return None


_KINDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


class FilterSection(_Section):
    """[filter]: overrides of ``lunad.filters.FilterConfig`` (same names and units)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    def sets(self, key: str) -> bool:
        """Whether the file sets ``key`` (a ``FilterConfig`` name), whatever its value:
        a sigma0 ``lunad calibrate`` measured may equal the default's 0.004 m."""
        return key in (self.model_extra or {})

    @property
    def sets_noise_model(self) -> bool:
        """Whether the file sets ``sigma0_m`` or ``k_m_per_lux`` (``lunad calibrate
        --write`` writes them): the noise model is then this sensor's."""
        return self.sets("sigma0_m") or self.sets("k_m_per_lux")

    def to_filter_config(self) -> FilterConfig:
        """The filter's own settings, checked against its field names and types."""
        known = {f.name: f for f in dataclasses.fields(FilterConfig)}
        values: dict[str, Any] = {}
        for key, value in (self.model_extra or {}).items():
            field = known.get(key)
            if field is None:
                raise ValueError(f"filter.{key}: unknown key; allowed: {', '.join(known)}")
            default = getattr(FilterConfig(), key)
            if isinstance(default, (bool, int)) or not isinstance(default, float):
                ok = type(value) is type(default)  # an int field takes no 2.7, no inf
            else:
                ok = isinstance(value, (int, float)) and not isinstance(value, bool)
                if ok and not _finite(value):
                    raise ValueError(f"filter.{key}: must be a finite number, got {_shown(value)}")
            if not ok:
                kind = _KINDS.get(type(default), f"a {type(default).__name__}")
                raise ValueError(f"filter.{key}: must be {kind}, got {_shown(value)}")
            values[key] = type(default)(value)
        try:
            return FilterConfig(**values)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"filter: {exc}") from exc


class Config(_Section):
    """The whole daemon configuration."""

    sensor: SensorSection = SensorSection()
    source: SourceSection = SourceSection()
    publish: PublishSection = PublishSection()
    filter: FilterSection = FilterSection()
    log_level: Literal["debug", "info", "warning", "error"] = "info"

    @model_validator(mode="after")
    def _i2c_in_centimetres(self) -> Config:
        if self.source.kind == "i2c" and self.sensor.output_format != "cm":
            raise ValueError(
                "sensor.output_format (--output-format): must be cm over I2C, whose distance"
                " registers are centimetres; got 'mm'"
            )
        return self


def load_config(
    path: Path | str | None,
    overrides: dict[str, Any] | None = None,
    *,
    settings_required: bool = True,
) -> Config:
    """Read ``path`` (or defaults), apply ``overrides`` and validate.

    Args:
        path: a TOML file, or None for the built-in defaults.
        overrides: dotted field name -> value, from command-line flags; None values
            are ignored.
        settings_required: refuse a file that sets nothing (no key in any table:
            empty, all comments, or only headers). It would mean the defaults, and on
            a reload another device and endpoint at once; a file an editor truncated
            looks like that. ``lunad calibrate --write`` may start a file from nothing.

    Raises:
        ConfigError: the file is missing, not TOML or (``settings_required``) sets
            nothing, or a field is wrong.
    """
    data: dict[str, Any] = {}
    origin = "defaults"
    if path is not None:
        origin = str(path)
        data = _parse_toml(_read_config_text(path), path)
        if settings_required and not _sets_anything(data):
            raise ConfigError(
                f"config file {path} (--config): sets nothing (empty, only comments or "
                "only table headers): a file an editor truncated? Leave --config out to "
                "run on the built-in defaults"
            )
    flags: set[str] = set()
    for dotted, value in (overrides or {}).items():
        if value is None:
            continue
        flags.add(dotted)
        node = data
        *parents, leaf = dotted.split(".")
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{part}: must be a table in {origin}")
            node = child
        node[leaf] = value
    source = data.get("source")
    if isinstance(source, dict) and "rate_hz" in source:
        raise ConfigError(
            f"invalid configuration ({origin}): source.rate_hz: unknown key; "
            "the frame rate is [sensor] frame_rate_hz (--rate)"
        )
    try:
        cfg = Config.model_validate(data, context={"flags": flags})
        cfg.filter.to_filter_config()
    except ValidationError as exc:
        raise ConfigError(_describe(exc, origin)) from None
    except ValueError as exc:
        raise ConfigError(f"{origin}: {exc}") from None
    except RecursionError:  # a value nested past the interpreter's limit, anywhere
        raise ConfigError(f"invalid configuration ({origin}): a value nests too deeply") from None
    rate = cfg.sensor.frame_rate_hz
    return cfg.model_copy(update={"source": cfg.source.model_copy(update={"rate_hz": rate})})


def _sets_anything(table: dict[str, Any]) -> bool:
    """Whether a parsed TOML table holds a key that is not itself a table, at any depth."""
    return any(not isinstance(v, dict) or _sets_anything(v) for v in table.values())


def _read_config_text(path: Path | str) -> str:
    """The text of the config file ``path``, read only if it is a regular file of at
    most ``MAX_CONFIG_BYTES``.

    A FIFO would block the daemon's start without a word, and a device such as
    ``/dev/zero`` would be read without end. The type is checked before opening, so
    that no device is opened at all (a tty's open can toggle its modem lines), and
    again on the open file, opened non-blocking, in case the path was replaced in
    between; the read stops one byte past the cap whatever the file's size says (a
    file in /proc says 0).

    Raises:
        ConfigError: missing, not a regular file, too large, unreadable or not UTF-8;
            the message names the file and ``--config``.
    """
    where = f"config file {path} (--config)"
    try:
        kind = file_kind(os.stat(path).st_mode)
        if kind is not None:
            raise ConfigError(f"{where} is {kind}, not a regular file")
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
        try:
            kind = file_kind(os.fstat(fd).st_mode)
            if kind is not None:
                raise ConfigError(f"{where} is {kind}, not a regular file")
            raw = _read_at_most(fd, MAX_CONFIG_BYTES + 1)
        finally:
            os.close(fd)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except OSError as exc:
        raise ConfigError(f"{where} cannot be read: {exc}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{where} is larger than {MAX_CONFIG_BYTES // 1024} KiB; a config is a few kB"
        )
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{where} cannot be read: {exc}") from None


def _read_at_most(fd: int, limit: int) -> bytes:
    """Up to ``limit`` bytes from ``fd``, fewer at end of file."""
    parts: list[bytes] = []
    left = limit
    while left > 0:
        part = os.read(fd, min(left, 1 << 16))
        if not part:
            break
        parts.append(part)
        left -= len(part)
    return b"".join(parts)


def _parse_toml(text: str, path: Path | str) -> dict[str, Any]:
    """``text`` parsed as TOML.

    Every failure of the parser is the file's fault and becomes a ``ConfigError``: a
    traceback exits 1, and systemd would restart the daemon into the same crash (78
    stops it). Besides ``TOMLDecodeError``, tomllib raises ``RecursionError`` on arrays
    or inline tables nested a few hundred deep (its parser recurses), and ``ValueError``
    on an integer of more than 4300 digits (Python's limit on converting them).

    Raises:
        ConfigError: naming the file and ``--config``.
    """
    where = f"config file {path} (--config)"
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where} is not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(
            f"{where} is not usable TOML: arrays or tables nested too deeply"
        ) from None
    except Exception as exc:  # any parser failure is the file's (see above)
        why = str(exc).partition("; use sys.set_int_max_str_digits")[0]  # not the user's knob
        raise ConfigError(f"{where} is not usable TOML: {why}") from None


def _shown(value: object) -> str:
    """``repr(value)`` cut to ``MAX_SHOWN_CHARS``, for an error message.

    An integer too long to print (over 4300 digits) is shown by its size: its repr
    raises ``ValueError``, which would replace the message being written.
    """
    try:
        text = repr(value)
    except ValueError:  # only an int's repr raises it
        size = f" of {len(hex(value)) - 2} hex digits" if isinstance(value, int) else ""
        return f"an integer{size}, too long to show"
    except RecursionError:
        return f"a {type(value).__name__} nested too deeply to show"
    if len(text) > MAX_SHOWN_CHARS:
        text = f"{text[: MAX_SHOWN_CHARS - 5]}... ({len(text)} characters)"
    return text


def _finite(value: float) -> bool:
    """``math.isfinite`` that takes an integer too large for a float as not finite."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def _same_path(a: str, b: str) -> bool:
    """True when ``a`` and ``b`` name one file: the same file on disk, or, where
    either does not exist yet, the same absolute path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def _describe(exc: ValidationError, origin: str) -> str:
    """One line per wrong field: ``source.baud (--baud): must be one of ...; got 12``."""
    lines = []
    for err in exc.errors():
        field = ".".join(str(p) for p in err["loc"])
        flag = FLAGS.get(field)
        where = f"{field} ({flag})" if flag else field
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        got = err.get("input")
        quiet = (
            err["type"] in ("extra_forbidden", "missing")
            or isinstance(got, dict)
            or ", got " in msg  # the check showed the value itself (an address in hex)
        )
        suffix = "" if quiet else f"; got {_shown(got)}"
        lines.append(f"{where}: {msg}{suffix}" if field else msg)  # a check across sections
        # names its fields itself
    return f"invalid configuration ({origin}): " + "; ".join(lines)
