"""The records the service produces: the contract between estimation and every sink.

Each record is immutable, with a ``to_dict()`` giving the JSON payload of ``design.md``
(one object per sample, ``schema`` first): a frozen dataclass, except
:class:`VelocityRecord`, a ``NamedTuple``: an estimator builds five or six of them per IMU
sample, and a frozen dataclass's ``__init__`` (one ``object.__setattr__`` per field) costs
2.5× a tuple's (1.9 against 0.75 µs for its 11 fields). Frames and units are in the
field names: ``v_body_mps`` is FRD body-frame velocity in m/s, ``v_ned_mps`` is the
earth-frame (NED) velocity in m/s, ``t_boot_s`` is the vehicle's boot clock in s.

``flatten()`` gives the same record as one flat row (``v_ned_mps`` -> ``v_ned_mps_n``
...), used by ``replay --out`` (CSV/JSONL) so that files and Zenoh payloads agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple

# the vocabulary of the records, from the table of configurations (exported with them)
from glmav_observer.configurations import CONFIGS, NED_AXES, AxisName

__all__ = [
    "CONFIGS",
    "HEALTH_SCHEMA",
    "MEASUREMENT_SCHEMA",
    "NED_AXES",
    "REFERENCE_SCHEMA",
    "TRUTH_SCHEMA",
    "VELOCITY_SCHEMA",
    "AxisName",
    "FaultEvent",
    "HealthRecord",
    "MeasurementRecord",
    "Record",
    "ReferenceFitSummary",
    "ReferenceRecord",
    "TruthRecord",
    "Vec3",
    "VelocityRecord",
    "flatten",
]

VELOCITY_SCHEMA = "glmav.velocity/1"
HEALTH_SCHEMA = "glmav.health/1"
TRUTH_SCHEMA = "glmav.truth/1"
MEASUREMENT_SCHEMA = "glmav.measurement/1"
REFERENCE_SCHEMA = "glmav.reference/1"

Vec3 = tuple[float, float, float]


def _vec(v: Vec3 | None) -> list[float | None] | None:
    """A 3-vector as a JSON list; NaN becomes null (JSON has no NaN)."""
    if v is None:
        return None
    return [None if not math.isfinite(x) else float(x) for x in v]


class VelocityRecord(NamedTuple):
    """One configuration's estimate at one vehicle time (key ``glmav/<sysid>/velocity/<config>``).

    ``config`` is one of ``CONFIGS``, ``"active"`` or ``"aided"``; for ``"active"``,
    ``source_config`` names the configuration selected. ``lost_axis`` is the NED axis not
    measured (dead reckoned) and ``sigma_lost_mps`` its 1-sigma uncertainty, growing with
    time since hand-over (None when nothing is lost). ``health`` is ``"ok"``,
    ``"dead_reckoning"`` or ``"degraded"``, and for ``"active"`` also ``"aided"`` while
    its lost axis is the aided one (``[estimation] aero_active``) with a
    pseudo-measurement accepted in the last second. ``"aided"`` is published only while one axis is
    lost: the hand-over configuration (``source_config``) with its lost axis aided by the
    learnt drag model; its ``health`` is ``"aided"`` while pseudo-measurements are accepted,
    ``"dead_reckoning"`` otherwise, and ``sigma_lost_mps`` the aided axis's 1σ.
    """

    sysid: int
    config: str
    t_boot_s: float
    v_body_mps: Vec3
    v_ned_mps: Vec3
    lost_axis: AxisName | None
    health: str
    seq: int
    source_config: str | None = None
    sigma_lost_mps: float | None = None
    schema: str = VELOCITY_SCHEMA
    #: the NED axes this estimate dead-reckons now, in n, e, d order: its lost axis, an
    #: isolated axis, an axis the autopilot says is unaided (GPS lost), every axis while
    #: the measurement stream is silent (``estimation.drift``)
    dead_reckoned_axes: tuple[AxisName, ...] = ()
    #: 1σ per NED axis of the dead-reckoned axes' drift (0.0 on a measured axis); None
    #: when no axis is dead-reckoned
    sigma_ned_mps: Vec3 | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": self.schema,
            "sysid": self.sysid,
            "config": self.config,
            "t_boot_s": self.t_boot_s,
            "v_body_mps": _vec(self.v_body_mps),
            "v_ned_mps": _vec(self.v_ned_mps),
            "lost_axis": self.lost_axis,
            "health": self.health,
            "seq": self.seq,
            "source_config": self.source_config,
            "sigma_lost_mps": self.sigma_lost_mps,
            "dead_reckoned_axes": list(self.dead_reckoned_axes),
            "sigma_ned_mps": None if self.sigma_ned_mps is None else _vec(self.sigma_ned_mps),
        }


@dataclass(frozen=True, slots=True)
class FaultEvent:
    """A fault found by the FDI.

    Velocity-sensor faults (``dropout``, ``freeze``, ``bias``, ``noise``, and ``unaided``
    when the autopilot says its velocity is not aided) name the NED axis isolated. An
    accelerometer fault (``accel_bias``) isolates no axis: ``axis`` is ``"body"``,
    ``t_onset_s`` the estimated change time and ``bias_body_mps2`` the estimated change of
    the body-frame (FRD) accelerometer bias. A velocity-sensor fault leaves both None: it is
    isolated after a run of failed tests, and no onset time is estimated for it.
    """

    axis: AxisName | Literal["body"]
    kind: (
        str  # "dropout" | "freeze" | "bias" | "noise" | "unaided" | "accel_bias" | "accel_bias_end"
    )
    t_detect_s: float
    t_onset_s: float | None = None
    bias_body_mps2: Vec3 | None = None
    #: the IMU an accelerometer event is on (1: the estimator's; None: not told apart)
    imu: int | None = None
    #: 1σ of ``bias_body_mps2`` per body axis, when the redundant IMUs measured it
    bias_sigma_mps2: Vec3 | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "axis": self.axis,
            "kind": self.kind,
            "t_detect_s": self.t_detect_s,
            "t_onset_s": self.t_onset_s,
            "bias_body_mps2": _vec(self.bias_body_mps2),
            "imu": self.imu,
            "bias_sigma_mps2": _vec(self.bias_sigma_mps2),
        }


@dataclass(frozen=True, slots=True)
class ReferenceFitSummary:
    """What the FDI's reference fit has learnt of the vehicle's sensors (docs/design/observer-notes.md,
    "The reference"): the body-frame (FRD) accelerometer bias, the attitude's heading error
    and the velocity measurement's lag. Each is the fit's mean; ``*_sigma`` its 1σ."""

    accel_bias_body_mps2: Vec3
    accel_bias_sigma_mps2: Vec3
    heading_error_rad: float
    heading_error_sigma_rad: float
    measurement_lag_s: float
    measurement_lag_sigma_s: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "accel_bias_body_mps2": _vec(self.accel_bias_body_mps2),
            "accel_bias_sigma_mps2": _vec(self.accel_bias_sigma_mps2),
            "heading_error_rad": self.heading_error_rad,
            "heading_error_sigma_rad": self.heading_error_sigma_rad,
            "measurement_lag_s": self.measurement_lag_s,
            "measurement_lag_sigma_s": self.measurement_lag_sigma_s,
        }


@dataclass(frozen=True, slots=True)
class HealthRecord:
    """Per-vehicle health (key ``glmav/<sysid>/health``, 10 Hz).

    ``residual_ned_mps`` are the per-axis residuals of the velocity measurement
    against the prediction; ``test_ratio`` the residual statistics over their
    thresholds (> 1 means the axis fails its test); ``axis_state`` maps each NED axis
    to ``"ok"``, ``"suspect"``, ``"faulty"`` or ``"recovering"``; ``isolated_faults``
    the axes isolated now, plus any ``accel_bias`` event of the last 5 s (axis ``"body"``:
    it isolates nothing); ``input_rates_hz`` the measured stream rates by message name;
    ``reference_fit`` what the FDI's reference has learnt (null before its first fit).
    """

    sysid: int
    t_boot_s: float
    seq: int
    active_config: str
    residual_ned_mps: Vec3
    test_ratio: Vec3
    axis_state: dict[str, str]
    isolated_faults: tuple[FaultEvent, ...]
    input_rates_hz: dict[str, float]
    counters: dict[str, int]
    reference_fit: ReferenceFitSummary | None = None
    schema: str = field(default=HEALTH_SCHEMA)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": self.schema,
            "sysid": self.sysid,
            "t_boot_s": self.t_boot_s,
            "seq": self.seq,
            "active_config": self.active_config,
            "residual_ned_mps": _vec(self.residual_ned_mps),
            "test_ratio": _vec(self.test_ratio),
            "axis_state": dict(self.axis_state),
            "isolated_faults": [f.to_dict() for f in self.isolated_faults],
            "input_rates_hz": dict(self.input_rates_hz),
            "counters": dict(self.counters),
            "reference_fit": None if self.reference_fit is None else self.reference_fit.to_dict(),
        }


@dataclass(frozen=True, slots=True)
class TruthRecord:
    """The simulator's truth (SIM_STATE), for error plots and metrics only."""

    sysid: int
    t_boot_s: float
    v_body_mps: Vec3
    v_ned_mps: Vec3
    euler_rad: Vec3
    position_ned_m: Vec3 | None
    seq: int
    schema: str = field(default=TRUTH_SCHEMA)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": self.schema,
            "sysid": self.sysid,
            "t_boot_s": self.t_boot_s,
            "v_body_mps": _vec(self.v_body_mps),
            "v_ned_mps": _vec(self.v_ned_mps),
            "euler_rad": _vec(self.euler_rad),
            "position_ned_m": _vec(self.position_ned_m),
            "seq": self.seq,
        }


@dataclass(frozen=True, slots=True)
class MeasurementRecord:
    """The velocity measurement as received (LOCAL_POSITION_NED), NaN where missing.

    ``euler_rad`` is the latest attitude (ATTITUDE, ZYX roll/pitch/yaw) held at that
    vehicle time, so that sinks can draw the pose of a vehicle that sends no truth.
    """

    sysid: int
    t_boot_s: float
    v_ned_mps: Vec3
    position_ned_m: Vec3
    seq: int
    euler_rad: Vec3 | None = None
    schema: str = field(default=MEASUREMENT_SCHEMA)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": self.schema,
            "sysid": self.sysid,
            "t_boot_s": self.t_boot_s,
            "v_ned_mps": _vec(self.v_ned_mps),
            "position_ned_m": _vec(self.position_ned_m),
            "euler_rad": _vec(self.euler_rad),
            "seq": self.seq,
        }


@dataclass(frozen=True, slots=True)
class ReferenceRecord:
    """The autopilot's own estimate of the velocity (its EKF), from a flight log.

    Not a measurement (the EKF has fused the IMU already) and not truth: what the observer
    is compared with when a log has no simulator truth. ``source`` names the log's
    message or topic (``XKF1 core 0``, ``vehicle_local_position``).
    """

    sysid: int
    t_boot_s: float
    v_ned_mps: Vec3
    source: str
    seq: int
    schema: str = field(default=REFERENCE_SCHEMA)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": self.schema,
            "sysid": self.sysid,
            "t_boot_s": self.t_boot_s,
            "v_ned_mps": _vec(self.v_ned_mps),
            "source": self.source,
            "seq": self.seq,
        }


Record = VelocityRecord | HealthRecord | TruthRecord | MeasurementRecord | ReferenceRecord


def flatten(record: Record) -> dict[str, Any]:
    """One flat row: lists become ``name_<axis>`` columns, nested dicts ``name.key``."""
    row: dict[str, Any] = {}
    for key, raw in record.to_dict().items():
        # the same columns whether or not a record has a σ per axis
        value = [None, None, None] if raw is None and key == "sigma_ned_mps" else raw
        if isinstance(value, list) and len(value) == 3 and key.endswith(("_mps", "_m", "_rad")):
            suffixes = ("u", "v", "w") if "body" in key else ("n", "e", "d")
            if key == "euler_rad":
                suffixes = ("roll", "pitch", "yaw")
            for s, x in zip(suffixes, value, strict=True):
                row[f"{key}_{s}"] = x
        elif isinstance(value, list) and len(value) == 3 and key in ("test_ratio",):
            for s, x in zip(NED_AXES, value, strict=True):
                row[f"{key}_{s}"] = x
        elif isinstance(value, dict):
            for k, x in value.items():
                row[f"{key}.{k}"] = x
        else:
            row[key] = value
    return row
