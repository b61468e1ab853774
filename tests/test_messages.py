"""The published message contract (docs/messages.md): the hot-path JSON validates
against the models and against the JSON Schemas shipped in the package."""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

import jsonschema
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from lunad.protocol.messages import (
    HealthMessage,
    RangeMessage,
    as_cached,
    decode,
    encode_health,
    encode_range,
    json_schemas,
    new_run_id,
    range_ident,
    reasons_json,
    topic,
)

RUN = "0123456789abcdef"
IDENT = range_ident("front", RUN)
CONTRACT_RANGE = {
    "v",
    "sensor",
    "run",
    "seq",
    "frames",
    "t_mono_ns",
    "t_unix_ns",
    "raw_m",
    "amp",
    "temp_c",
    "strength",
    "range_m",
    "sigma_m",
    "lux_est",
    "status",
    "reasons",
    "zone",
    "cached",
    "age_ms",
}


def shipped_schema(kind: str) -> dict[str, Any]:
    text = resources.files("lunad.protocol").joinpath("schema", f"{kind}.v2.json").read_text()
    doc: dict[str, Any] = json.loads(text)
    return doc


def validate(kind: str, payload: bytes) -> None:
    """Validate against the shipped JSON Schema, as a consumer in any language would."""
    jsonschema.validate(json.loads(payload), shipped_schema(kind))


def health(**kw: Any) -> HealthMessage:
    base: dict[str, Any] = dict(
        sensor="s", run=RUN, t_unix_ns=1, t_mono_ns=2, state="connected", frames=3,
        checksum_errors=0, bytes_discarded=0, fps=100.0, frame_rate_hz=100.0,
        dropout_ratio=0.0, dropped_sends=0, uptime_s=1.0, last_error=None, firmware=None,
    )  # fmt: skip
    base.update(kw)
    return HealthMessage(**base)


def test_the_shipped_schemas_are_the_models_own() -> None:
    """protocol/schema/*.json is generated from the models (python -m
    lunad.protocol.messages); a model change without regenerating fails here."""
    for name, doc in json_schemas().items():
        kind = name.split(".")[0]
        assert shipped_schema(kind) == json.loads(json.dumps(doc)), name
        assert set(doc["required"]) == set(doc["properties"])


def test_topics_end_in_a_slash_so_that_prefixes_do_not_collide() -> None:
    assert topic("range", "front") == b"range/front/"
    assert not topic("range", "frontleft").startswith(topic("range", "front"))


def test_encode_range_is_valid_json_and_schema() -> None:
    payload = encode_range(
        range_ident('front"x', RUN),
        7,
        1,
        123,
        456,
        1.234567,
        1800,
        40.0,
        0.9,
        1.2301,
        0.00456,
        1234.5,
        "ok",
        reasons_json(()),
        "stable",
    )
    assert set(json.loads(payload)) == CONTRACT_RANGE
    assert json.loads(payload)["sensor"] == 'front"x'  # escaped, so still valid JSON
    with pytest.raises(ValidationError):  # but not a name the config allows
        decode(topic("range", "front"), payload)
    ok = encode_range(
        IDENT, 7, 4, 123, 456, 1.234567, 1800, 40.0, 0.9, 1.2301, 0.00456, 1234.5, "ok",
        reasons_json(()), "stable",
    )  # fmt: skip
    validate("range", ok)
    msg = RangeMessage.model_validate_json(ok)
    assert msg.sensor == "front" and msg.run == RUN and msg.seq == 7 and msg.frames == 4
    assert msg.raw_m == 1.2346 and msg.range_m == 1.2301 and msg.sigma_m == 0.00456
    assert msg.lux_est == 1234.5 and msg.cached is False and msg.age_ms == 0


def test_encode_range_dropout_with_nulls() -> None:
    payload = encode_range(
        IDENT, 0, 1, 1, 2, None, 57, 40.0, 0.0285, None, None, None, "dropout",
        reasons_json(("weak_signal", "too_far")), "unreliable",
    )  # fmt: skip
    validate("range", payload)
    msg = RangeMessage.model_validate_json(payload)
    assert msg.range_m is None and msg.reasons == ["weak_signal", "too_far"]


def test_schema_rejects_contract_breaks() -> None:
    good = json.loads(
        encode_range(
            IDENT,
            0,
            1,
            1,
            2,
            None,
            57,
            40.0,
            0.1,
            None,
            None,
            None,
            "dropout",
            b'["weak_signal"]',
            "unreliable",
        )
    )
    breaks = [
        ("status", "fine"),
        ("reasons", ["out_of_range"]),  # v1's, split into too_close / too_far in v2
        ("amp", 70000),
        ("seq", -1),
        ("frames", 0),
        ("run", "xyz"),
        ("v", 1),
        ("seq", 1 << 64),
    ]
    for key, bad in breaks:
        with pytest.raises(ValidationError):
            RangeMessage.model_validate({**good, key: bad})
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({**good, key: bad}, shipped_schema("range"))
    with pytest.raises(ValidationError):
        RangeMessage.model_validate({**good, "extra": 1})
    missing = dict(good)
    del missing["cached"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(missing, shipped_schema("range"))
    with pytest.raises(ValueError):
        decode(b"other/s/", b"{}")


def test_a_cached_range_says_so_and_turns_stale_with_age() -> None:
    live = encode_range(
        IDENT, 9, 1, 1, 2, 2.0, 1800, 40.0, 0.9, 2.0, 0.004, 100.0, "ok", b"[]", "stable"
    )
    fresh = as_cached("range", live, 120, 500)
    validate("range", fresh)
    msg = RangeMessage.model_validate_json(fresh)
    assert msg.cached and msg.age_ms == 120 and msg.status == "ok" and msg.range_m == 2.0
    old = RangeMessage.model_validate_json(as_cached("range", live, 6000, 500))
    assert old.cached and old.age_ms == 6000
    assert old.status == "dropout" and old.range_m is None and old.reasons == ["stale"]
    h = encode_health(health())
    assert as_cached("health", h, 6000, 500) == h


@pytest.mark.parametrize("number", ["NaN", "Infinity", "-Infinity", "1e400"])
@pytest.mark.parametrize(("kind", "key"), [("range", "range_m"), ("health", "fps")])
def test_decode_refuses_numbers_that_are_not_finite(kind: str, key: str, number: str) -> None:
    """``range_m`` is a float or null: a NaN or an infinity (``1e400`` is valid JSON and
    reads as one) handed to robot code as ``ok`` is worse than a message counted as bad."""
    if kind == "range":
        payload = encode_range(
            IDENT, 0, 1, 1, 2, 1.0, 500, 40.0, 0.25, 1.0, 0.01, 0.0, "ok", b"[]", "stable"
        )
    else:
        payload = encode_health(health())
    d = json.loads(payload)
    text = json.dumps({**d, key: 12345.5}).replace("12345.5", number)
    with pytest.raises(ValueError):
        decode(topic(kind, "s"), text.encode())


def test_health_round_trip_has_ros_range_facts() -> None:
    h = health(state="stopped", firmware="3.0.9", serial="U0900018010001", min_range_m=0.3)
    payload = encode_health(h)
    validate("health", payload)
    back = decode(topic("health", "s"), payload)
    assert back == h
    d = json.loads(payload)
    assert d["min_range_m"] == 0.3 and d["max_range_m"] == 8.0
    assert d["radiation_type"] == "infrared" and 0.03 < d["fov_rad"] < 0.04
    assert d["noise_model"] == "default"


def test_run_ids_are_fresh_and_fit_the_schema() -> None:
    a, b = new_run_id(), new_run_id()
    assert a != b and len(a) == 16 and int(a, 16) >= 0


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@given(
    raw=st.none() | finite,
    temp=st.integers(0, 65535),
    strength=st.floats(0, 100),
    rng=st.none() | finite,
    sigma=st.none() | st.floats(0, 10),
    lux=st.none() | st.floats(0, 2e5),
)
def test_encode_range_values_are_the_rounded_inputs(
    raw: float | None,
    temp: int,
    strength: float,
    rng: float | None,
    sigma: float | None,
    lux: float | None,
) -> None:
    """Fixed-decimal formatting parses to exactly ``round(x, n)``, the documented value."""
    temp_c = temp / 8 - 256  # the sensor's raw/8 - 256: exact in three decimals
    d = json.loads(
        encode_range(
            IDENT, 1, 1, 2, 3, raw, 100, temp_c, strength, rng, sigma, lux, "ok", b"[]", "stable"
        )
    )

    def want(x: float | None, n: int) -> float | None:
        return None if x is None else round(x, n)

    assert d["raw_m"] == want(raw, 4) and d["range_m"] == want(rng, 4)
    assert d["sigma_m"] == want(sigma, 5) and d["lux_est"] == want(lux, 1)
    assert d["temp_c"] == temp_c and d["strength"] == round(strength, 5)
