"""PX4 ULog files (``.ulg``), read with pyulog: PX4 1.5 to today.

Topics used (PX4 uORB message definitions; instance 0 of each: a multi-instance topic,
``sensor_gps`` of two receivers or the ``estimator_*`` of several EKF instances, gives
its first instance; data appended after a crash is read with the rest):

- ``vehicle_attitude``: ``q[0..3]`` (w, x, y, z), FRD body to NED.
- ``sensor_combined``: ``accelerometer_m_s2[0..2]`` (specific force, FRD, m/s²) and
  ``gyro_rad[0..2]`` (rad/s); ``timestamp`` is the gyro's sample time.
- ``vehicle_gps_position`` (else ``sensor_gps``): ``vel_n_m_s``, ``vel_e_m_s``, ``vel_d_m_s``,
  kept when ``fix_type`` ≥ 3 and ``vel_ned_valid``.
- ``vehicle_local_position``: ``vx``, ``vy``, ``vz`` (m/s), ``x``, ``y``, ``z`` (m), the EKF's
  estimate (the reference), kept where ``v_xy_valid`` and ``v_z_valid``.
- ``estimator_status``: ``vel_test_ratio`` (> 1: the EKF rejected a GPS velocity).
- ``vehicle_local_position_groundtruth`` (SITL): ``vx``, ``vy``, ``vz``, the simulator's truth.
- the parameters (``EKF2_GPS_DELAY``, ms; ``MAV_TYPE``, the airframe) and the info
  ``sys_name``/``ver_sw``/``ver_sw_release`` (the firmware: ``PX4 v1.13.0``).

Times: ``timestamp`` in µs of the autopilot's clock.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Any

import numpy as np

from glmav_observer.frames import euler_from_quaternion_wxyz
from glmav_observer.ingest.logfiles.streams import (
    LogError,
    LogStreams,
    UnsupportedLogError,
    finite_rows,
    sort_by_time,
)

TOPICS = [
    "vehicle_attitude",
    "sensor_combined",
    "vehicle_gps_position",
    "sensor_gps",
    "vehicle_local_position",
    "estimator_status",
    "vehicle_local_position_groundtruth",
]
#: MAVLink's MAV_TYPE (PX4's parameter of that name) -> the airframe.
_MAV_TYPES = {1: "plane", 2: "multirotor", 3: "multirotor", 4: "helicopter", 10: "rover",
              11: "boat", 12: "submarine", 13: "multirotor", 14: "multirotor",
              15: "multirotor", 19: "vtol", 20: "vtol", 21: "vtol", 22: "vtol", 23: "vtol",
              24: "vtol", 25: "vtol"}  # fmt: skip
#: PX4's GPS fix type: 3 is a 3D fix.
GPS_FIX_3D = 3
#: Parameters giving the GPS latency, with their scale to seconds.
DELAY_PARAMS: tuple[tuple[str, float], ...] = (("EKF2_GPS_DELAY", 1e-3),)


def _topic(ulog: Any, name: str) -> dict[str, np.ndarray[Any, Any]] | None:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0:
            data: dict[str, np.ndarray[Any, Any]] = d.data
            return data
    return None


def _cols(d: dict[str, np.ndarray[Any, Any]], names: list[str]) -> np.ndarray[Any, Any]:
    return np.stack([np.asarray(d[n], dtype=np.float64) for n in names], axis=1)


def firmware_name(info: dict[str, Any]) -> str:
    """``PX4 v1.13.0`` from ``ver_sw_release`` (0xMMmmpptt), else ``PX4 <git hash>``."""
    release = info.get("ver_sw_release")
    if isinstance(release, int) and release > 0:
        major, minor, patch = (release >> 24) & 0xFF, (release >> 16) & 0xFF, (release >> 8) & 0xFF
        return f"PX4 v{major}.{minor}.{patch}"
    name = str(info.get("sys_name", "PX4"))
    ver = info.get("ver_sw")
    return f"{name} {ver[:8]}" if isinstance(ver, str) and ver else name


def read_ulog(path: str | Path) -> LogStreams:
    """The streams of a PX4 ULog (:class:`LogError` if it cannot be read)."""
    from pyulog import ULog

    path = Path(path)
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # pyulog prints what it finds damaged
            ulog = ULog(str(path), message_name_filter_list=TOPICS)
    except Exception as err:  # pyulog raises what its parser hits on a damaged file
        raise LogError(f"{path}: damaged ULog: {type(err).__name__}: {err}") from err
    params = {str(k): float(v) for k, v in ulog.initial_parameters.items()}
    s = LogStreams(
        format="ulog",
        vehicle=firmware_name(ulog.msg_info_dict),
        params=params,
        vehicle_type=_MAV_TYPES.get(int(params.get("MAV_TYPE", -1)), "unknown"),
    )
    try:
        att = _topic(ulog, "vehicle_attitude")
        if att is not None:
            t = np.asarray(att["timestamp"], dtype=np.float64) * 1e-6
            q = _cols(att, [f"q[{i}]" for i in range(4)])
            ok = finite_rows("attitude", s, t, q) & (np.linalg.norm(q, axis=1) > 0.5)
            s.t_att_s, s.euler_rad = sort_by_time(t[ok], euler_from_quaternion_wxyz(q[ok]))
            s.sources["attitude"] = "vehicle_attitude"
        imu = _topic(ulog, "sensor_combined")
        if imu is not None:
            t = np.asarray(imu["timestamp"], dtype=np.float64) * 1e-6
            f = _cols(imu, [f"accelerometer_m_s2[{i}]" for i in range(3)])
            w = _cols(imu, [f"gyro_rad[{i}]" for i in range(3)])
            ok = finite_rows("imu", s, t, f, w)
            s.t_imu_s, s.f_body_mps2, s.omega_body_radps = sort_by_time(t[ok], f[ok], w[ok])
            s.sources["imu"] = "sensor_combined"
        for name in ("vehicle_gps_position", "sensor_gps"):
            gps = _topic(ulog, name)
            if gps is None:
                continue
            t = np.asarray(gps["timestamp"], dtype=np.float64) * 1e-6
            v = _cols(gps, ["vel_n_m_s", "vel_e_m_s", "vel_d_m_s"])
            fix3d = np.asarray(gps["fix_type"]) >= GPS_FIX_3D
            vel_ok = np.asarray(gps["vel_ned_valid"]) != 0
            fix = fix3d & vel_ok
            s.drop("gps_no_3d_fix", int((~fix3d).sum()))
            s.drop("gps_velocity_not_valid", int((fix3d & ~vel_ok).sum()))
            ok = fix & finite_rows("gps", s, t, v)
            s.t_gps_s, s.v_gps_ned_mps = sort_by_time(t[ok], v[ok])
            s.sources["gps"] = name
            break
        lp = _topic(ulog, "vehicle_local_position")
        if lp is not None:
            t = np.asarray(lp["timestamp"], dtype=np.float64) * 1e-6
            v = _cols(lp, ["vx", "vy", "vz"])
            p = _cols(lp, ["x", "y", "z"])
            valid = (np.asarray(lp["v_xy_valid"]) != 0) & (np.asarray(lp["v_z_valid"]) != 0)
            s.drop("ekf_invalid", int((~valid).sum()))
            ok = valid & finite_rows("ekf", s, t, v)
            s.t_ekf_s, s.v_ekf_ned_mps, s.p_ekf_ned_m = sort_by_time(t[ok], v[ok], p[ok])
            if len(s.t_ekf_s):
                s.sources["ekf"] = "vehicle_local_position"
        est = _topic(ulog, "estimator_status")
        if est is not None and "vel_test_ratio" in est:
            t = np.asarray(est["timestamp"], dtype=np.float64) * 1e-6
            r = np.asarray(est["vel_test_ratio"], dtype=np.float64)
            ok = np.isfinite(r)
            s.t_ekf_vel_ratio_s, s.ekf_vel_test_ratio = sort_by_time(t[ok], r[ok])
            s.sources["ekf_innovations"] = "estimator_status.vel_test_ratio"
        gt = _topic(ulog, "vehicle_local_position_groundtruth")
        if gt is not None:
            t = np.asarray(gt["timestamp"], dtype=np.float64) * 1e-6
            v = _cols(gt, ["vx", "vy", "vz"])
            ok = finite_rows("truth", s, t, v)
            s.t_truth_s, s.v_truth_ned_mps = sort_by_time(t[ok], v[ok])
            s.sources["truth"] = "vehicle_local_position_groundtruth"
    except KeyError as err:  # a topic without the fields of its definition in this reader
        raise UnsupportedLogError(
            path, f"field {err} in its topic (an unknown PX4 version?)"
        ) from err
    if not (len(s.t_att_s) or len(s.t_imu_s) or len(s.t_gps_s)):
        raise UnsupportedLogError(
            path, "vehicle_attitude, sensor_combined or GPS data: not a flight log"
        )
    return s
