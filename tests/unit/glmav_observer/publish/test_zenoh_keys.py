"""Keys and payload encoding of the Zenoh sink (no sessions)."""

from __future__ import annotations

import json

import pytest
import zenoh

from glmav_observer.publish.zenoh_config import ZenohConfigError
from glmav_observer.publish.zenoh_keys import (
    alive_key,
    check_prefix,
    check_service_id,
    config_key,
    default_service_id,
    encode_json,
    encode_payload,
    route,
    state_key,
)
from glmav_observer.records import (
    HealthRecord,
    MeasurementRecord,
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
