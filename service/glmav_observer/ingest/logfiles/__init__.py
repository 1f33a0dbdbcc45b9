"""Recorded logs: recognised by content, and autopilot flight logs turned into typed samples.

:func:`detect_format` looks at a file's first bytes, never its name:

- ``ulog``: PX4 ULog, magic ``ULog`` 0x01 0x12 0x35;
- ``dataflash``: ArduPilot binary dataflash, a message header 0xA3 0x95 then the FMT
  message's type 0x80;
- ``dataflash-text``: ArduPilot's text dump (``.log``), a first line ``FMT, ...``;
- ``tlog``: MAVLink telemetry log, an 8-byte time stamp then a MAVLink 1 (0xFE) or 2
  (0xFD) frame; an empty file is an empty ``tlog``.

:func:`read_flight_log` reads a ULog or dataflash log into a :class:`FlightLog`: the samples
of :mod:`glmav_observer.ingest.samples` in the order the estimator takes them, the
autopilot's own EKF velocity (the reference) and the simulator truth when present.

Velocity measurement (``velocity_source``): ``gps`` (default), the receiver's velocity,
independent of the IMU; or ``ekf``, the autopilot's EKF velocity (which has already fused
the IMU, so the observer then mostly reproduces it). GPS samples are moved to their time
of validity ``t − delay`` and all samples sorted by that time: offline the log is whole, so
each measurement is fused at its own time exactly. The delay comes from the log's
parameters (``EKF2_GPS_DELAY``, ``GPS1_DELAY_MS``, ...), else is estimated
(:mod:`.latency`), else is 0 (the summary says which).

Attitude is logged at 10-50 Hz, the IMU faster: the attitude is interpolated at the IMU
times (yaw unwrapped), which offline is exact to the interpolation error instead of the
zero-order hold's half-period lag.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from glmav_observer.ingest.logfiles.latency import (
    earth_acceleration_mps2,
    estimate_gps_delay_s,
)
from glmav_observer.ingest.logfiles.streams import (
    F64,
    LogError,
    LogStreams,
    UnsupportedLogError,
    interp_euler,
)
from glmav_observer.ingest.samples import (
    AttitudeSample,
    ImuSample,
    ImuSource,
    Sample,
    TruthSample,
    VelocitySample,
)

__all__ = [
    "FlightLog",
    "LogError",
    "LogFormat",
    "LogStreams",
    "UnsupportedLogError",
    "VelocitySource",
    "detect_format",
    "read_flight_log",
]

LogFormat = Literal["tlog", "dataflash", "dataflash-text", "ulog"]
VelocitySource = Literal["gps", "ekf"]
VELOCITY_SOURCES: tuple[str, ...] = ("gps", "ekf")

ULOG_MAGIC = b"ULog\x01\x12\x35"
DATAFLASH_MAGIC = b"\xa3\x95\x80"
#: Truth is logged at up to 400 Hz (SIM2); the metrics need no more than this.
TRUTH_MAX_RATE_HZ = 50.0
#: The system id given to a flight log's vehicle (a log holds one vehicle).
LOG_SYSID = 1


def detect_format(path: str | Path) -> LogFormat:
    """The log's format from its first bytes (:class:`LogError` when none matches)."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            head = f.read(64)
    except OSError as err:
        raise LogError(f"{path}: cannot read ({err.strerror})") from err
    if not head:
        return "tlog"  # an empty file: a telemetry log that recorded nothing (replays 0 messages)
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    if head.lstrip().startswith(b"FMT,"):
        return "dataflash-text"
    if len(head) > 8 and head[8] in (0xFD, 0xFE):
        return "tlog"
    raise LogError(
        f"{path}: not a log this reads (first bytes {head[:8].hex(' ')}): expected a MAVLink "
        ".tlog, an ArduPilot dataflash .bin/.log or a PX4 .ulg"
    )


@dataclass
class FlightLog:
    """An autopilot log ready for the estimator."""

    path: Path
    format: LogFormat
    streams: LogStreams
    velocity_source: VelocitySource
    gps_delay_s: float
    #: where the delay came from: "parameter NAME", "estimated", "given", "none" (no GPS
    #: or not estimable: 0 used) or "not used" (velocity from the EKF)
    gps_delay_source: str
    samples: list[Sample] = field(default_factory=list)
    #: the EKF's velocity: times (s) and NED velocities (m/s)
    t_reference_s: F64 = field(default_factory=lambda: np.zeros(0))
    v_reference_ned_mps: F64 = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def vehicle(self) -> str:
        return self.streams.vehicle

    def duration_s(self) -> float:
        t0, t1 = self.streams.span_s()
        return t1 - t0


def _delay_from_params(s: LogStreams) -> tuple[float, str] | None:
    from glmav_observer.ingest.logfiles.dataflash import DELAY_PARAMS as DF_PARAMS
    from glmav_observer.ingest.logfiles.ulog import DELAY_PARAMS as UL_PARAMS

    for name, scale in (*UL_PARAMS, *DF_PARAMS):
        value = s.params.get(name)
        if value is not None and value > 0:
            return value * scale, f"parameter {name}"
    return None


def read_streams(path: str | Path, fmt: LogFormat | None = None) -> tuple[LogFormat, LogStreams]:
    """Detect and read a ULog or dataflash log."""
    fmt = fmt or detect_format(path)
    if fmt not in ("ulog", "dataflash", "dataflash-text"):
        raise LogError(
            f"{path}: a {fmt} is replayed through MAVLink ingest, not read as a flight log"
        )
    try:
        if fmt == "ulog":
            from glmav_observer.ingest.logfiles.ulog import read_ulog

            return fmt, read_ulog(path)
        from glmav_observer.ingest.logfiles.dataflash import read_dataflash

        return fmt, read_dataflash(path, text=fmt == "dataflash-text")
    except LogError:
        raise
    except Exception as err:  # the parsers raise whatever a damaged byte leads them to
        what = "ULog" if fmt == "ulog" else "dataflash log"
        raise LogError(f"{path}: damaged {what}: {type(err).__name__}: {err}") from err


def missing_streams(s: LogStreams, velocity_source: str) -> str:
    """What the estimator needs that the log lacks, named with the messages looked for ("")."""
    ulog = s.format == "ulog"
    if len(s.t_imu_s) == 0:
        return "IMU data (sensor_combined)" if ulog else "IMU data (IMU message)"
    if len(s.t_att_s) == 0:
        return "attitude (vehicle_attitude)" if ulog else "attitude (ATT or AHR2 message)"
    if velocity_source == "gps" and len(s.t_gps_s) == 0:
        where = "vehicle_gps_position or sensor_gps" if ulog else "GPS message"
        why = ", ".join(f"{k} {v}" for k, v in s.dropped.items() if k.startswith("gps_"))
        return (
            f"GPS velocity with a 3D fix ({where}{': ' + why if why else ''}); "
            "--velocity-source ekf measures with the EKF's velocity instead"
        )
    if velocity_source == "ekf" and len(s.t_ekf_s) == 0:
        return (
            "EKF velocity (vehicle_local_position)" if ulog else "EKF velocity (XKF1, NKF1 or EKF1)"
        )
    return ""


def read_flight_log(
    path: str | Path,
    velocity_source: VelocitySource = "gps",
    *,
    gps_delay_s: float | None = None,
) -> FlightLog:
    """Read a ULog or dataflash log into samples (see the module docstring)."""
    if velocity_source not in VELOCITY_SOURCES:
        raise ValueError(f"velocity source must be gps or ekf, got {velocity_source!r}")
    fmt, s = read_streams(path)
    missing = missing_streams(s, velocity_source)
    if missing:
        raise UnsupportedLogError(path, missing)
    if velocity_source == "ekf":
        delay, source = 0.0, "not used"
    elif gps_delay_s is not None:
        delay, source = float(gps_delay_s), "given"
    elif (p := _delay_from_params(s)) is not None:
        delay, source = p
    else:
        a = earth_acceleration_mps2(s.t_imu_s, s.f_body_mps2, s.t_att_s, s.euler_rad)
        est = estimate_gps_delay_s(s.t_imu_s, a, s.t_gps_s, s.v_gps_ned_mps)
        delay, source = (est.delay_s, "estimated") if est is not None else (0.0, "none")
    log = FlightLog(
        Path(path), fmt, s, velocity_source, delay, source, t_reference_s=s.t_ekf_s,
        v_reference_ned_mps=s.v_ekf_ned_mps,
    )  # fmt: skip
    log.samples = _samples(s, velocity_source, delay)
    return log


def _samples(s: LogStreams, velocity_source: VelocitySource, delay_s: float) -> list[Sample]:
    """Every sample, sorted by time of validity (attitude, IMU, velocity, truth at a tie)."""
    keyed: list[tuple[float, int, Sample]] = []
    sid = LOG_SYSID
    t_imu = s.t_imu_s
    in_span = (t_imu >= s.t_att_s[0]) & (t_imu <= s.t_att_s[-1])
    euler_at_imu = interp_euler(t_imu, s.t_att_s, s.euler_rad)
    f_l = s.f_body_mps2.tolist()
    w_l = s.omega_body_radps.tolist()
    e_l = euler_at_imu.tolist()
    for i, t in enumerate(t_imu.tolist()):
        w = (w_l[i][0], w_l[i][1], w_l[i][2])
        if in_span[i]:
            keyed.append((t, 0, AttitudeSample(sid, t, (e_l[i][0], e_l[i][1], e_l[i][2]), w)))
        f = (f_l[i][0], f_l[i][1], f_l[i][2])
        keyed.append((t, 1, ImuSample(sid, t, f, w, ImuSource.HIGHRES_IMU)))
    nan3 = (float("nan"),) * 3
    if velocity_source == "gps":
        for t, v in zip(s.t_gps_s.tolist(), s.v_gps_ned_mps.tolist(), strict=True):
            tv = t - delay_s
            keyed.append((tv, 2, VelocitySample(sid, tv, nan3, (v[0], v[1], v[2]))))
    else:
        for t, v, p in zip(
            s.t_ekf_s.tolist(), s.v_ekf_ned_mps.tolist(), s.p_ekf_ned_m.tolist(), strict=True
        ):
            keyed.append((t, 2, VelocitySample(sid, t, (p[0], p[1], p[2]), (v[0], v[1], v[2]))))
    if len(s.t_truth_s):
        t_att = s.t_truth_att_s if len(s.t_truth_att_s) else s.t_att_s
        eul = s.euler_truth_rad if len(s.t_truth_att_s) else s.euler_rad
        keep = _decimate(s.t_truth_s, 1.0 / TRUTH_MAX_RATE_HZ)
        tt = s.t_truth_s[keep]
        e_t = interp_euler(tt, t_att, eul).tolist()
        for k, (t, v) in enumerate(zip(tt.tolist(), s.v_truth_ned_mps[keep].tolist(), strict=True)):
            e = (e_t[k][0], e_t[k][1], e_t[k][2])
            keyed.append((t, 3, TruthSample(sid, t, e, (v[0], v[1], v[2]))))
    keyed.sort(key=lambda x: (x[0], x[1]))
    return [x[2] for x in keyed]


def _decimate(t: F64, min_step_s: float) -> np.ndarray[tuple[int], np.dtype[np.bool_]]:
    """Mask keeping the first sample of each ``min_step_s`` bin of time (jitter-proof)."""
    if len(t) == 0:
        return np.zeros(0, dtype=bool)
    bins = np.floor((t - t[0]) / min_step_s)
    keep = np.ones(len(t), dtype=bool)
    keep[1:] = bins[1:] != bins[:-1]
    return keep
