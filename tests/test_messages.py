"""The published message contract: the hot-path JSON validates against the schema."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from lunad.protocol.messages import (
    HealthMessage,
    RangeMessage,
    decode,
    encode_health,
    encode_range,
    reasons_json,
    topic,
)

CONTRACT_RANGE = {
    "v",
    "sensor",
    "seq",
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
}


def test_encode_range_is_valid_json_and_schema() -> None:
    payload = encode_range(
        json.dumps('front"x').encode(),
        7,
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
    msg = decode(topic("range", "front"), payload)
    assert isinstance(msg, RangeMessage)
    assert set(json.loads(payload)) == CONTRACT_RANGE
    assert msg.sensor == 'front"x' and msg.seq == 7 and msg.raw_m == 1.2346
    assert msg.range_m == 1.2301 and msg.sigma_m == 0.00456 and msg.lux_est == 1234.5


def test_encode_range_dropout_with_nulls() -> None:
    payload = encode_range(
        b'"s"',
        0,
        1,
        2,
        None,
        57,
        40.0,
        0.0285,
        None,
        None,
        None,
        "dropout",
        reasons_json(("weak_signal", "out_of_range")),
        "unreliable",
    )
    msg = RangeMessage.model_validate_json(payload)
    assert msg.range_m is None and msg.reasons == ["weak_signal", "out_of_range"]


def test_schema_rejects_contract_breaks() -> None:
    good = json.loads(
        encode_range(
            b'"s"',
            0,
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
    for key, bad in [("status", "fine"), ("reasons", ["sunny"]), ("amp", 70000), ("seq", -1)]:
        with pytest.raises(ValidationError):
            RangeMessage.model_validate({**good, key: bad})
    with pytest.raises(ValidationError):
        RangeMessage.model_validate({**good, "extra": 1})
    with pytest.raises(ValueError):
        decode(b"other/s", b"{}")


@pytest.mark.parametrize("number", ["NaN", "Infinity", "-Infinity", "1e400"])
@pytest.mark.parametrize(("kind", "key"), [("range", "range_m"), ("health", "fps")])
def test_decode_refuses_numbers_that_are_not_finite(kind: str, key: str, number: str) -> None:
    """``range_m`` is a float or null (DESIGN.md): a NaN or an infinity (``1e400`` is
    valid JSON and reads as one) handed to robot code as ``ok`` is worse than a message
    counted as bad."""
    if kind == "range":
        payload = encode_range(
            b'"s"', 0, 1, 2, 1.0, 500, 40.0, 0.25, 1.0, 0.01, 0.0, "ok", b"[]", "stable"
        )
    else:
        payload = encode_health(
            HealthMessage(
                sensor="s", t_unix_ns=1, state="connected", frames=3, checksum_errors=0,
                bytes_discarded=0, fps=100.0, dropout_ratio=0.0, dropped_sends=0,
                uptime_s=1.0, last_error=None, firmware=None,
            )
        )  # fmt: skip
    d = json.loads(payload)
    text = json.dumps({**d, key: 12345.5}).replace("12345.5", number)
    with pytest.raises(ValueError):
        decode(topic(kind, "s"), text.encode())


def test_health_round_trip_has_ros_range_facts() -> None:
    h = HealthMessage(
        sensor="s",
        t_unix_ns=1,
        state="waiting",
        frames=3,
        checksum_errors=0,
        bytes_discarded=0,
        fps=0.0,
        dropout_ratio=0.0,
        dropped_sends=0,
        uptime_s=1.0,
        last_error=None,
        firmware="3.0.9",
    )
    back = decode(topic("health", "s"), encode_health(h))
    assert back == h
    d = json.loads(encode_health(h))
    assert d["min_range_m"] == 0.2 and d["max_range_m"] == 8.0
    assert d["radiation_type"] == "infrared" and 0.03 < d["fov_rad"] < 0.04


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
            b'"s"', 1, 2, 3, raw, 100, temp_c, strength, rng, sigma, lux, "ok", b"[]", "stable"
        )
    )

    def want(x: float | None, n: int) -> float | None:
        return None if x is None else round(x, n)

    assert d["raw_m"] == want(raw, 4) and d["range_m"] == want(rng, 4)
    assert d["sigma_m"] == want(sigma, 5) and d["lux_est"] == want(lux, 1)
    assert d["temp_c"] == temp_c and d["strength"] == round(strength, 5)
