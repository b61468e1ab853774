"""Daemon configuration: a TOML file validated by pydantic, command-line flags on top.

Every mistake becomes one ``ConfigError`` whose message names the field (as written
in the TOML file, and the flag that sets it) and what is allowed, so ``lunad serve``
can print it and exit with code 78 before opening anything. An example file with
every key commented is ``systemd/lunad.toml.example``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin

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
from lunad.protocol.commands import BAUD_RATES, FRAME_RATES_HZ

DEFAULT_ENDPOINT = "tcp://127.0.0.1:7781"
DEFAULT_DEVICE = "/dev/serial0"
_ENDPOINT_RE = re.compile(r"^(tcp://[^\s]+:(\d+|\*)|ipc://[^\s]+|inproc://[^\s]+)$")
PORT_MAX = 65535  # TCP ports are 16 bits; libzmq takes a larger number modulo 2**16

FLAGS: dict[str, str] = {
    "sensor.name": "--name",
    "sensor.frame_rate_hz": "--rate",
    "sensor.configure": "--no-configure",
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
    "log_level": "--log-level",
}
"""Which command-line flag overrides which config field (for error messages)."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_for_number(cls, v: Any, info: ValidationInfo) -> Any:
        """TOML's ``true`` is not a number: pydantic would take it as 1 (1 Hz, 1 message)."""
        if isinstance(v, bool) and info.field_name is not None:
            if _is_number(cls.model_fields[info.field_name].annotation):
                raise ValueError("must be a number, not true or false")
        return v


def _is_number(annotation: Any) -> bool:
    """True for ``int``, ``float``, and those made optional or ``Annotated``."""
    if annotation in (int, float):
        return True
    return any(
        _is_number(a)
        for a in get_args(annotation)[: 1 if get_origin(annotation) is Annotated else None]
    )


class SensorSection(_Section):
    """[sensor]: what this sensor is called and how to set it up at start."""

    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")] = "tfluna"
    frame_rate_hz: int = 100
    configure: bool = True

    @field_validator("frame_rate_hz")
    @classmethod
    def _rate(cls, v: int) -> int:
        if v == 0 or v not in FRAME_RATES_HZ:
            raise ValueError("must be 500/n Hz for an integer n: 250, 166, 125, 100, ..., 1")
        return v


class SourceSection(_Section):
    """[source]: where the bytes come from.

    ``kind`` picks the backend: ``serial`` reads ``device`` at ``baud``; ``i2c`` reads
    ``bus`` (a number for /dev/i2c-N, or ``sim`` for the simulated bus) at ``address``;
    ``replay`` plays the recording at ``path`` at ``speed`` x real time (``max``, stored
    as None: as fast as possible). ``record`` names a file that gets every byte read,
    with its read time (``lunad serve --record``; see ``lunad.daemon.record``).
    ``rate_hz`` is [sensor] ``frame_rate_hz``, copied here by ``load_config`` for
    backends that pace themselves (I2C); it is not a key of its own.
    """

    kind: Literal["serial", "i2c", "replay"] = "serial"
    device: Annotated[str, Field(min_length=1)] = DEFAULT_DEVICE
    baud: int = 115200
    bus: Annotated[str, Field(pattern=r"^(\d+|sim)$")] = "1"
    address: Annotated[int, Field(ge=0x08, le=0x77)] = 0x10
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

    @field_validator("speed", mode="before")
    @classmethod
    def _speed_max(cls, v: Any) -> Any:
        return None if v == "max" else v

    @field_validator("speed")
    @classmethod
    def _speed(cls, v: float | None) -> float | None:
        if v is not None and not 0 < v <= 1000:
            raise ValueError("must be a factor in (0, 1000] or max")
        return v

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

    @field_validator("baud")
    @classmethod
    def _baud(cls, v: int) -> int:
        if v not in BAUD_RATES:
            raise ValueError(f"must be one of {', '.join(map(str, BAUD_RATES))}")
        return v


class PublishSection(_Section):
    """[publish]: the ZeroMQ PUB socket."""

    endpoint: str = DEFAULT_ENDPOINT
    health_interval_s: Annotated[float, Field(gt=0, le=60)] = 1.0
    sndhwm: Annotated[int, Field(ge=1, le=1_000_000)] = 1000
    publish_hz: Annotated[float, Field(ge=0.01, le=250)] | None = None

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, v: str) -> str:
        if not _ENDPOINT_RE.match(v):
            raise ValueError("must look like tcp://HOST:PORT or ipc:///PATH")
        problem = tcp_port_problem(v)
        if problem is not None:
            raise ValueError(problem)
        return v


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
                    raise ValueError(f"filter.{key}: must be a finite number, got {value!r}")
            if not ok:
                kind = _KINDS.get(type(default), f"a {type(default).__name__}")
                raise ValueError(f"filter.{key}: must be {kind}, got {value!r}")
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


def load_config(path: Path | str | None, overrides: dict[str, Any] | None = None) -> Config:
    """Read ``path`` (or defaults), apply ``overrides`` and validate.

    Args:
        path: a TOML file, or None for the built-in defaults.
        overrides: dotted field name -> value, from command-line flags; None values
            are ignored.

    Raises:
        ConfigError: the file is missing or not TOML, or a field is wrong.
    """
    data: dict[str, Any] = {}
    origin = "defaults"
    if path is not None:
        origin = str(path)
        try:
            data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"config file {path} does not exist") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"config file {path} cannot be read: {exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {path} is not valid TOML: {exc}") from None
    for dotted, value in (overrides or {}).items():
        if value is None:
            continue
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
        cfg = Config.model_validate(data)
        cfg.filter.to_filter_config()
    except ValidationError as exc:
        raise ConfigError(_describe(exc, origin)) from None
    except ValueError as exc:
        raise ConfigError(f"{origin}: {exc}") from None
    rate = cfg.sensor.frame_rate_hz
    return cfg.model_copy(update={"source": cfg.source.model_copy(update={"rate_hz": rate})})


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
        quiet = err["type"] in ("extra_forbidden", "missing") or isinstance(got, dict)
        suffix = "" if quiet else f"; got {got!r}"
        lines.append(f"{where}: {msg}{suffix}")
    return f"invalid configuration ({origin}): " + "; ".join(lines)
