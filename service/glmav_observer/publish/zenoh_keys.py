"""What a Zenoh subscriber sees: the key expressions (checked prefixes and service ids,
one key per record kind, :func:`route`) and the payloads (``to_dict()`` + ``service_id``
as compact JSON with NaN as null, or as MessagePack: :func:`payload_encoder`). The key
table is in :mod:`glmav_observer.publish.zenoh_sink`.
"""

from __future__ import annotations

import functools
import json
import math
import os
import re
import socket
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import orjson
import ormsgpack

from glmav_observer._version import __version__
from glmav_observer.publish.schema import DEFAULT_ENCODING, ENCODINGS
from glmav_observer.records import (
    HealthRecord,
    MeasurementRecord,
    Record,
    TruthRecord,
    VelocityRecord,
)

if TYPE_CHECKING:
    pass
from glmav_observer.publish.zenoh_config import ZenohConfigError

_WILDCARD_CHARS = frozenset("*$?#")


# ---------------------------------------------------------------------------------------
# Key expressions
# ---------------------------------------------------------------------------------------


def check_prefix(prefix: str) -> str:
    """``prefix`` if it is a usable key prefix (no wildcards, no empty or ``@`` chunks)."""
    chunks = prefix.split("/")
    if not prefix or any(not c for c in chunks):
        raise ZenohConfigError(f"zenoh prefix {prefix!r}: empty chunk (use e.g. 'glmav')")
    if any(ch in _WILDCARD_CHARS for ch in prefix):
        raise ZenohConfigError(f"zenoh prefix {prefix!r}: wildcards (* $ ? #) are not allowed")
    if any(c.startswith("@") for c in chunks):
        raise ZenohConfigError(f"zenoh prefix {prefix!r}: chunks starting with '@' are reserved")
    return prefix


def check_service_id(service_id: str) -> str:
    """``service_id`` if it is one plain key chunk."""
    if (
        not service_id
        or "/" in service_id
        or service_id.startswith("@")
        or any(ch in _WILDCARD_CHARS for ch in service_id)
    ):
        raise ZenohConfigError(
            f"zenoh service id {service_id!r}: must be one non-empty key chunk "
            "without '/', wildcards (* $ ? #) or a leading '@'"
        )
    return service_id


def default_service_id() -> str:
    """``<host>-<pid>``, made a valid key chunk."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname()) or "host"
    return f"{host}-{os.getpid()}"


def velocity_key(prefix: str, sysid: int | str, config: str) -> str:
    return f"{prefix}/{sysid}/velocity/{config}"


def health_key(prefix: str, sysid: int | str) -> str:
    return f"{prefix}/{sysid}/health"


def measurement_key(prefix: str, sysid: int | str) -> str:
    return f"{prefix}/{sysid}/measurement"


def truth_key(prefix: str, sysid: int | str) -> str:
    return f"{prefix}/{sysid}/truth"


def state_key(prefix: str, sysid: int | str = "*") -> str:
    return f"{prefix}/{sysid}/state"


def config_key(prefix: str, service_id: str) -> str:
    return f"{prefix}/@config/{service_id}"


def alive_key(prefix: str, service_id: str = "*", sysid: int | str | None = None) -> str:
    base = f"{prefix}/@alive/{service_id}"
    return base if sysid is None else f"{base}/{sysid}"


def route(prefix: str, record: Record) -> tuple[str, str, str]:
    """``(kind, key, slot)`` of a record: its decimation kind, key, and slot in the state."""
    if isinstance(record, VelocityRecord):
        kind = "active" if record.config == "active" else "velocity"
        return kind, velocity_key(prefix, record.sysid, record.config), record.config
    if isinstance(record, HealthRecord):
        return "health", health_key(prefix, record.sysid), "health"
    if isinstance(record, MeasurementRecord):
        return "measurement", measurement_key(prefix, record.sysid), "measurement"
    if isinstance(record, TruthRecord):
        return "truth", truth_key(prefix, record.sysid), "truth"
    raise TypeError(f"not a record: {type(record).__name__}")


# ---------------------------------------------------------------------------------------
# Payloads
# ---------------------------------------------------------------------------------------


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def encode_json(obj: Mapping[str, Any]) -> bytes:
    """Compact JSON bytes; NaN/inf anywhere become null."""
    try:
        return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
    except ValueError:
        return json.dumps(_finite(obj), separators=(",", ":"), default=str).encode()


def encode_payload(
    record: Record, service_id: str | None = None, encoding: str = DEFAULT_ENCODING
) -> bytes:
    """The payload of one record: ``record.to_dict()`` (with ``service_id`` when given)
    in ``encoding`` (compact JSON by default), through :func:`payload_encoder` (made once
    per encoding and service id)."""
    return _cached_encoder(encoding, service_id)(record)


#: A record's payload: what :func:`payload_encoder` returns.
Encoder = Callable[[Record], bytes]

_NUMPY = orjson.OPT_SERIALIZE_NUMPY  # numpy scalars and arrays (NaN -> null) as numbers
_MSGPACK_NUMPY = ormsgpack.OPT_SERIALIZE_NUMPY


def payload_encoder(encoding: str, service_id: str | None = None) -> Encoder:
    """The encoder of one service's payloads: ``record.to_dict()`` plus ``service_id``
    (when given) as ``encoding`` (:data:`~glmav_observer.publish.schema.ENCODINGS`).

    JSON: orjson's compact output (NaN and infinities as null, as the stdlib path of
    :func:`encode_json` gives; floats in their shortest round-trip form), so a reader's
    ``json.loads`` gets exactly ``to_dict()``. A :class:`VelocityRecord`, the bulk of
    the traffic, skips ``to_dict()``: its object is built straight from the tuple's
    fields (its vectors as arrays, which orjson writes with NaN as null as ``_vec``
    does). MessagePack: the same map (binary float64s); a velocity vector holding a
    non-finite value goes through ``to_dict()`` (None there, as in JSON). Anything the
    fast paths refuse (a number beyond 64 bits, an unknown type) falls back to the
    stdlib's rules (:func:`encode_json`, non-serialisable values as strings).
    """
    if encoding not in ENCODINGS:
        raise ValueError(f"unknown payload encoding {encoding!r} (one of {', '.join(ENCODINGS)})")
    extra: dict[str, str] = {} if service_id is None else {"service_id": service_id}
    # a service's health sample (a few per second) also says which release publishes it
    health_extra = extra if service_id is None else {**extra, "service_version": __version__}

    def slow_dict(record: Record) -> dict[str, Any]:
        d = record.to_dict()
        d.update(health_extra if type(record) is HealthRecord else extra)
        return d

    if encoding == "msgpack":
        packb = ormsgpack.packb
        isfinite = math.isfinite

        def encode_msgpack(record: Record) -> bytes:
            if type(record) is VelocityRecord:
                b, v = record.v_body_mps, record.v_ned_mps
                try:  # (math.isfinite: numpy scalars' own arithmetic would warn on inf - inf)
                    finite = (
                        isfinite(b[0]) and isfinite(b[1]) and isfinite(b[2])
                        and isfinite(v[0]) and isfinite(v[1]) and isfinite(v[2])
                    )  # fmt: skip
                except TypeError:
                    finite = False
                d = _velocity_dict(record, extra) if finite else slow_dict(record)
            else:
                d = slow_dict(record)
            try:
                return packb(d, option=_MSGPACK_NUMPY)
            except (ormsgpack.MsgpackEncodeError, TypeError):
                return packb(slow_dict(record), option=_MSGPACK_NUMPY, default=str)

        return encode_msgpack

    dumps = orjson.dumps

    def encode_json_fast(record: Record) -> bytes:
        try:
            if type(record) is VelocityRecord:
                return dumps(_velocity_dict(record, extra), option=_NUMPY)
            return dumps(slow_dict(record), option=_NUMPY)
        except orjson.JSONEncodeError:
            return encode_json(slow_dict(record))

    return encode_json_fast


def _velocity_dict(record: VelocityRecord, extra: dict[str, str]) -> dict[str, Any]:
    """``record.to_dict()`` (plus ``extra``) from the tuple's fields, for an encoder that
    writes NaN as null itself (to_dict does it for the stdlib's JSON)."""
    (sysid, config, t, b, v, lost, health, seq, src, sigma, schema, dr_axes, sig_ned) = record
    return {
        "schema": schema, "sysid": sysid, "config": config, "t_boot_s": t,
        "v_body_mps": b, "v_ned_mps": v, "lost_axis": lost, "health": health,
        "seq": seq, "source_config": src, "sigma_lost_mps": sigma,
        "dead_reckoned_axes": dr_axes, "sigma_ned_mps": sig_ned, **extra,
    }  # fmt: skip


_cached_encoder = functools.lru_cache(maxsize=64)(payload_encoder)


def zenoh_encoding_name(encoding: str) -> str:
    """The Zenoh encoding (a MIME type) the publishers of ``encoding`` declare."""
    return ENCODINGS[encoding]


def decode_payload(payload: bytes, zenoh_encoding: str = "application/json") -> Any:
    """A sample's payload decoded by its Zenoh encoding (``str(sample.encoding)``):
    MessagePack for ``application/msgpack``, JSON otherwise. Raises ``ValueError``
    (``UnicodeDecodeError``, ``json.JSONDecodeError``, ``ormsgpack.MsgpackDecodeError``
    are all ValueErrors) when the payload is not what its encoding says."""
    if zenoh_encoding.split(";", 1)[0] == ENCODINGS["msgpack"]:
        return ormsgpack.unpackb(payload)
    return json.loads(payload)
