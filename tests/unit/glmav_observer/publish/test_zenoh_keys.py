"""Keys and payload encoding of the Zenoh sink (no sessions)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from glmav_observer import __version__
from glmav_observer.publish.schema import validate
from glmav_observer.publish.zenoh_config import ZenohConfigError
from glmav_observer.publish.zenoh_keys import (
    alive_key,
    check_prefix,
    check_service_id,
    config_key,
    decode_payload,
    default_service_id,
    encode_json,
    encode_payload,
    payload_encoder,
    route,
    state_key,
)
from glmav_observer.publish.zenoh_sink import check_encoding
from glmav_observer.records import (
    HealthRecord,
    MeasurementRecord,
    Record,
    TruthRecord,
    VelocityRecord,
)


def _vel(config: str, sysid: int = 3) -> VelocityRecord:
    return VelocityRecord(sysid, config, 1.5, (1.0, 2.0, 3.0), (0.1, 0.2, 0.3), None, "ok", 4)


def test_routes_follow_the_design_key_table() -> None:
    nan3 = (float("nan"),) * 3
    health = HealthRecord(7, 0.1, 1, "full", nan3, nan3, {}, (), {}, {})
    cases = [
        (_vel("full"), ("velocity", "glmav/3/velocity/full", "full")),
        (_vel("c3"), ("velocity", "glmav/3/velocity/c3", "c3")),
        (_vel("active"), ("active", "glmav/3/velocity/active", "active")),
        (health, ("health", "glmav/7/health", "health")),
        (MeasurementRecord(2, 0.0, nan3, nan3, 0), ("measurement", "glmav/2/measurement", "measurement")),
        (TruthRecord(2, 0.0, nan3, nan3, nan3, None, 0), ("truth", "glmav/2/truth", "truth")),
    ]  # fmt: skip
    for record, want in cases:
        assert route("glmav", record) == want
    assert route("fleet/a", _vel("c1", 12))[1] == "fleet/a/12/velocity/c1"
    with pytest.raises(TypeError):
        route("glmav", object())  # type: ignore[arg-type]
    assert state_key("glmav") == "glmav/*/state"
    assert state_key("glmav", 4) == "glmav/4/state"
    assert config_key("glmav", "gs1") == "glmav/@config/gs1"
    assert alive_key("glmav", "gs1") == "glmav/@alive/gs1"
    assert alive_key("glmav", "gs1", 4) == "glmav/@alive/gs1/4"
    # the wildcard state queryable does not answer the verbatim @config/@alive chunks
    assert not zenoh.KeyExpr(state_key("glmav")).intersects(config_key("glmav", "gs1"))
    assert zenoh.KeyExpr(state_key("glmav")).intersects("glmav/4/state")


def test_payload_is_compact_json_of_to_dict_with_nan_as_null() -> None:
    record = VelocityRecord(1, "c1", 2.0, (1.0, float("nan"), 3.0), (1.0, 2.0, 3.0), "d", "ok", 9)
    raw = encode_payload(record)
    assert b" " not in raw
    assert json.loads(raw) == record.to_dict()
    assert json.loads(raw)["v_body_mps"] == [1.0, None, 3.0]
    # non-finite scalars that to_dict passes through still give valid JSON
    assert json.loads(encode_json({"a": float("inf"), "b": [float("nan")], "c": {"d": 1.5}})) == {
        "a": None,
        "b": [None],
        "c": {"d": 1.5},
    }


@pytest.mark.parametrize("prefix", ["", "a//b", "/glmav", "glmav/", "gl*", "a/$x", "g/@x", "a?b"])
def test_bad_prefixes_are_refused(prefix: str) -> None:
    with pytest.raises(ZenohConfigError, match="zenoh prefix"):
        check_prefix(prefix)


@pytest.mark.parametrize("service_id", ["", "a/b", "@x", "a*", "a#b"])
def test_bad_service_ids_are_refused(service_id: str) -> None:
    with pytest.raises(ZenohConfigError, match="zenoh service id"):
        check_service_id(service_id)


def test_default_service_id_is_one_valid_chunk() -> None:
    sid = default_service_id()
    assert check_service_id(sid) == sid
    zenoh.KeyExpr(alive_key("glmav", sid))  # a valid key expression


# ---------------------------------------------------------------------------------------
# Wire encodings: the fast encoders give exactly to_dict() + service_id
# ---------------------------------------------------------------------------------------

_FLOATS = st.floats(allow_nan=True, allow_infinity=True) | st.integers(-(2**40), 2**40)
_VEC = st.tuples(_FLOATS, _FLOATS, _FLOATS)


def _expected(record: Record, service_id: str | None) -> dict[str, Any]:
    """What the stdlib path of today gives: to_dict() + service_id through encode_json."""
    d = record.to_dict()
    if service_id is not None:
        d["service_id"] = service_id
        if isinstance(record, HealthRecord):  # a service's health sample names its release
            d["service_version"] = __version__
    value: dict[str, Any] = json.loads(encode_json(d))
    return value


def _same(a: Any, b: Any) -> bool:
    """Equal, with NaN equal to NaN (a MessagePack float keeps what to_dict() keeps)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return (bool(a == b) and type(a) is type(b)) or (a == b and {type(a), type(b)} <= {int, float})


@settings(max_examples=300, deadline=None)
@given(
    t=_FLOATS,
    body=_VEC,
    ned=_VEC,
    sigma=st.none() | _FLOATS,
    lost=st.sampled_from([None, "n", "e", "d"]),
    src=st.none() | st.sampled_from(["c1", "full", '\u00e9t\u00e9 "q"']),
    seq=st.integers(0, 2**63 - 1),
    service_id=st.none() | st.sampled_from(["svc", "gs-\u00e9"]),
    numpy_floats=st.booleans(),
)
def test_json_and_msgpack_encoders_give_exactly_to_dict(  # noqa: PLR0917 -- hypothesis draws
    t: float,
    body: tuple[float, float, float],
    ned: tuple[float, float, float],
    sigma: float | None,
    lost: str | None,
    src: str | None,
    seq: int,
    service_id: str | None,
    numpy_floats: bool,
) -> None:
    if numpy_floats:
        body = (np.float64(body[0]), np.float64(body[1]), np.float64(body[2]))  # type: ignore[assignment]
    record = VelocityRecord(7, "c2", t, body, ned, lost, "ok", seq, src, sigma)  # type: ignore[arg-type]
    want = _expected(record, service_id)
    got = json.loads(payload_encoder("json", service_id)(record))
    assert _same(got, want), (got, want)
    assert json.loads(encode_payload(record, service_id)) == got
    # MessagePack: the same object, non-finite scalars kept as to_dict() keeps them
    want_mp = record.to_dict()
    if service_id is not None:
        want_mp["service_id"] = service_id
    got_mp = decode_payload(payload_encoder("msgpack", service_id)(record), "application/msgpack")
    assert _same(got_mp, json.loads(json.dumps(want_mp))), (got_mp, want_mp)


def test_every_record_kind_encodes_to_its_dict_in_both_encodings() -> None:
    nan3 = (float("nan"),) * 3
    records: list[Record] = [
        _vel("active"),
        HealthRecord(7, 0.1, 1, "full", nan3, (0.1, 0.2, 3.5), {"n": "ok", "e": "ok", "d": "faulty"}, (), {"RAW_IMU": 250.0}, {"gaps": 1}),
        MeasurementRecord(7, 0.2, (1.0, float("nan"), 0.3), (1.5, 2.0, -10.0), 3),
        TruthRecord(7, 0.3, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.1, 0.2), None, 3),
    ]  # fmt: skip
    for record in records:
        want = _expected(record, "svc")
        assert json.loads(payload_encoder("json", "svc")(record)) == want
        mp = payload_encoder("msgpack", "svc")(record)
        assert decode_payload(mp, "application/msgpack") == want
        assert validate(decode_payload(mp, "application/msgpack")) == []
    # a number no fast path takes (beyond 64 bits) falls back to the stdlib's rules
    huge = _vel("full")._replace(seq=2**70)
    assert json.loads(payload_encoder("json", "svc")(huge))["seq"] == 2**70


def test_unknown_encoding_and_undecodable_payloads_are_errors() -> None:
    with pytest.raises(ValueError, match="unknown payload encoding 'cbor'"):
        payload_encoder("cbor")
    with pytest.raises(ZenohConfigError, match="zenoh encoding 'cbor': must be one of"):
        check_encoding("cbor")
    with pytest.raises(ValueError):
        decode_payload(b"\xc1", "application/msgpack")
    with pytest.raises(ValueError):
        decode_payload(b"\x93\x01\x02", "application/json")
    assert decode_payload(b'{"a":1}', "application/json;charset=utf-8") == {"a": 1}
