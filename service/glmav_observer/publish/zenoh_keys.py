"""What a Zenoh subscriber sees: the key expressions (checked prefixes and service ids,
one key per record kind, :func:`route`) and the payloads (compact JSON, NaN as null). The
key table is in :mod:`glmav_observer.publish.zenoh_sink`.
"""

from __future__ import annotations

import json
import math
import os
import re
import socket
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

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


def encode_payload(record: Record, service_id: str | None = None) -> bytes:
    """The payload of one record: ``record.to_dict()`` (with ``service_id`` when given)
    as compact JSON."""
    d = record.to_dict()
    if service_id is not None:
        d["service_id"] = service_id
    return encode_json(d)
