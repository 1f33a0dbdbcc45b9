"""What a flight log holds for the estimator: time-stamped arrays in SI units, one per stream.

The readers (:mod:`.dataflash`, :mod:`.ulog`) fill a :class:`LogStreams`; everything after
that (latency, samples, summary) is format-independent. Times are the autopilot's own clock
in seconds (``TimeUS`` of dataflash, ``timestamp`` of ULog), frames are NED (earth) and FRD
(body), angles ZYX Euler (roll, pitch, yaw) in rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


class LogError(ValueError):
    """A log that cannot be read: the message names the file and the reason."""


class UnsupportedLogError(LogError):
    """A readable log that lacks what the estimator needs: "unsupported: this log has no X"."""

    def __init__(self, path: object, missing: str) -> None:
        super().__init__(f"{path}: unsupported: this log has no {missing}")
        self.missing = missing


def empty3() -> F64:
    return np.zeros((0, 3))


@dataclass
class LogStreams:
    """The streams of one flight log (arrays of equal length per stream, time ascending)."""

    format: str  # "dataflash" | "ulog"
    vehicle: str  # e.g. "ArduCopter V4.6.0-dev", "PX4 cb09dde6"
    params: dict[str, float]
    #: the airframe: multirotor, helicopter, plane, vtol, rover, boat, submarine or unknown
    vehicle_type: str = "unknown"
    t_att_s: F64 = field(default_factory=lambda: np.zeros(0))
    euler_rad: F64 = field(default_factory=empty3)
    t_imu_s: F64 = field(default_factory=lambda: np.zeros(0))
    f_body_mps2: F64 = field(default_factory=empty3)
    omega_body_radps: F64 = field(default_factory=empty3)
    #: the GPS receiver's velocity, stamped when the autopilot received it (not yet shifted)
    t_gps_s: F64 = field(default_factory=lambda: np.zeros(0))
    v_gps_ned_mps: F64 = field(default_factory=empty3)
    #: the autopilot's EKF velocity and position (its own estimate: the reference)
    t_ekf_s: F64 = field(default_factory=lambda: np.zeros(0))
    v_ekf_ned_mps: F64 = field(default_factory=empty3)
    p_ekf_ned_m: F64 = field(default_factory=empty3)
    #: simulator truth, when the log has it (ArduPilot SITL: SIM2 velocity, SIM attitude)
    t_truth_s: F64 = field(default_factory=lambda: np.zeros(0))
    v_truth_ned_mps: F64 = field(default_factory=empty3)
    t_truth_att_s: F64 = field(default_factory=lambda: np.zeros(0))
    euler_truth_rad: F64 = field(default_factory=empty3)
    #: the EKF's velocity innovation test ratio (> 1: the EKF rejected a GPS velocity)
    t_ekf_vel_ratio_s: F64 = field(default_factory=lambda: np.zeros(0))
    ekf_vel_test_ratio: F64 = field(default_factory=lambda: np.zeros(0))
    #: samples dropped while reading, by reason (no fix, non-finite value, ...)
    dropped: dict[str, int] = field(default_factory=dict)
    #: names of the log's messages/topics each stream came from (for the summary)
    sources: dict[str, str] = field(default_factory=dict)

    def drop(self, reason: str, n: int = 1) -> None:
        if n:
            self.dropped[reason] = self.dropped.get(reason, 0) + n

    def rates_hz(self) -> dict[str, float]:
        """Mean rate of each non-empty stream: (n − 1) / span."""
        out: dict[str, float] = {}
        for name, t in (
            ("attitude", self.t_att_s),
            ("imu", self.t_imu_s),
            ("gps", self.t_gps_s),
            ("ekf", self.t_ekf_s),
            ("truth", self.t_truth_s),
        ):
            if len(t) >= 2 and t[-1] > t[0]:
                out[name] = float((len(t) - 1) / (t[-1] - t[0]))
        return out

    def span_s(self) -> tuple[float, float]:
        """First and last time of any stream (0, 0 when empty)."""
        firsts = [t[0] for t in (self.t_att_s, self.t_imu_s, self.t_gps_s, self.t_ekf_s) if len(t)]
        lasts = [t[-1] for t in (self.t_att_s, self.t_imu_s, self.t_gps_s, self.t_ekf_s) if len(t)]
        if not firsts:
            return 0.0, 0.0
        return float(min(firsts)), float(max(lasts))


def finite_rows(name: str, streams: LogStreams, *arrays: Any) -> NDArray[np.bool_]:
    """Mask of rows finite in every array; the others are counted as ``nan_<name>``."""
    ok = np.ones(len(arrays[0]), dtype=bool)
    for a in arrays:
        arr = np.asarray(a, dtype=np.float64)
        ok &= np.isfinite(arr).all(axis=1) if arr.ndim == 2 else np.isfinite(arr)
    streams.drop(f"nan_{name}", int((~ok).sum()))
    return ok


def sort_by_time(t: F64, *arrays: F64) -> tuple[F64, ...]:
    """Arrays reordered by ascending ``t`` (stable), duplicates of a time kept."""
    order = np.argsort(t, kind="stable")
    return (t[order], *(a[order] for a in arrays))


def interp_euler(t_query: F64, t_att: F64, euler: F64) -> F64:
    """Euler angles interpolated at ``t_query`` (yaw unwrapped, then wrapped to ±π)."""
    unwrapped = euler.copy()
    unwrapped[:, 2] = np.unwrap(euler[:, 2])
    out = np.stack([np.interp(t_query, t_att, unwrapped[:, k]) for k in range(3)], axis=1)
    out[:, 2] = (out[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return out


#: In flight: the reference's speed above this (m/s) ...
IN_FLIGHT_SPEED_MPS = 1.0
#: ... or its height above the log's first reference height above this (m) ...
IN_FLIGHT_HEIGHT_M = 2.0
#: ... widened by this on each side (s), so that a hover between two legs stays in flight
IN_FLIGHT_MARGIN_S = 2.0


def in_flight_mask(t_s: F64, v_ned_mps: F64, p_ned_m: F64) -> NDArray[np.bool_]:
    """Reference samples taken in flight (moving or off the ground), see the constants.

    A log carries no common "airborne" flag across firmware generations; the EKF's own
    speed and height do, for every vehicle this reads (a plane on its take-off run
    counts as flying: it moves)."""
    n = len(t_s)
    if n == 0:
        return np.zeros(0, dtype=bool)
    speed = np.linalg.norm(v_ned_mps, axis=1)
    height = -(p_ned_m[:, 2] - p_ned_m[0, 2]) if len(p_ned_m) == n else np.zeros(n)
    core: NDArray[np.bool_] = (speed > IN_FLIGHT_SPEED_MPS) | (
        np.nan_to_num(height) > IN_FLIGHT_HEIGHT_M
    )
    if not core.any():
        return core
    t_core = t_s[core]
    i = np.searchsorted(t_core, t_s)
    before = np.abs(t_s - t_core[np.clip(i - 1, 0, len(t_core) - 1)])
    after = np.abs(t_core[np.clip(i, 0, len(t_core) - 1)] - t_s)
    out: NDArray[np.bool_] = np.minimum(before, after) <= IN_FLIGHT_MARGIN_S
    return out
