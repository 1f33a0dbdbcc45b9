"""Typed samples in SI units: what ingest hands to estimation.

Every sample carries the MAVLink system id of the vehicle that sent it and the
vehicle's own boot-clock time ``t_boot_s`` (never the host clock). Frames and units
are in the names: NED earth frame, FRD body frame, ZYX Euler angles (MAVLink
``ATTITUDE``), m/s, m/s², rad, rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

Vec3 = tuple[float, float, float]


class ImuSource(IntEnum):
    """The IMU message a specific force came from; a larger value is preferred."""

    RAW_IMU = 1
    SCALED_IMU = 2
    HIGHRES_IMU = 3


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """``ATTITUDE``: ZYX Euler angles (roll, pitch, yaw) and FRD body rates."""

    sysid: int
    t_boot_s: float
    euler_rad: Vec3
    omega_body_radps: Vec3


@dataclass(frozen=True, slots=True)
class ImuSample:
    """Specific force (accelerometer, FRD) and gyro rates from one of the IMU messages."""

    sysid: int
    t_boot_s: float
    f_body_mps2: Vec3
    omega_body_radps: Vec3
    source: ImuSource


@dataclass(frozen=True, slots=True)
class VelocitySample:
    """``LOCAL_POSITION_NED``: earth-frame position and velocity; NaN marks a missing axis."""

    sysid: int
    t_boot_s: float
    position_ned_m: Vec3
    v_ned_mps: Vec3


@dataclass(frozen=True, slots=True)
class TruthSample:
    """``SIM_STATE`` (simulator truth, metrics only). SIM_STATE carries no time field:
    ``t_boot_s`` is the latest vehicle time seen from that vehicle when it arrived."""

    sysid: int
    t_boot_s: float
    euler_rad: Vec3
    v_ned_mps: Vec3


@dataclass(frozen=True, slots=True)
class AidingSample:
    """What the autopilot says its velocity output rests on (``LOCAL_POSITION_NED`` is the
    autopilot's own estimate, not a sensor): from ``EKF_STATUS_REPORT`` (ArduPilot) or
    ``GPS_RAW_INT``. ``horizontal_aided`` / ``vertical_aided`` are None when the message
    says nothing about that direction. ``reason`` names what failed (e.g. ``gps_fix_1``,
    ``ekf_velocity_horiz_unaided``). No time field: stamped like ``SIM_STATE``."""

    sysid: int
    t_boot_s: float
    source: str  # "EKF_STATUS_REPORT" | "GPS_RAW_INT"
    horizontal_aided: bool | None
    vertical_aided: bool | None
    reason: str
    #: GPS_RAW_INT's ground velocity (north, east; m/s) with a 3D fix: a velocity no IMU
    #: of the vehicle touched (``VehicleEstimator._resolve_imu``); None otherwise
    gps_v_ne_mps: tuple[float, float] | None = None
    #: its 1σ per axis from the receiver (GPS_RAW_INT ``vel_acc``), m/s; None: not given
    gps_v_sigma_mps: float | None = None


@dataclass(frozen=True, slots=True)
class ControlSample:
    """``SERVO_OUTPUT_RAW``: the autopilot's actuator outputs, PWM µs per channel
    (``servo_pwm_us[0]`` is channel 1; 0 = unused). What a channel means is the vehicle's
    (``estimation.aero.control.ControlMapping``). Its ``time_usec`` is a uint32 that wraps
    every 71.6 min: stamped with the vehicle's latest time instead, like ``SIM_STATE``."""

    sysid: int
    t_boot_s: float
    servo_pwm_us: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class SecondaryImuSample:
    """``SCALED_IMU2`` / ``SCALED_IMU3``: the specific force of another IMU on the vehicle
    (``instance`` 2 or 3), compared with the estimator's own (``estimation.imu_monitor``),
    never integrated."""

    sysid: int
    t_boot_s: float
    instance: int
    f_body_mps2: Vec3


Sample = (
    AttitudeSample
    | ImuSample
    | VelocitySample
    | TruthSample
    | AidingSample
    | ControlSample
    | SecondaryImuSample
)
