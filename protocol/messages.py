"""The published message contract, schema v2 (docs/messages.md).

Every message is two ZeroMQ frames: a topic (``range/<sensor>/`` or ``health/<sensor>/``,
ending in ``/`` so that a subscription matches one sensor exactly) and a UTF-8 JSON
object. The pydantic models are the schema robot code can rely on and decode with; the
JSON Schemas shipped beside this module (``schema/range.v2.json``,
``schema/health.v2.json``) are generated from them (``json_schemas``). The daemon builds
the JSON of ``range`` messages directly with ``encode_range`` (no per-frame validation
on the hot path), and the tests check that what it builds validates against both.
"""

from __future__ import annotations

import json
import math
import secrets
from pathlib import Path
from typing import Annotated, Any, ClassVar, Final, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

SCHEMA_VERSION = 2
RANGE_TOPIC = "range"
HEALTH_TOPIC = "health"

MIN_RANGE_M = 0.2  # blind zone, M05 p.10 (docs/tfluna.md section 5)
MAX_RANGE_M = 8.0  # range at 90 % reflectivity, DS p.2 (docs/tfluna.md section 5)
FOV_RAD = math.radians(2.0)  # 2 degrees, DS p.2 (docs/tfluna.md section 5)
RADIATION_TYPE: Final = "infrared"  # 850 nm VCSEL, DS p.2 (docs/tfluna.md section 5)

U64_MAX = (1 << 64) - 1
I64_MAX = (1 << 63) - 1
U32_MAX = (1 << 32) - 1
MAX_MESSAGE_BYTES = 65536
"""Longest payload a subscriber takes, bytes (our bound). A range message is about 400
bytes and a health message under 2 KiB; one much longer is not the daemon's, and
decoding a long bad one costs its length many times over (pydantic copies the input
into each error it reports: 1.3 GB for a 7.6 MiB one)."""

Status = Literal["ok", "degraded", "dropout"]
ReasonName = Literal[
    "weak_signal",
    "saturated",
    "too_close",
    "too_far",
    "no_distance",
    "outlier",
    "high_ambient",
    "unreliable_zone",
    "stale",
]
ZoneName = Literal["stable", "marginal", "unreliable"]
State = Literal["connected", "waiting", "reconnecting", "stopped"]
NoiseModel = Literal["default", "configured"]
RunId = Annotated[str, Field(pattern=r"^[0-9a-f]{16}$")]
SENSOR_NAME_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
"""A sensor name: part of the topics range/NAME/ and health/NAME/, so no '/'."""
SensorName = Annotated[str, Field(pattern=SENSOR_NAME_PATTERN)]
U64 = Annotated[int, Field(ge=0, le=U64_MAX)]
I64 = Annotated[int, Field(ge=-I64_MAX - 1, le=I64_MAX)]


_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)
"""Types as the JSON Schema has them: ``"5"`` is not an integer, nor ``1`` a boolean
(an integer is a float); the Python client refuses what another language's consumer
checking the shipped schema refuses."""


class RangeMessage(BaseModel):
    """One cleaned reading (topic ``range/<sensor>/``). Distances in metres, times in
    nanoseconds; docs/messages.md says what each field means to a robot.

    Besides each field's type, the contract's rules between fields hold: ``range_m``
    and ``sigma_m`` are null exactly when ``status`` is ``dropout``, and an ``ok``
    message has no reasons and is not in the ``unreliable`` zone.
    """

    model_config = _STRICT
    kind: ClassVar[str] = RANGE_TOPIC

    v: Literal[2] = 2
    sensor: SensorName
    run: RunId
    seq: U64
    frames: Annotated[int, Field(ge=1, le=U64_MAX)] = 1
    t_mono_ns: I64
    t_unix_ns: I64
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
    cached: bool = False
    age_ms: Annotated[int, Field(ge=0, le=U32_MAX)] = 0

    @model_validator(mode="after")
    def _status_rules(self) -> RangeMessage:
        dropout = self.status == "dropout"
        if dropout != (self.range_m is None) or dropout != (self.sigma_m is None):
            raise ValueError(
                "range_m and sigma_m are null exactly when status is dropout, got "
                f"status {self.status!r}, range_m {self.range_m}, sigma_m {self.sigma_m}"
            )
        if self.status == "ok" and (self.reasons or self.zone == "unreliable"):
            raise ValueError(
                f"an ok message has no reasons and is not unreliable, got reasons "
                f"{self.reasons} in zone {self.zone!r}"
            )
        return self


class HealthMessage(BaseModel):
    """The daemon's state, about once a second, at every change and a last one when it
    stops (topic ``health/<sensor>/``)."""

    model_config = _STRICT
    kind: ClassVar[str] = HEALTH_TOPIC

    v: Literal[2] = 2
    sensor: SensorName
    run: RunId
    t_unix_ns: I64
    t_mono_ns: I64
    state: State
    frames: U64
    checksum_errors: U64
    bytes_discarded: U64
    fps: Annotated[float, Field(ge=0)]
    frame_rate_hz: Annotated[float, Field(ge=0)]
    dropout_ratio: Annotated[float, Field(ge=0, le=1)]
    dropped_sends: U64
    uptime_s: Annotated[float, Field(ge=0)]
    last_error: str | None
    firmware: str | None
    serial: str | None = None
    min_range_m: float = MIN_RANGE_M
    max_range_m: float = MAX_RANGE_M
    fov_rad: float = FOV_RAD
    radiation_type: Literal["infrared"] = RADIATION_TYPE
    noise_model: NoiseModel = "default"


Message = RangeMessage | HealthMessage


def json_schemas() -> dict[str, dict[str, Any]]:
    """The JSON Schema of each message kind, keyed by its file name in ``schema/``
    (``python -m lunad.protocol.messages`` writes them there)."""
    out = {}
    for model in (RangeMessage, HealthMessage):
        doc = model.model_json_schema()
        doc["required"] = sorted(doc["properties"])  # every field is always sent
        doc["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        doc["$id"] = f"https://lunad.invalid/schema/{model.kind}.v{SCHEMA_VERSION}.json"
        if model is RangeMessage:
            doc["allOf"] = _RANGE_STATUS_RULES
        out[f"{model.kind}.v{SCHEMA_VERSION}.json"] = doc
    return out


_NULL, _NUMBER = {"type": "null"}, {"type": "number"}
_RANGE_STATUS_RULES = [
    {
        "if": {"properties": {"status": {"const": "dropout"}}},
        "then": {"properties": {"range_m": _NULL, "sigma_m": _NULL}},
        "else": {"properties": {"range_m": _NUMBER, "sigma_m": _NUMBER}},
    },
    {
        "if": {"properties": {"status": {"const": "ok"}}},
        "then": {
            "properties": {"reasons": {"maxItems": 0}, "zone": {"not": {"const": "unreliable"}}}
        },
    },
]
"""``RangeMessage``'s rules between fields, in JSON Schema (its ``_status_rules``)."""


def topic(kind: str, sensor: str) -> bytes:
    """The ZeroMQ topic frame for ``kind`` ('range' or 'health') of ``sensor``: it ends
    in ``/``, so a subscription to it matches this sensor only."""
    return f"{kind}/{sensor}/".encode()


def new_run_id() -> str:
    """A fresh run identity: 16 hex digits from the OS's random source."""
    return secrets.token_hex(8)


def range_ident(sensor: str, run: str) -> bytes:
    """The constant part of a sensor's ``range`` messages, JSON-encoded once:
    ``"sensor":...,"run":...`` (for ``encode_range``)."""
    return b'"sensor":%b,"run":%b' % (json.dumps(sensor).encode(), json.dumps(run).encode())


def encode_range(
    ident: bytes,
    seq: int,
    frames: int,
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
    """JSON of a live ``range`` message, built without validation (hot path).

    Args:
        ident: ``range_ident(sensor, run)``, done once.
        reasons_json: the reasons list already JSON-encoded, e.g. ``b'["weak_signal"]'``.
        Everything else as in ``RangeMessage``; metres are rounded to 0.1 mm (sigma to
        0.01 mm), lux to 0.1. ``cached`` is false and ``age_ms`` 0: a live message.
    """
    if raw_m is not None and range_m is not None and sigma_m is not None and lux_est is not None:
        return _RANGE_JSON % (
            ident,
            seq,
            frames,
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
        ident,
        seq,
        frames,
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
    b'{"v":2,%b,"seq":%d,"frames":%d,"t_mono_ns":%d,"t_unix_ns":%d,"raw_m":%.4f,"amp":%d,'
    b'"temp_c":%.3f,"strength":%.5f,"range_m":%.4f,"sigma_m":%.5f,"lux_est":%.1f,'
    b'"status":"%b","reasons":%b,"zone":"%b","cached":false,"age_ms":0}'
)
"""One bytes ``%`` format for a whole message with every value present (most frames).

Bytes and one template, rather than a str template with f-string floats and
``.encode()``: one formatting path instead of three, the same output byte for byte
(docs/performance.md measures it). Fixed decimals (``1.9800``) parse to the same float
as ``round(x, 4)``; ``tests/test_messages.py`` checks that on random values."""

_RANGE_JSON_NULLS = (
    b'{"v":2,%b,"seq":%d,"frames":%d,"t_mono_ns":%d,"t_unix_ns":%d,"raw_m":%b,"amp":%d,'
    b'"temp_c":%.3f,"strength":%.5f,"range_m":%b,"sigma_m":%b,"lux_est":%b,'
    b'"status":"%b","reasons":%b,"zone":"%b","cached":false,"age_ms":0}'
)
"""The same message with ``raw_m``, ``range_m``, ``sigma_m`` and ``lux_est`` passed in
already formatted, so that each can be ``null``."""


def as_cached(kind: str, payload: bytes, age_ms: int, stale_after_ms: int) -> bytes:
    """The last-value cache's copy of a message for a subscriber that just connected.

    A ``range`` message gets ``cached`` true and its ``age_ms``; once older than
    ``stale_after_ms`` it becomes a ``dropout`` with the reason ``stale`` and a null
    range (docs/messages.md, "Cached and stale messages"). A ``health`` message is
    sent as it was. Rare (once per topic per connecting subscriber), so validated.
    """
    if kind != RANGE_TOPIC:
        return payload
    msg = RangeMessage.model_validate_json(payload)
    age = max(0, min(U32_MAX, age_ms))
    msg = msg.model_copy(update={"cached": True, "age_ms": age})
    if age > stale_after_ms:
        msg = as_stale(msg)
    return msg.model_dump_json().encode()


def as_stale(msg: RangeMessage) -> RangeMessage:
    """``msg`` as a cached message too old to act on is sent: a ``dropout`` with the
    reason ``stale``, no range and the ``unreliable`` zone (docs/messages.md, "Cached
    and stale messages")."""
    reasons = [r for r in msg.reasons if r != "stale"] + ["stale"]
    return msg.model_copy(
        update={
            "status": "dropout",
            "range_m": None,
            "sigma_m": None,
            "reasons": reasons,
            "zone": "unreliable",
        }
    )


def encode_health(msg: HealthMessage) -> bytes:
    """JSON of a ``health`` message (about once a second, so validated)."""
    return msg.model_dump_json().encode()


def decode(topic_frame: bytes, payload: bytes) -> Message:
    """Decode a two-frame message into its typed model.

    Raises:
        ValueError: unknown topic kind, a payload over ``MAX_MESSAGE_BYTES``, one that
            breaks the schema (pydantic's ``ValidationError`` is a ``ValueError``), or
            one whose ``sensor`` is not the topic's.
    """
    kind, _, rest = topic_frame.partition(b"/")  # v2 topics end in "/", v1 ones did not
    if kind == RANGE_TOPIC.encode():
        model: type[Message] = RangeMessage
    elif kind == HEALTH_TOPIC.encode():
        model = HealthMessage
    else:
        raise ValueError(f"unknown topic {topic_frame!r}")
    if len(payload) > MAX_MESSAGE_BYTES:
        raise ValueError(f"a {len(payload)}-byte payload: over {MAX_MESSAGE_BYTES} bytes")
    msg = model.model_validate_json(payload)
    if rest and rest.rstrip(b"/") != msg.sensor.encode():
        raise ValueError(f"a message of sensor {msg.sensor!r} on topic {topic_frame!r}")
    return msg


def reasons_json(reasons: tuple[str, ...]) -> bytes:
    """The JSON list of reason names (cached by the caller per distinct tuple)."""
    return json.dumps(list(reasons), separators=(",", ":")).encode()


def _write_schemas() -> None:
    """Write ``json_schemas()`` into this package's ``schema/`` folder."""
    folder = Path(__file__).with_name("schema")
    folder.mkdir(exist_ok=True)
    for name, doc in json_schemas().items():
        (folder / name).write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    _write_schemas()
