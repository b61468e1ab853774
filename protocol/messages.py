"""The published message contract (DESIGN.md, "Published messages").

Every message is two ZeroMQ frames: a topic (``range/<sensor>`` or ``health/<sensor>``)
and a UTF-8 JSON object. The pydantic models are the schema robot code can rely on and
decode with; the daemon builds the JSON of ``range`` messages directly with
``encode_range`` (no per-frame validation on the hot path), and the tests check that
what it builds validates against the models.
"""

from __future__ import annotations

import json
import math
from typing import Annotated, ClassVar, Final, Literal

from pydantic import BaseModel, ConfigDict, Field

SCHEMA_VERSION = 1
RANGE_TOPIC = "range"
HEALTH_TOPIC = "health"

MIN_RANGE_M = 0.2  # blind zone, M05 p.10
MAX_RANGE_M = 8.0  # range at 90 % reflectivity, DS p.2
FOV_RAD = math.radians(2.0)  # 2 degrees, DS p.2
RADIATION_TYPE: Final = "infrared"  # 850 nm VCSEL, DS p.2

Status = Literal["ok", "degraded", "dropout"]
ReasonName = Literal["weak_signal", "saturated", "out_of_range", "outlier", "high_ambient", "stale"]
ZoneName = Literal["stable", "marginal", "unreliable"]
State = Literal["connected", "waiting", "reconnecting"]


class RangeMessage(BaseModel):
    """One parsed data frame, cleaned (topic ``range/<sensor>``). Distances in metres."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    kind: ClassVar[str] = RANGE_TOPIC

    v: Literal[1] = 1
    sensor: str
    seq: Annotated[int, Field(ge=0)]
    t_mono_ns: int
    t_unix_ns: int
    raw_m: float | None
    amp: Annotated[int, Field(ge=0, le=0xFFFF)]
    temp_c: float
    strength: float
    range_m: float | None
    sigma_m: float | None
    lux_est: float | None
    status: Status
    reasons: list[ReasonName]
    zone: ZoneName


class HealthMessage(BaseModel):
    """The daemon's state, about once a second and at every change (topic ``health/<sensor>``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    kind: ClassVar[str] = HEALTH_TOPIC

    v: Literal[1] = 1
    sensor: str
    t_unix_ns: int
    state: State
    frames: Annotated[int, Field(ge=0)]
    checksum_errors: Annotated[int, Field(ge=0)]
    bytes_discarded: Annotated[int, Field(ge=0)]
    fps: Annotated[float, Field(ge=0)]
    dropout_ratio: Annotated[float, Field(ge=0, le=1)]
    dropped_sends: Annotated[int, Field(ge=0)]
    uptime_s: Annotated[float, Field(ge=0)]
    last_error: str | None
    firmware: str | None
    min_range_m: float = MIN_RANGE_M
    max_range_m: float = MAX_RANGE_M
    fov_rad: float = FOV_RAD
    radiation_type: Literal["infrared"] = RADIATION_TYPE


Message = RangeMessage | HealthMessage


def topic(kind: str, sensor: str) -> bytes:
    """The ZeroMQ topic frame for ``kind`` ('range' or 'health') of ``sensor``."""
    return f"{kind}/{sensor}".encode()


def encode_range(
    sensor_json: bytes,
    seq: int,
    t_mono_ns: int,
    t_unix_ns: int,
    raw_m: float | None,
    amp: int,
    temp_c: float,
    strength: float,
    range_m: float | None,
    sigma_m: float | None,
    lux_est: float | None,
    status: str,
    reasons_json: bytes,
    zone: str,
) -> bytes:
    """JSON of a ``range`` message, built without validation (hot path).

    Args:
        sensor_json: the sensor name already JSON-encoded (with quotes), done once.
        reasons_json: the reasons list already JSON-encoded, e.g. ``b'["weak_signal"]'``.
        Everything else as in ``RangeMessage``; metres are rounded to 0.1 mm (sigma to
        0.01 mm), lux to 0.1.
    """
    if raw_m is not None and range_m is not None and sigma_m is not None and lux_est is not None:
        return _RANGE_JSON % (
            sensor_json,
            seq,
            t_mono_ns,
            t_unix_ns,
            raw_m,
            amp,
            temp_c,
            strength,
            range_m,
            sigma_m,
            lux_est,
            status.encode(),
            reasons_json,
            zone.encode(),
        )
    return _RANGE_JSON_NULLS % (
        sensor_json,
        seq,
        t_mono_ns,
        t_unix_ns,
        b"null" if raw_m is None else b"%.4f" % raw_m,
        amp,
        temp_c,
        strength,
        b"null" if range_m is None else b"%.4f" % range_m,
        b"null" if sigma_m is None else b"%.5f" % sigma_m,
        b"null" if lux_est is None else b"%.1f" % lux_est,
        status.encode(),
        reasons_json,
        zone.encode(),
    )


_RANGE_JSON = (
    b'{"v":1,"sensor":%b,"seq":%d,"t_mono_ns":%d,"t_unix_ns":%d,"raw_m":%.4f,"amp":%d,'
    b'"temp_c":%.3f,"strength":%.5f,"range_m":%.4f,"sigma_m":%.5f,"lux_est":%.1f,'
    b'"status":"%b","reasons":%b,"zone":"%b"}'
)
"""One bytes ``%`` format for a whole message with every value present (most frames).

Bytes and one template, rather than a str template with f-string floats and
``.encode()``: one formatting path instead of three, the same output byte for byte.
5.2 against 7.4 us a message hot, 39 against 59 us with the CPU caches evicted before
each message (docs/performance.md, "Session 5"). Fixed decimals (``1.9800``) parse to
the same float as ``round(x, 4)``; ``tests/test_messages.py`` checks that on random
values."""

_RANGE_JSON_NULLS = (
    b'{"v":1,"sensor":%b,"seq":%d,"t_mono_ns":%d,"t_unix_ns":%d,"raw_m":%b,"amp":%d,'
    b'"temp_c":%.3f,"strength":%.5f,"range_m":%b,"sigma_m":%b,"lux_est":%b,'
    b'"status":"%b","reasons":%b,"zone":"%b"}'
)
"""The same message with ``raw_m``, ``range_m``, ``sigma_m`` and ``lux_est`` passed in
already formatted, so that each can be ``null``."""


def encode_health(msg: HealthMessage) -> bytes:
    """JSON of a ``health`` message (about once a second, so validated)."""
    return msg.model_dump_json().encode()


def decode(topic_frame: bytes, payload: bytes) -> Message:
    """Decode a two-frame message into its typed model.

    Raises:
        ValueError: unknown topic kind, or a payload that breaks the schema
            (pydantic's ``ValidationError`` is a ``ValueError``).
    """
    kind = topic_frame.split(b"/", 1)[0]
    if kind == RANGE_TOPIC.encode():
        return RangeMessage.model_validate_json(payload)
    if kind == HEALTH_TOPIC.encode():
        return HealthMessage.model_validate_json(payload)
    raise ValueError(f"unknown topic {topic_frame!r}")


def reasons_json(reasons: tuple[str, ...]) -> bytes:
    """The JSON list of reason names (cached by the caller per distinct tuple)."""
    return json.dumps(list(reasons), separators=(",", ":")).encode()
