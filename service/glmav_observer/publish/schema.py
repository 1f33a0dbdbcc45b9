"""The JSON schemas of what the service publishes, and a small validator for them.

``SCHEMAS`` maps each payload's ``schema`` field (``"glmav.velocity/1"`` ...) to a JSON
Schema document (draft 2020-12, restricted to the keywords below) so that any client can
check our payloads with the tool of its choice. :func:`validate` interprets exactly that
subset by hand, so the service needs no JSON Schema library at run time; the tests check
that it agrees with an independent implementation.

Supported keywords: ``type`` (a name or a list), ``const``, ``enum``, ``properties``,
``required``, ``additionalProperties`` (bool or schema), ``items``, ``minItems``, ``minLength``,
``maxItems``, ``minimum``, ``maximum``, ``anyOf``. Numbers must also be finite (JSON has no
NaN; our encoder writes null).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from glmav_observer.configurations import AIDED
from glmav_observer.reads import STREAMS
from glmav_observer.records import (
    CONFIGS,
    HEALTH_SCHEMA,
    MEASUREMENT_SCHEMA,
    REFERENCE_SCHEMA,
    TRUTH_SCHEMA,
    VELOCITY_SCHEMA,
)

STATE_SCHEMA = "glmav.state/1"
CONFIG_SCHEMA = "glmav.config/1"

#: The key prefix of everything the service publishes, unless configured.
DEFAULT_PREFIX = "glmav"

#: The key kinds a decimation can be set for (``[zenoh.decimation]``, the sink's
#: ``decimation`` mapping, the published config), with their defaults: every record.
KINDS: tuple[str, ...] = ("velocity", "active", "health", "measurement", "truth")
DEFAULT_DECIMATION: dict[str, int] = dict.fromkeys(KINDS, 1)
#: Largest decimation (every Nth record): far above any useful value.
MAX_DECIMATION = 10_000

#: The wire encodings of the record keys (``[zenoh] encoding``, docs/zenoh.md "Payloads"),
#: each with the Zenoh encoding its publishers declare: the same ``to_dict()`` +
#: ``service_id`` object as JSON text (the default: any client reads it with its
#: standard library) or as a MessagePack map (smaller: binary floats). Queryables always
#: answer in JSON.
ENCODINGS: dict[str, str] = {"json": "application/json", "msgpack": "application/msgpack"}
DEFAULT_ENCODING = "json"


def encoding_reason(name: object) -> str | None:
    """None if ``name`` is one of :data:`ENCODINGS`, else the reason."""
    if name in ENCODINGS:
        return None
    return f"must be one of {', '.join(repr(e) for e in ENCODINGS)} (the payloads' wire encoding)"


def decimation_reason(every: object) -> str | None:
    """None if ``every`` is a valid decimation of one kind, else the reason."""
    if isinstance(every, bool) or not isinstance(every, int) or not 0 <= every <= MAX_DECIMATION:
        return (
            f"must be an integer in [0, {MAX_DECIMATION}] "
            "(1 = every record, N = every Nth, 0 = off)"
        )
    return None


Schema = dict[str, Any]

_AXES: list[str | None] = ["n", "e", "d"]
_SYSID: Schema = {"type": "integer", "minimum": 0, "maximum": 255}
_SEQ: Schema = {"type": "integer", "minimum": 0}
_TIME: Schema = {"type": "number"}
#: A 3-vector whose components may be null (a missing or non-finite value).
_VEC3: Schema = {
    "type": "array",
    "items": {"type": ["number", "null"]},
    "minItems": 3,
    "maxItems": 3,
}


def _nullable(schema: Schema) -> Schema:
    return {"anyOf": [schema, {"type": "null"}]}


def _object(properties: dict[str, Schema], *, required: list[str] | None = None) -> Schema:
    return {
        "type": "object",
        "properties": properties,
        "required": list(properties) if required is None else required,
        "additionalProperties": False,
    }


#: The publishing service's id: in every Zenoh sample (absent from file records).
_SERVICE_ID: Schema = {"type": "string", "minLength": 1}


#: The publishing service's release (``glmav_observer.__version__``, semantic versioning):
#: in Zenoh health samples and the ``@config`` reply; optional, so older payloads still check.
_VERSION: Schema = {"type": "string", "minLength": 1}


def _record(properties: dict[str, Schema], *, optional: dict[str, Schema] | None = None) -> Schema:
    """A record's schema: ``properties`` all required, plus the optional ``service_id``
    (and the ``optional`` ones)."""
    return _object(
        {**properties, "service_id": _SERVICE_ID, **(optional or {})}, required=list(properties)
    )


VELOCITY: Schema = _record(
    {
        "schema": {"const": VELOCITY_SCHEMA},
        "sysid": _SYSID,
        "config": {"enum": [*CONFIGS, AIDED, "active"]},
        "t_boot_s": _TIME,
        "v_body_mps": _VEC3,
        "v_ned_mps": _VEC3,
        "lost_axis": {"enum": [*_AXES, None]},
        "health": {"enum": ["ok", "dead_reckoning", "degraded", "aided"]},
        "seq": _SEQ,
        "source_config": {"enum": [*CONFIGS, None]},
        "sigma_lost_mps": {"type": ["number", "null"], "minimum": 0},
        "dead_reckoned_axes": {
            "type": "array",
            "items": {"enum": list(_AXES)},
            "uniqueItems": True,
            "maxItems": 3,
        },
        "sigma_ned_mps": {"anyOf": [_VEC3, {"type": "null"}]},
    }
)

_FAULT: Schema = _object(
    {
        "axis": {"enum": [*_AXES, "body"]},
        "kind": {
            "enum": [
                "dropout",
                "freeze",
                "bias",
                "noise",
                "unaided",
                "accel_bias",
                "accel_bias_end",
            ]
        },
        "t_detect_s": _TIME,
        "t_onset_s": {"type": ["number", "null"]},
        "bias_body_mps2": {"anyOf": [_VEC3, {"type": "null"}]},
        "imu": {"type": ["integer", "null"], "minimum": 1},
        "bias_sigma_mps2": {"anyOf": [_VEC3, {"type": "null"}]},
    }
)

_AXIS_STATE = {"enum": ["warmup", "ok", "suspect", "faulty", "recovering", "unaided"]}

HEALTH: Schema = _record(
    {
        "schema": {"const": HEALTH_SCHEMA},
        "sysid": _SYSID,
        "t_boot_s": _TIME,
        "seq": _SEQ,
        "active_config": {"enum": list(CONFIGS)},
        "residual_ned_mps": _VEC3,
        "test_ratio": _VEC3,
        "axis_state": _object({"n": _AXIS_STATE, "e": _AXIS_STATE, "d": _AXIS_STATE}),
        "isolated_faults": {"type": "array", "items": _FAULT},
        "input_rates_hz": {
            "type": "object",
            "additionalProperties": {"type": "number", "minimum": 0},
        },
        "counters": {
            "type": "object",
            "additionalProperties": {"type": "integer", "minimum": 0},
        },
        "reference_fit": _nullable(
            _object(
                {
                    "accel_bias_body_mps2": _VEC3,
                    "accel_bias_sigma_mps2": _VEC3,
                    "heading_error_rad": {"type": ["number", "null"]},
                    "heading_error_sigma_rad": {"type": ["number", "null"]},
                    "measurement_lag_s": {"type": ["number", "null"]},
                    "measurement_lag_sigma_s": {"type": ["number", "null"]},
                }
            )
        ),
    },
    optional={"service_version": _VERSION},
)

MEASUREMENT: Schema = _record(
    {
        "schema": {"const": MEASUREMENT_SCHEMA},
        "sysid": _SYSID,
        "t_boot_s": _TIME,
        "v_ned_mps": _VEC3,
        "position_ned_m": _VEC3,
        "euler_rad": _nullable(_VEC3),
        "seq": _SEQ,
    }
)

TRUTH: Schema = _record(
    {
        "schema": {"const": TRUTH_SCHEMA},
        "sysid": _SYSID,
        "t_boot_s": _TIME,
        "v_body_mps": _VEC3,
        "v_ned_mps": _VEC3,
        "euler_rad": _VEC3,
        "position_ned_m": _nullable(_VEC3),
        "seq": _SEQ,
    }
)

REFERENCE: Schema = _object(
    {
        "schema": {"const": REFERENCE_SCHEMA},
        "sysid": _SYSID,
        "t_boot_s": _TIME,
        "v_ned_mps": _VEC3,
        "source": {"type": "string"},
        "seq": _SEQ,
    }
)

#: The reply of the ``<prefix>/<sysid>/state`` queryable: the latest record of each kind.
STATE: Schema = _object(
    {
        "schema": {"const": STATE_SCHEMA},
        "service_id": {"type": "string"},
        "sysid": _SYSID,
        "velocity": {
            "type": "object",
            "properties": {name: VELOCITY for name in [*CONFIGS, AIDED, "active"]},
            "additionalProperties": False,
        },
        "health": _nullable(HEALTH),
        "measurement": _nullable(MEASUREMENT),
        "truth": _nullable(TRUTH),
    }
)

#: The reply of the ``<prefix>/@config/<service-id>`` queryable.
CONFIG: Schema = _object(
    {
        "schema": {"const": CONFIG_SCHEMA},
        "service_id": {"type": "string"},
        "prefix": {"type": "string"},
        "zenoh_config": {"type": ["string", "null"]},
        "decimation": _object(
            {kind: {"type": "integer", "minimum": 0, "maximum": MAX_DECIMATION} for kind in KINDS}
        ),
        # what is published per record stream, Hz of vehicle time (glmav_observer.reads)
        "rates_hz": _object(
            {
                stream: {"anyOf": [{"type": "number", "minimum": 0}, {"const": "every"}]}
                for stream in STREAMS
            }
        ),
        "config": {"type": "object"},
        "version": _VERSION,
    },
    required=["schema", "service_id", "prefix", "zenoh_config", "decimation", "rates_hz", "config"],
)

SCHEMAS: dict[str, Schema] = {
    VELOCITY_SCHEMA: VELOCITY,
    HEALTH_SCHEMA: HEALTH,
    MEASUREMENT_SCHEMA: MEASUREMENT,
    TRUTH_SCHEMA: TRUTH,
    REFERENCE_SCHEMA: REFERENCE,
    STATE_SCHEMA: STATE,
    CONFIG_SCHEMA: CONFIG,
}


class SchemaError(ValueError):
    """A payload that does not match its schema; ``errors`` lists every violation."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__("; ".join(errors))
        self.errors = errors


def _type_ok(value: Any, name: str) -> bool:
    if name == "null":
        return value is None
    if name == "boolean":
        return isinstance(value, bool)
    if name == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if name == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    if name == "string":
        return isinstance(value, str)
    if name == "array":
        return isinstance(value, list)
    if name == "object":
        return isinstance(value, dict)
    raise ValueError(f"unsupported JSON Schema type {name!r}")


def _check(value: Any, schema: Schema, path: str, errors: list[str]) -> None:
    where = path or "$"
    if "anyOf" in schema:
        branches: list[list[str]] = []
        for sub in schema["anyOf"]:
            sub_errors: list[str] = []
            _check(value, sub, path, sub_errors)
            if not sub_errors:
                break
            branches.append(sub_errors)
        else:
            errors.append(f"{where}: matches none of anyOf ({' | '.join(b[0] for b in branches)})")
            return
    if "const" in schema and value != schema["const"]:
        errors.append(f"{where}: expected {schema['const']!r}, got {value!r}")
        return
    if "enum" in schema and not any(value == e and type(value) is type(e) for e in schema["enum"]):
        errors.append(f"{where}: {value!r} not one of {schema['enum']!r}")
        return
    if "type" in schema:
        names = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        if not any(_type_ok(value, n) for n in names):
            errors.append(f"{where}: expected {'|'.join(names)}, got {type(value).__name__}")
            return
    if isinstance(value, float) and not math.isfinite(value):
        errors.append(f"{where}: non-finite number {value!r}")
        return
    if isinstance(value, int | float) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            errors.append(f"{where}: {value!r} < minimum {schema['minimum']!r}")
        if "maximum" in schema and value > schema["maximum"]:
            errors.append(f"{where}: {value!r} > maximum {schema['maximum']!r}")
    if isinstance(value, str) and "minLength" in schema and len(value) < schema["minLength"]:
        errors.append(f"{where}: {len(value)} characters < minLength {schema['minLength']}")
    if isinstance(value, list):
        if "minItems" in schema and len(value) < schema["minItems"]:
            errors.append(f"{where}: {len(value)} items < minItems {schema['minItems']}")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            errors.append(f"{where}: {len(value)} items > maxItems {schema['maxItems']}")
        if "items" in schema:
            for i, item in enumerate(value):
                _check(item, schema["items"], f"{path}[{i}]", errors)
    if isinstance(value, dict):
        properties: dict[str, Schema] = schema.get("properties", {})
        for key in schema.get("required", []):
            if key not in value:
                errors.append(f"{where}: missing required {key!r}")
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            sub_path = f"{path}.{key}" if path else str(key)
            if key in properties:
                _check(item, properties[key], sub_path, errors)
            elif extra is False:
                errors.append(f"{where}: unexpected property {key!r}")
            elif isinstance(extra, dict):
                _check(item, extra, sub_path, errors)


def validate(payload: Any, schema_id: str | None = None) -> list[str]:
    """Every violation of ``payload`` against its schema (empty list: valid).

    ``schema_id`` defaults to the payload's own ``schema`` field; an unknown or missing
    schema id is itself a violation.
    """
    if schema_id is None:
        if not isinstance(payload, Mapping) or not isinstance(payload.get("schema"), str):
            return ["$: no 'schema' string field"]
        schema_id = payload["schema"]
    schema = SCHEMAS.get(schema_id)
    if schema is None:
        return [f"$: unknown schema {schema_id!r} (known: {', '.join(SCHEMAS)})"]
    errors: list[str] = []
    _check(payload, schema, "", errors)
    return errors


def check(payload: Any, schema_id: str | None = None) -> None:
    """Raise :class:`SchemaError` listing every violation, if any."""
    errors = validate(payload, schema_id)
    if errors:
        raise SchemaError(errors)
