"""The hand-written payload validator against an independent JSON Schema implementation."""

from __future__ import annotations

import copy
import json
import math
from typing import Any

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from glmav_observer.configurations import LOST_AXIS_OF_CONFIG
from glmav_observer.publish.schema import SCHEMAS, SchemaError, check, validate
from glmav_observer.publish.zenoh_keys import encode_payload
from glmav_observer.records import (
    CONFIGS,
    FaultEvent,
    HealthRecord,
    MeasurementRecord,
    ReferenceFitSummary,
    TruthRecord,
    VelocityRecord,
)

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
vec3 = st.tuples(floats, floats, floats)
sysids = st.integers(0, 255)
seqs = st.integers(0, 2**40)


@st.composite
def velocity_records(draw: st.DrawFn) -> VelocityRecord:
    config = draw(st.sampled_from([*CONFIGS, "active"]))
    source = draw(st.sampled_from(CONFIGS)) if config == "active" else None
    lost = LOST_AXIS_OF_CONFIG[source if source else config]
    return VelocityRecord(
        sysid=draw(sysids),
        config=config,
        t_boot_s=draw(finite),
        v_body_mps=draw(vec3),
        v_ned_mps=draw(vec3),
        lost_axis=lost,  # type: ignore[arg-type]
        health=draw(st.sampled_from(["ok", "dead_reckoning", "degraded"])),
        seq=draw(seqs),
        source_config=source,
        sigma_lost_mps=None if lost is None else draw(st.floats(0, 1e6)),
    )


@st.composite
def health_records(draw: st.DrawFn) -> HealthRecord:
    axis_states = st.sampled_from(["warmup", "ok", "suspect", "faulty", "recovering"])
    faults = st.lists(
        st.builds(
            FaultEvent,
            axis=st.sampled_from(["n", "e", "d"]),
            kind=st.sampled_from(["dropout", "freeze", "bias", "noise"]),
            t_detect_s=finite,
            t_onset_s=st.none() | finite,
        ),
        max_size=3,
    )
    return HealthRecord(
        sysid=draw(sysids),
        t_boot_s=draw(finite),
        seq=draw(seqs),
        active_config=draw(st.sampled_from(CONFIGS)),
        residual_ned_mps=draw(vec3),
        test_ratio=draw(vec3),
        axis_state={a: draw(axis_states) for a in ("n", "e", "d")},
        isolated_faults=tuple(draw(faults)),
        input_rates_hz=draw(st.dictionaries(st.text(max_size=12), st.floats(0, 1e4), max_size=4)),
        counters=draw(st.dictionaries(st.text(max_size=12), st.integers(0, 2**40), max_size=4)),
        reference_fit=draw(
            st.none()
            | st.builds(
                ReferenceFitSummary,
                accel_bias_body_mps2=vec3,
                accel_bias_sigma_mps2=vec3,
                heading_error_rad=finite,
                heading_error_sigma_rad=finite,
                measurement_lag_s=finite,
                measurement_lag_sigma_s=finite,
            )
        ),
    )


measurement_records = st.builds(
    MeasurementRecord,
    sysid=sysids,
    t_boot_s=finite,
    v_ned_mps=vec3,
    position_ned_m=vec3,
    seq=seqs,
    euler_rad=st.none() | vec3,
)
truth_records = st.builds(
    TruthRecord,
    sysid=sysids,
    t_boot_s=finite,
    v_body_mps=vec3,
    v_ned_mps=vec3,
    euler_rad=vec3,
    position_ned_m=st.none() | vec3,
    seq=seqs,
)
any_record = velocity_records() | health_records() | measurement_records | truth_records


def test_the_schemas_are_valid_json_schema_documents() -> None:
    for schema in SCHEMAS.values():
        jsonschema.Draft202012Validator.check_schema(schema)


@settings(max_examples=150, deadline=None)
@given(any_record)
def test_every_encoded_record_is_valid_for_both_validators(record: Any) -> None:
    payload = json.loads(encode_payload(record))
    assert payload == json.loads(json.dumps(record.to_dict()))  # the encoder adds nothing
    assert validate(payload) == []
    jsonschema.validate(payload, SCHEMAS[payload["schema"]])


def _velocity() -> dict[str, Any]:
    return VelocityRecord(
        1, "c1", 0.5, (1.0, 2.0, 3.0), (3.0, 2.0, 1.0), "d", "dead_reckoning", 7, None, 0.2
    ).to_dict()


MUTATIONS: list[tuple[str, Any]] = [
    ("missing field", lambda p: p.pop("seq")),
    ("extra field", lambda p: p.update(extra=1)),
    ("string for number", lambda p: p.update(t_boot_s="0.5")),
    ("bool for integer", lambda p: p.update(seq=True)),
    ("float for integer", lambda p: p.update(seq=7.5)),
    ("negative seq", lambda p: p.update(seq=-1)),
    ("sysid > 255", lambda p: p.update(sysid=256)),
    ("unknown config", lambda p: p.update(config="c9")),
    ("unknown lost axis", lambda p: p.update(lost_axis="x")),
    ("two components", lambda p: p.update(v_ned_mps=[1.0, 2.0])),
    ("four components", lambda p: p.update(v_body_mps=[1.0, 2.0, 3.0, 4.0])),
    ("string component", lambda p: p.update(v_body_mps=[1.0, "2", 3.0])),
    ("negative sigma", lambda p: p.update(sigma_lost_mps=-0.1)),
    ("wrong schema id", lambda p: p.update(schema="glmav.health/1")),
]


@pytest.mark.parametrize(("name", "mutate"), MUTATIONS, ids=[m[0] for m in MUTATIONS])
def test_each_violation_is_reported_by_both_validators(name: str, mutate: Any) -> None:
    payload = _velocity()
    assert validate(payload) == []
    mutate(payload)
    errors = validate(payload, "glmav.velocity/1")
    assert len(errors) >= 1, name
    assert not jsonschema.Draft202012Validator(SCHEMAS["glmav.velocity/1"]).is_valid(payload)
    with pytest.raises(SchemaError):
        check(payload, "glmav.velocity/1")


def test_errors_name_the_path() -> None:
    health = HealthRecord(
        2, 1.0, 3, "full", (0.0, 0.0, 0.0), (0.1, 0.2, 0.3), {"n": "ok", "e": "ok", "d": "ok"},
        (FaultEvent("d", "bias", 0.9),), {"RAW_IMU": 250.0}, {"bad": 0},
    ).to_dict()  # fmt: skip
    bad = copy.deepcopy(health)
    bad["isolated_faults"][0]["kind"] = "gremlins"
    bad["axis_state"]["e"] = "fine"
    bad["counters"]["bad"] = -1
    errors = validate(bad)
    assert len(errors) == 3
    assert any(e.startswith("isolated_faults[0].kind: 'gremlins' not one of") for e in errors)
    assert any(e.startswith("axis_state.e: 'fine' not one of") for e in errors)
    assert any(e.startswith("counters.bad: -1 < minimum 0") for e in errors)


def test_non_finite_numbers_and_unknown_schemas_are_refused() -> None:
    payload = _velocity()
    payload["t_boot_s"] = math.nan  # what a careless encoder would let through
    assert validate(payload) == ["t_boot_s: non-finite number nan"]
    assert validate({"schema": "glmav.nothing/1"})[0].startswith("$: unknown schema")
    assert validate([1, 2]) == ["$: no 'schema' string field"]
    assert validate({"schema": 1}) == ["$: no 'schema' string field"]


def test_state_payload_nests_the_record_schemas() -> None:
    velocity = _velocity()
    state = {
        "schema": "glmav.state/1",
        "service_id": "svc",
        "sysid": 1,
        "velocity": {"c1": velocity},
        "health": None,
        "measurement": None,
        "truth": None,
    }
    assert validate(state) == []
    jsonschema.validate(state, SCHEMAS["glmav.state/1"])
    state["velocity"]["c1"] = {**velocity, "seq": "x"}
    assert validate(state) == ["velocity.c1.seq: expected integer, got str"]
    state["velocity"] = {"c7": velocity}
    assert validate(state) == ["velocity: unexpected property 'c7'"]
    state["velocity"] = {}
    state["health"] = {"schema": "glmav.health/1"}
    (error,) = validate(state)
    assert error.startswith("health: matches none of anyOf")


def test_zenoh_payloads_carry_the_service_id_and_it_is_checked() -> None:
    record = VelocityRecord(1, "full", 0.5, (1.0, 2.0, 3.0), (3.0, 2.0, 1.0), None, "ok", 7)
    payload = json.loads(encode_payload(record, "svc-a"))
    assert payload == {**record.to_dict(), "service_id": "svc-a"}
    assert validate(payload) == []
    jsonschema.validate(payload, SCHEMAS["glmav.velocity/1"])
    for bad in ("", 3):
        wrong = {**payload, "service_id": bad}
        assert len(validate(wrong)) == 1
        assert not jsonschema.Draft202012Validator(SCHEMAS["glmav.velocity/1"]).is_valid(wrong)
