"""Decoded MAVLink messages -> typed samples in SI units (pure; no I/O, no clock policy).

Units at the edge (MAVLink common.xml):

- ``ATTITUDE``: rad, rad/s, ``time_boot_ms``.
- ``HIGHRES_IMU``: m/s², rad/s, ``time_usec``.
- ``SCALED_IMU``: mG (1e-3 g, g = 9.80665 m/s²), mrad/s, ``time_boot_ms``.
- ``SCALED_IMU2``, ``SCALED_IMU3``: the same units; another IMU of the vehicle, compared
  with the estimator's (:class:`SecondaryImuSample`), not integrated.
- ``RAW_IMU``: raw counts, ``time_usec``; the scales come from configuration, per
  vehicle (ArduPilot sends mG and mrad/s, the defaults of :class:`RawImuScale`).
- ``LOCAL_POSITION_NED``: m, m/s (NED), ``time_boot_ms``.
- ``SIM_STATE``: rad, m/s (NED); no time field.
- ``SERVO_OUTPUT_RAW``: PWM µs per channel (:class:`ControlSample`); its uint32
  ``time_usec`` wraps after 71.6 min, so it is stamped with the vehicle's latest time.
- ``EKF_STATUS_REPORT`` (ArduPilot), ``GPS_RAW_INT``: what the autopilot's velocity rests
  on (:class:`AidingSample`); stamped with the vehicle's latest time, like ``SIM_STATE``.

Time fields are returned raw in µs with their kind, so that the per-vehicle clock
(:mod:`glmav_observer.ingest.clock`) decides (UNIX-epoch ``time_usec`` detection).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Any

from glmav_observer.ingest.samples import (
    AidingSample,
    AttitudeSample,
    ControlSample,
    ImuSample,
    ImuSource,
    Sample,
    SecondaryImuSample,
    TruthSample,
    Vec3,
    VelocitySample,
)

#: Standard gravity, for milli-g (MAVLink SCALED_IMU, ArduPilot RAW_IMU).
STANDARD_G_MPS2 = 9.80665
MG_TO_MPS2 = STANDARD_G_MPS2 * 1e-3
MRAD_TO_RAD = 1e-3

#: Messages that become samples.
SAMPLE_MESSAGES: frozenset[str] = frozenset(
    {
        "ATTITUDE",
        "RAW_IMU",
        "SCALED_IMU",
        "HIGHRES_IMU",
        "SCALED_IMU2",
        "SCALED_IMU3",
        "LOCAL_POSITION_NED",
        "SIM_STATE",
        "EKF_STATUS_REPORT",
        "GPS_RAW_INT",
        "SERVO_OUTPUT_RAW",
    }
)
#: Messages without a usable vehicle time: stamped with the vehicle's latest time and not
#: submitted to its clock (GPS_RAW_INT's time_usec is the receiver's, often UNIX time).
UNTIMED_MESSAGES: frozenset[str] = frozenset(
    {"SIM_STATE", "EKF_STATUS_REPORT", "GPS_RAW_INT", "SERVO_OUTPUT_RAW"}
)
#: SERVO_OUTPUT_RAW channels: 1-8, and 9-16 when the MAVLink 2 extension is present
SERVO_CHANNELS = 16

#: EKF_STATUS_REPORT flags (MAVLink ``ESTIMATOR_STATUS_FLAGS``).
EKF_VELOCITY_HORIZ = 2
EKF_VELOCITY_VERT = 4
EKF_UNINITIALIZED = 1024
#: GPS_RAW_INT fix types below this give no velocity (``GPS_FIX_TYPE_3D_FIX``).
GPS_FIX_3D = 3
#: GPS_RAW_INT's ``vel`` / ``cog`` when unknown
UINT16_UNKNOWN = 65535


class TimeKind(Enum):
    """How a message stamps vehicle time."""

    BOOT_MS = "time_boot_ms"  # ms since boot
    USEC = "time_usec"  # µs since boot, or since the UNIX epoch on some autopilots
    NONE = "none"  # no time field (SIM_STATE): stamped with the vehicle's latest time


# The members as module globals for the per-message paths (Python 3.11 reads a member
# through its class with EnumType's slow attribute lookup: ~150 ns against ~10)
TIME_BOOT_MS, TIME_USEC, TIME_NONE = TimeKind.BOOT_MS, TimeKind.USEC, TimeKind.NONE
_HIGHRES_IMU, _SCALED_IMU, _RAW_IMU = ImuSource.HIGHRES_IMU, ImuSource.SCALED_IMU, ImuSource.RAW_IMU


@dataclass(frozen=True, slots=True)
class RawImuScale:
    """Scales of ``RAW_IMU`` counts for one vehicle (ArduPilot: 1 LSB = 1 mG, 1 mrad/s)."""

    accel_mps2_per_lsb: float = MG_TO_MPS2
    gyro_radps_per_lsb: float = MRAD_TO_RAD


class ConversionError(ValueError):
    """A message that cannot become a sample (reason names the counter)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def message_time_us(msg: Any) -> tuple[int, TimeKind]:
    """The raw time stamp of a sample message, in µs, and its kind."""
    name = msg.get_type()
    if name in ("RAW_IMU", "HIGHRES_IMU"):
        return int(msg.time_usec), TIME_USEC
    if name in UNTIMED_MESSAGES:
        return 0, TIME_NONE
    return int(msg.time_boot_ms) * 1000, TIME_BOOT_MS


def _finite3(values: tuple[float, float, float], what: str) -> Vec3:
    x, y, z = float(values[0]), float(values[1]), float(values[2])
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ConversionError("nan_field", f"{what} not finite: {values}")
    return (x, y, z)


#: Beyond any IMU's range (high-g MEMS accelerometers: ±200 g; gyros: ±4000 °/s): a value
#: above these is corruption, not a measurement, and one would poison the estimate.
IMU_MAX_F_MPS2 = 2000.0
IMU_MAX_OMEGA_RADPS = 70.0


def _imu_vectors(f: Vec3, w: Vec3, name: str) -> tuple[Vec3, Vec3]:
    # (finite here: _finite3 came first) any component beyond the range, i.e. the max of |x|
    f0, f1, f2 = abs(f[0]), abs(f[1]), abs(f[2])
    w0, w1, w2 = abs(w[0]), abs(w[1]), abs(w[2])
    lim_f, lim_w = IMU_MAX_F_MPS2, IMU_MAX_OMEGA_RADPS
    if f0 > lim_f or f1 > lim_f or f2 > lim_f or w0 > lim_w or w1 > lim_w or w2 > lim_w:
        raise ConversionError("implausible", f"{name} beyond any IMU range: f={f} w={w}")
    if f == (0.0, 0.0, 0.0):
        # an accelerometer never reads exactly zero on a vehicle in gravity: absent sensor
        raise ConversionError("imu_absent", f"{name} specific force is exactly zero")
    return f, w


def to_sample(msg: Any, t_boot_s: float, raw_scale: RawImuScale) -> Sample:
    """Convert one decoded message (name in ``SAMPLE_MESSAGES``) stamped at ``t_boot_s``.

    Raises :class:`ConversionError` (reason ``nan_field``, ``imu_absent``) for a message
    that cannot be used; ``LOCAL_POSITION_NED`` keeps NaN velocities (a dropout is data).
    """
    name = msg.get_type()
    sysid = int(msg.get_srcSystem())
    if name == "ATTITUDE":
        euler = _finite3((msg.roll, msg.pitch, msg.yaw), "ATTITUDE angles")
        omega = _finite3((msg.rollspeed, msg.pitchspeed, msg.yawspeed), "ATTITUDE rates")
        return AttitudeSample(sysid, t_boot_s, euler, omega)
    if name == "HIGHRES_IMU":
        f, w = _imu_vectors(
            _finite3((msg.xacc, msg.yacc, msg.zacc), "HIGHRES_IMU acc"),
            _finite3((msg.xgyro, msg.ygyro, msg.zgyro), "HIGHRES_IMU gyro"),
            name,
        )
        return ImuSample(sysid, t_boot_s, f, w, _HIGHRES_IMU)
    if name in ("SCALED_IMU", "RAW_IMU"):
        if name == "SCALED_IMU":
            ka, kw, src = MG_TO_MPS2, MRAD_TO_RAD, _SCALED_IMU
        else:
            ka, kw = raw_scale.accel_mps2_per_lsb, raw_scale.gyro_radps_per_lsb
            src = _RAW_IMU
        fa = (msg.xacc * ka, msg.yacc * ka, msg.zacc * ka)
        fw = (msg.xgyro * kw, msg.ygyro * kw, msg.zgyro * kw)
        f, w = _imu_vectors(_finite3(fa, f"{name} acc"), _finite3(fw, f"{name} gyro"), name)
        return ImuSample(sysid, t_boot_s, f, w, src)
    if name in ("SCALED_IMU2", "SCALED_IMU3"):
        fa = (msg.xacc * MG_TO_MPS2, msg.yacc * MG_TO_MPS2, msg.zacc * MG_TO_MPS2)
        f, _ = _imu_vectors(_finite3(fa, f"{name} acc"), (0.0, 0.0, 0.0), name)
        return SecondaryImuSample(sysid, t_boot_s, 2 if name == "SCALED_IMU2" else 3, f)
    if name == "LOCAL_POSITION_NED":
        pos = (float(msg.x), float(msg.y), float(msg.z))
        vel = (float(msg.vx), float(msg.vy), float(msg.vz))
        return VelocitySample(sysid, t_boot_s, pos, vel)
    if name == "SIM_STATE":
        euler = _finite3((msg.roll, msg.pitch, msg.yaw), "SIM_STATE angles")
        vel3 = _finite3((msg.vn, msg.ve, msg.vd), "SIM_STATE velocity")
        return TruthSample(sysid, t_boot_s, euler, vel3)
    if name == "SERVO_OUTPUT_RAW":
        pwm = tuple(
            int(getattr(msg, f"servo{i}_raw", 0) or 0) for i in range(1, SERVO_CHANNELS + 1)
        )
        return ControlSample(sysid, t_boot_s, pwm)
    if name == "EKF_STATUS_REPORT":
        flags = int(msg.flags)
        horiz = bool(flags & EKF_VELOCITY_HORIZ) and not flags & EKF_UNINITIALIZED
        vert = bool(flags & EKF_VELOCITY_VERT) and not flags & EKF_UNINITIALIZED
        reasons = [
            r
            for r, ok in (
                ("ekf_velocity_horiz_unaided", horiz),
                ("ekf_velocity_vert_unaided", vert),
            )
            if not ok
        ]
        return AidingSample(sysid, t_boot_s, name, horiz, vert, ",".join(reasons))
    if name == "GPS_RAW_INT":
        fix = int(msg.fix_type)
        ok = fix >= GPS_FIX_3D
        v_ne = None
        vel_cmps, cog_cdeg = int(msg.vel), int(msg.cog)
        if ok and UINT16_UNKNOWN not in {vel_cmps, cog_cdeg}:
            speed_mps, course_rad = vel_cmps * 0.01, math.radians(cog_cdeg * 0.01)
            v_ne = (speed_mps * math.cos(course_rad), speed_mps * math.sin(course_rad))
        # the GPS says nothing about the vertical velocity an autopilot may take from a baro
        return AidingSample(sysid, t_boot_s, name, ok, None, "" if ok else f"gps_fix_{fix}", v_ne)
    raise ConversionError("unknown_message", f"{name} is not a sample message")
