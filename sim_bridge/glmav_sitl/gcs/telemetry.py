"""Telemetry a ground station needs beyond the estimator's streams (MAVSDK, QGroundControl).

The simulated autopilot's own navigation solution is the truth (its controller flies on
the truth), so GLOBAL_POSITION_INT and VFR_HUD carry true values; the sensor streams
(LOCAL_POSITION_NED, ATTITUDE, IMU) carry the noisy, possibly faulty, measurements.

====================  =======  ===================================================
message               Hz       content
====================  =======  ===================================================
GLOBAL_POSITION_INT   10       lat/lon (degE7, flat earth around home), alt AMSL and
                               relative (mm), NED velocity (cm/s), heading (cdeg)
SYS_STATUS            1        gyro, accel, GPS present/enabled/healthy; PREARM_CHECK
                               set while the vehicle may arm (ground-station flight,
                               disarmed, on the ground)
HOME_POSITION         0.5      home (lat, lon, alt); also on REQUEST_MESSAGE 242 or
                               GET_HOME_POSITION (410)
EXTENDED_SYS_STATE    2        landed state (on ground, takeoff, in air, landing)
VFR_HUD               4        ground speed, heading, climb rate, altitude AMSL
====================  =======  ===================================================
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.simulator import Simulator, TruthState

from .autopilot import Autopilot

#: stream name -> (MAVLink message id, default rate Hz); SET_MESSAGE_INTERVAL changes them
GCS_STREAMS: dict[str, tuple[int, float]] = {
    "global_position_int": (33, 10.0),
    "sys_status": (1, 1.0),
    "home_position": (242, 0.5),
    "extended_sys_state": (245, 2.0),
    "vfr_hud": (74, 4.0),
}
EARTH_RADIUS_M = 6378137.0

_SENSORS = (
    mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink2.MAV_SYS_STATUS_SENSOR_GPS
)


def lat_lon_deg(sim: Simulator, north_m: float, east_m: float) -> tuple[float, float]:
    """Flat-earth latitude and longitude of a NED offset from home."""
    lat0 = sim.sitl.home_lat_deg
    lat = lat0 + math.degrees(north_m / EARTH_RADIUS_M)
    lon = sim.sitl.home_lon_deg + math.degrees(
        east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0)))
    )
    return lat, lon


def message(name: str, sim: Simulator, tr: TruthState, ap: Autopilot) -> Any:
    """The message of GCS stream ``name`` now."""
    t_ms = sim.t_us // 1000
    if name == "global_position_int":
        lat, lon = lat_lon_deg(sim, tr.p_ned_m[0], tr.p_ned_m[1])
        v = tr.v_ned_mps
        hdg = math.degrees(tr.euler_rad[2]) % 360.0
        return mavlink2.MAVLink_global_position_int_message(
            t_ms,
            round(lat * 1e7),
            round(lon * 1e7),
            round((sim.sitl.home_alt_m - tr.p_ned_m[2]) * 1000.0),
            round(-tr.p_ned_m[2] * 1000.0),
            round(v[0] * 100.0),
            round(v[1] * 100.0),
            round(v[2] * 100.0),
            round(hdg * 100.0) % 36000,
        )
    if name == "sys_status":
        prearm = (
            mavlink2.MAV_SYS_STATUS_PREARM_CHECK
            if ap.gcs_flight and not ap.armed and ap.on_ground()
            else 0
        )
        return mavlink2.MAVLink_sys_status_message(
            _SENSORS | mavlink2.MAV_SYS_STATUS_PREARM_CHECK,
            _SENSORS | prearm,
            _SENSORS | prearm,
            0,
            0,
            -1,
            -1,
            0,
            0,
            0,
            0,
            0,
            0,
        )
    if name == "home_position":
        return home_position(sim)
    if name == "extended_sys_state":
        return mavlink2.MAVLink_extended_sys_state_message(
            mavlink2.MAV_VTOL_STATE_UNDEFINED, ap.landed_state()
        )
    if name == "vfr_hud":
        v = tr.v_ned_mps
        return mavlink2.MAVLink_vfr_hud_message(
            math.hypot(v[0], v[1]),
            math.hypot(v[0], v[1]),
            round(math.degrees(tr.euler_rad[2]) % 360.0) % 360,
            0,
            sim.sitl.home_alt_m - tr.p_ned_m[2],
            -v[2],
        )
    raise KeyError(name)


def home_position(sim: Simulator) -> Any:
    s = sim.sitl
    return mavlink2.MAVLink_home_position_message(
        round(s.home_lat_deg * 1e7),
        round(s.home_lon_deg * 1e7),
        round(s.home_alt_m * 1000.0),
        0.0,
        0.0,
        0.0,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        sim.t_us,
    )


def statustext(severity: int, text: str) -> Any:
    """A STATUSTEXT (text truncated to the message's 50 characters)."""
    return mavlink2.MAVLink_statustext_message(severity, text[:50].encode("ascii", "replace"))
