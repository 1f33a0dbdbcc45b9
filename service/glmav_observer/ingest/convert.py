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
    ControlSample,
    Sample,
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


@dataclass(frozen=True, slots=True)
class RawImuScale:
    """Scales of ``RAW_IMU`` counts for one vehicle (ArduPilot: 1 LSB = 1 mG, 1 mrad/s)."""

    accel_mps2_per_lsb: float = MG_TO_MPS2
    gyro_radps_per_lsb: float = MRAD_TO_RAD


#: Beyond any IMU's range (high-g MEMS accelerometers: ±200 g; gyros: ±4000 °/s): a value
#: above these is corruption, not a measurement, and one would poison the estimate.
IMU_MAX_F_MPS2 = 2000.0
IMU_MAX_OMEGA_RADPS = 70.0


class ConversionError(ValueError):
    """A message that cannot become a sample (reason names the counter)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def to_sample(msg: Any, t_boot_s: float, raw_scale: RawImuScale) -> Sample:
    """Convert one message decoded by pymavlink (a low-rate one of ``SAMPLE_MESSAGES``:
    ``SERVO_OUTPUT_RAW``, ``EKF_STATUS_REPORT``, ``GPS_RAW_INT``) stamped at ``t_boot_s``.

    The high-rate messages (``ATTITUDE``, the IMU messages, ``LOCAL_POSITION_NED``,
    ``SIM_STATE``) are decoded by :mod:`glmav_observer.ingest.fastframe` into objects that
    convert themselves by the rules above (``FastMessage.sample``: :class:`ConversionError`
    ``nan_field``, ``implausible``, ``imu_absent`` for one that cannot be used;
    ``LOCAL_POSITION_NED`` keeps NaN velocities, a dropout is data).
    """
    name = msg.get_type()
    sysid = int(msg.get_srcSystem())
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
        # vel_acc (mm/s; MAVLink 2 extension, 0 or absent: unknown)
        vel_acc_mmps = int(getattr(msg, "vel_acc", 0) or 0)
        sigma = vel_acc_mmps * 1e-3 if v_ne is not None and vel_acc_mmps > 0 else None
        # the GPS says nothing about the vertical velocity an autopilot may take from a baro
        return AidingSample(
            sysid, t_boot_s, name, ok, None, "" if ok else f"gps_fix_{fix}", v_ne, sigma
        )
    raise ConversionError("unknown_message", f"{name} is not a sample message")
