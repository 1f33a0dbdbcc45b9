"""ArduPilot dataflash logs (binary ``.bin`` and text ``.log``), read with pymavlink's DFReader.

Every generation since ArduPilot 3.1 (2014): the reader looks at the formats (FMT) the log
declares and takes each stream from the message that carries it (units as logged).

- Time: ``TimeUS`` (µs since boot, from 3.3/3.4) or ``TimeMS`` (ms, before); the old
  ``GPS`` message's ``TimeMS`` is the GPS time of week, its boot time is ``T`` (ms). A
  log whose messages carry no boot time (ArduCopter 3.0) is unsupported.
- Attitude: ``ATT`` Roll, Pitch, Yaw in degrees, else ``AHR2`` (the DCM backup AHRS).
- IMU: ``IMU`` instance ``I`` = 0 (before 4.0 the instances were ``IMU``, ``IMU2``,
  ``IMU3``: ``IMU`` is the first); GyrX..Z rad/s, AccX..Z m/s², FRD, specific force.
- GPS: ``GPS`` instance 0 (``I`` = 0, or the message ``GPS`` before ``GPS2`` existed as an
  instance): Spd (horizontal speed, m/s), GCrs (course over ground, degrees from north),
  VZ (vertical speed, m/s, positive down), Status (3 = 3D fix or better).
  North = Spd cos(GCrs), east = Spd sin(GCrs).
- Reference, the first present of: ``XKF1`` (EKF3), ``NKF1`` (EKF2), ``EKF1`` (the
  EKF of 3.1-3.4), core ``C`` = ``EK3_PRIMARY``/``EK2_PRIMARY`` (VN, VE, VD m/s, PN, PE,
  PD m); the one ``AHRS_EKF_TYPE`` selects when several are logged. Without any EKF, the
  AHRS position ``POS`` (Lat, Lng, Alt) differentiated over ``POS_DIFF_WINDOW_S``.
- The EKF's velocity innovation test ratio ``SV`` of ``XKF4``/``NKF4``/``EKF4`` (> 1: a
  GPS velocity rejected).
- ``SIM2`` (SITL only): VN, VE, VD m/s, the simulator's truth; ``SIM``: its attitude, deg.
- ``PARM``: parameters (the GPS latency: ``GPS1_DELAY_MS``/``GPS_DELAY_MS``, ``EK2_GPS_DELAY``;
  the airframe: ``Q_ENABLE``, ``FRAME_CLASS``, the helicopter's ``H_*``).
- ``MSG``: the first text naming the firmware (``ArduCopter V4.6.0 ...``, ``APM:Copter
  V3.3 ...``) names the vehicle.

A log that lacks a stream the estimator needs is refused by :func:`read_flight_log` with
"unsupported: this log has no X"; "damaged" is kept for bytes the parser cannot decode.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from glmav_observer.ingest.logfiles.streams import (
    F64,
    LogError,
    LogStreams,
    UnsupportedLogError,
    finite_rows,
    sort_by_time,
)

_DEG = math.pi / 180.0
#: ArduPilot's GPS fix status: 3 is a 3D fix (4 DGPS, 5 RTK float, 6 RTK fixed).
GPS_FIX_3D = 3
#: The EKF generations, newest first, with their innovation message and primary parameter.
_EKFS = (("XKF1", "XKF4", "EK3_PRIMARY"), ("NKF1", "NKF4", "EK2_PRIMARY"), ("EKF1", "EKF4", ""))
#: ``AHRS_EKF_TYPE`` -> the message of the EKF it selects.
_EKF_BY_TYPE = {3: "XKF1", 2: "NKF1", 1: "EKF1"}
#: The AHRS position is differentiated over this span (s): its Lat/Lng resolution (1e-7°,
#: about 1 cm) over 1 s gives a velocity resolution of about 0.01 m/s.
POS_DIFF_WINDOW_S = 1.0
_EARTH_RADIUS_M = 6_378_137.0
_FIELDS = {
    "IMU": ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"),
    "ATT": ("Roll", "Pitch", "Yaw"),
    "AHR2": ("Roll", "Pitch", "Yaw"),
    "GPS": ("Status", "Spd", "GCrs", "VZ"),
    "XKF1": ("VN", "VE", "VD", "PN", "PE", "PD"),
    "NKF1": ("VN", "VE", "VD", "PN", "PE", "PD"),
    "EKF1": ("VN", "VE", "VD", "PN", "PE", "PD"),
    "XKF4": ("SV",),
    "NKF4": ("SV",),
    "EKF4": ("SV",),
    "POS": ("Lat", "Lng", "Alt"),
    "SIM": ("Roll", "Pitch", "Yaw"),
    "SIM2": ("VN", "VE", "VD"),
    "PARM": ("Name", "Value"),
    "MSG": ("Message",),
}


def _open(path: Path, text: bool) -> Any:
    from pymavlink import DFReader

    if text:
        return DFReader.DFReader_text(str(path), zero_time_base=False)
    return DFReader.DFReader_binary(str(path), zero_time_base=False)


def _declared(reader: Any) -> dict[str, list[str]]:
    """The message types the log holds (at least one message), with their columns."""
    out: dict[str, list[str]] = {}
    counts = reader.counts
    for name, mid in reader.name_to_id.items():
        fmt = reader.formats.get(mid) or reader.formats.get(name)
        n = counts.get(name, 0) if isinstance(counts, dict) else counts[mid]
        if fmt is not None and n:
            out[name] = list(fmt.columns)
    if isinstance(counts, dict):  # the text reader: formats and counts by name
        for name, n in counts.items():
            fmt = reader.formats.get(name)
            if fmt is not None and n:
                out[name] = list(fmt.columns)
    return out


def _time_field(name: str, cols: list[str]) -> tuple[str, float] | None:
    """The boot-time column of a message and its scale to s (None: the message has none)."""
    if "TimeUS" in cols:
        return "TimeUS", 1e-6
    if name == "GPS" and "T" in cols:  # before 3.3 GPS.TimeMS was the GPS time of week
        return "T", 1e-3
    if "TimeMS" in cols and name != "GPS":
        return "TimeMS", 1e-3
    return None


def _numeric_getter(fmt: Any, name: str, time_field: str, columns: list[str]) -> Any:
    """A function giving a message's time, its ``_FIELDS`` and its instance/core (0 when the
    format has none) as floats, scaled exactly as pymavlink's attribute access scales them
    (its ``__getattr__`` costs a third of the reading: this reads ``_elements`` directly)."""
    extra = {"IMU": "I", "GPS": "I"}.get(name) or ("C" if name[1:] in ("KF1", "KF4") else "")
    fields = [time_field, *_FIELDS[name], *([extra] if extra else [])]
    idx = [fmt.colhash[f] if f in columns else -1 for f in fields]
    mults = [fmt.msg_mults[i] if i >= 0 else None for i in idx]
    # pymavlink divides by 1/m for 0 < m < 1 (more exact for 1e-2, 1e-7): the same here
    divs = [1.0 / mu if mu is not None and 0.0 < mu < 1.0 else None for mu in mults]
    plan = list(zip(idx, mults, divs, strict=True))

    def get(m: Any) -> list[float]:
        e = m._elements
        scale = m._apply_multiplier
        out = []
        for i, mu, dv in plan:
            if i < 0:
                out.append(0.0)
                continue
            x = float(e[i])
            if mu is not None and scale:
                x = x / dv if dv is not None else x * mu
            out.append(x)
        return out

    return get


def vehicle_type(firmware: str, params: dict[str, float]) -> str:
    """The airframe from the firmware's name and its parameters."""
    fw = firmware.lower()
    if "plane" in fw:
        return "vtol" if params.get("Q_ENABLE", 0) >= 1 else "plane"
    if "copter" in fw or "heli" in fw:
        heli = "heli" in fw or params.get("FRAME_CLASS") == 6 or "H_SWASH_TYPE" in params
        return "helicopter" if heli or "H_SW_TYPE" in params else "multirotor"
    if "sub" in fw:
        return "submarine"
    if "rover" in fw:
        return "boat" if params.get("FRAME_CLASS") == 2 else "rover"
    if "blimp" in fw:
        return "blimp"
    return "unknown"


def read_dataflash(path: str | Path, *, text: bool = False) -> LogStreams:
    """The streams of an ArduPilot dataflash log (:class:`LogError` if it cannot be read)."""
    path = Path(path)
    noise = io.StringIO()
    try:
        with _captured_output(noise):
            s = _read(path, text)
    except LogError as err:
        reports = noise.getvalue().count("\n")
        if not reports or "damaged" in str(err):
            raise
        raise LogError(f"{err} (damaged: pymavlink reported {reports} bad blocks)") from err
    # what DFReader printed about a damaged log: counted here, not printed
    printed = noise.getvalue()
    s.drop("dataflash_messages_not_parsed", printed.count("Failed to parse "))
    s.drop("dataflash_bad_headers", printed.count("bad header "))
    s.drop(
        "dataflash_bad_bytes_skipped",
        sum(int(n) for n in re.findall(r"Skipped (\d+) bad bytes", printed)),
    )
    return s


@contextlib.contextmanager
def _captured_output(into: io.StringIO) -> Iterator[None]:
    """What is printed on stdout and stderr inside, by Python or by C code (pymavlink's
    indexer writes to the descriptors), goes to ``into`` (read as it is written: a
    damaged log can make it print a line per bad block)."""
    import tempfile

    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            with contextlib.redirect_stdout(into), contextlib.redirect_stderr(into):
                yield
        finally:
            for fd, old in ((1, saved[0]), (2, saved[1])):
                os.dup2(old, fd)
                os.close(old)
            tmp.seek(0)
            into.write(tmp.read().decode("utf-8", "replace"))


def _read(path: Path, text: bool) -> LogStreams:
    """:func:`read_dataflash`, its output captured by the caller."""
    try:
        reader = _open(path, text)
        declared = _declared(reader)
    except Exception as err:  # DFReader raises whatever its parser hits on a damaged header
        raise LogError(f"{path}: damaged dataflash log: {type(err).__name__}: {err}") from err
    usable = {n: c for n, c in declared.items() if set(_FIELDS.get(n, ("?",))) <= set(c)}
    times = {n: tc for n, c in usable.items() if (tc := _time_field(n, c)) is not None}
    timed = {n for n in times if n in ("ATT", "AHR2", "IMU", "GPS")}
    if not timed and any(n in declared for n in ("ATT", "IMU", "GPS")):
        raise UnsupportedLogError(
            path, "boot time stamps (TimeUS or TimeMS; ArduPilot logs them from 3.1)"
        )
    att_name = next((n for n in ("ATT", "AHR2") if n in times), "")
    ekf_names = [e for e, _, _ in _EKFS if e in times]
    wanted = {"PARM", "MSG", "IMU", "GPS", "SIM", "SIM2", att_name, *ekf_names}
    wanted |= {r for e, r, _ in _EKFS if e in ekf_names}
    if not ekf_names:
        wanted.add("POS")
    types = sorted(n for n in wanted if n in usable and (n in times or n in ("PARM", "MSG")))
    rows: dict[str, list[tuple[float, ...]]] = {n: [] for n in types}
    params: dict[str, float] = {}
    firmware = ""
    gps_no_fix = 0
    imu_inst = "I" in usable.get("IMU", [])
    gps_inst = "I" in usable.get("GPS", [])
    getters: dict[str, Any] = {}
    try:
        while True:
            m = reader.recv_match(type=types)
            if m is None:
                break
            name = m.fmt.name
            if name == "PARM":
                params[str(m.Name)] = float(m.Value)
                continue
            if name == "MSG":
                if not firmware:
                    text_msg = str(m.Message)
                    if text_msg.startswith(("Ardu", "APM", "Rover", "Blimp")):
                        firmware = text_msg.split(" (", maxsplit=1)[0].strip()
                continue
            get = getters.get(name)
            if get is None:
                get = getters[name] = _numeric_getter(m.fmt, name, times[name][0], usable[name])
            v = get(m)  # time (in the log's unit), the fields of _FIELDS, then instance/core
            t = v[0] * times[name][1]
            if name == "IMU":
                if not imu_inst or v[7] == 0:
                    rows[name].append((t, v[4], v[5], v[6], v[1], v[2], v[3]))
            elif name == "GPS":
                if gps_inst and v[5] != 0:
                    continue
                if v[1] < GPS_FIX_3D:
                    gps_no_fix += 1
                    continue
                crs = v[3] * _DEG
                rows[name].append((t, v[2] * math.cos(crs), v[2] * math.sin(crs), v[4]))
            elif name in ("XKF1", "NKF1", "EKF1"):
                rows[name].append((t, v[7], v[1], v[2], v[3], v[4], v[5], v[6]))
            elif name in ("XKF4", "NKF4", "EKF4"):
                rows[name].append((t, v[2], v[1]))
            elif name in ("ATT", "AHR2", "SIM"):
                rows[name].append((t, v[1] * _DEG, v[2] * _DEG, v[3] * _DEG))
            else:  # SIM2 (VN, VE, VD), POS (Lat, Lng, Alt)
                rows[name].append((t, v[1], v[2], v[3]))
    except Exception as err:  # a truncated or damaged message body
        raise LogError(f"{path}: damaged dataflash log: {type(err).__name__}: {err}") from err
    if not (rows.get(att_name) or rows.get("IMU") or rows.get("GPS")):
        raise UnsupportedLogError(path, "ATT, AHR2, IMU or GPS messages: not a flight log")
    s = LogStreams(
        format="dataflash",
        vehicle=firmware or "ArduPilot",
        params=params,
        vehicle_type=vehicle_type(firmware, params),
    )
    s.drop("gps_no_3d_fix", gps_no_fix)
    if rows.get(att_name):
        a = np.asarray(rows[att_name])
        ok = finite_rows("attitude", s, a)
        s.t_att_s, s.euler_rad = sort_by_time(a[ok, 0], a[ok, 1:4])
        s.sources["attitude"] = att_name
    if rows.get("IMU"):
        a = np.asarray(rows["IMU"])
        ok = finite_rows("imu", s, a)
        s.t_imu_s, s.f_body_mps2, s.omega_body_radps = sort_by_time(
            a[ok, 0], a[ok, 1:4], a[ok, 4:7]
        )
        s.sources["imu"] = "IMU[0]" if imu_inst else "IMU"
    if rows.get("GPS"):
        a = np.asarray(rows["GPS"])
        ok = finite_rows("gps", s, a)
        s.t_gps_s, s.v_gps_ned_mps = sort_by_time(a[ok, 0], a[ok, 1:4])
        s.sources["gps"] = "GPS[0] (Spd, GCrs, VZ)" if gps_inst else "GPS (Spd, GCrs, VZ)"
    _reference(s, rows, ekf_names)
    if rows.get("SIM2"):
        a = np.asarray(rows["SIM2"])
        ok = finite_rows("truth", s, a)
        s.t_truth_s, s.v_truth_ned_mps = sort_by_time(a[ok, 0], a[ok, 1:4])
        s.sources["truth"] = "SIM2"
        if rows.get("SIM"):
            b = np.asarray(rows["SIM"])
            s.t_truth_att_s, s.euler_truth_rad = sort_by_time(b[:, 0], b[:, 1:4])
    return s


def _reference(s: LogStreams, rows: dict[str, list[tuple[float, ...]]], ekfs: list[str]) -> None:
    """The EKF the autopilot used (or the differentiated AHRS position) into ``s``."""
    ekfs = [e for e in ekfs if rows.get(e)]
    if ekfs:
        chosen = _EKF_BY_TYPE.get(int(s.params.get("AHRS_EKF_TYPE", -1)))
        name = chosen if chosen in ekfs else ekfs[0]
        ratio_name, primary_param = next((r, p) for e, r, p in _EKFS if e == name)
        a = np.asarray(rows[name])
        cores = sorted(set(a[:, 1].astype(int).tolist()))
        core = int(s.params.get(primary_param, 0)) if primary_param else 0
        core = core if core in cores else cores[0]
        a = a[a[:, 1] == core]
        ok = finite_rows("ekf", s, a)
        s.t_ekf_s, s.v_ekf_ned_mps, s.p_ekf_ned_m = sort_by_time(a[ok, 0], a[ok, 2:5], a[ok, 5:8])
        s.sources["ekf"] = f"{name} core {core}"
        if rows.get(ratio_name):
            r = np.asarray(rows[ratio_name])
            r = r[r[:, 1] == core]
            ok = np.isfinite(r[:, 2])
            s.t_ekf_vel_ratio_s, s.ekf_vel_test_ratio = sort_by_time(r[ok, 0], r[ok, 2])
            s.sources["ekf_innovations"] = f"{ratio_name}.SV core {core}"
        return
    if rows.get("POS"):
        a = np.asarray(rows["POS"])
        ok = finite_rows("ekf", s, a)
        t, v, p = velocity_from_positions(a[ok, 0], a[ok, 1], a[ok, 2], a[ok, 3])
        s.t_ekf_s, s.v_ekf_ned_mps, s.p_ekf_ned_m = t, v, p
        s.sources["ekf"] = f"POS (AHRS position, differentiated over {POS_DIFF_WINDOW_S:g} s)"


def velocity_from_positions(
    t_s: F64, lat_deg: F64, lng_deg: F64, alt_m: F64
) -> tuple[F64, F64, F64]:
    """NED velocity by a centred difference over ``POS_DIFF_WINDOW_S`` of a position track.

    Positions in a local flat-earth NED frame at the first fix; returns (t, v, p) at the
    samples whose window lies inside the track."""
    if len(t_s) < 3:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    order = np.argsort(t_s, kind="stable")
    t, lat, lng, alt = t_s[order], lat_deg[order], lng_deg[order], alt_m[order]
    cos_lat = math.cos(float(lat[0]) * _DEG)
    p = np.stack(
        [
            (lat - lat[0]) * _DEG * _EARTH_RADIUS_M,
            (lng - lng[0]) * _DEG * _EARTH_RADIUS_M * cos_lat,
            -(alt - alt[0]),
        ],
        axis=1,
    )
    half = 0.5 * POS_DIFF_WINDOW_S
    i0 = np.searchsorted(t, t - half, side="left")
    i1 = np.searchsorted(t, t + half, side="right") - 1
    inside = (t - half >= t[0]) & (t + half <= t[-1]) & (i1 > i0)
    i0, i1 = i0[inside], i1[inside]
    v = (p[i1] - p[i0]) / (t[i1] - t[i0])[:, None]
    return t[inside], v, p[inside]


#: Parameters giving the GPS latency, in the order they are trusted, with their scale to s.
#: ``GPSn_DELAY_MS`` = 0 means "the driver's default": not a value, so it is skipped.
DELAY_PARAMS: tuple[tuple[str, float], ...] = (
    ("GPS1_DELAY_MS", 1e-3),
    ("GPS_DELAY_MS", 1e-3),
    ("EK3_GPS_DELAY", 1e-3),
    ("EK2_GPS_DELAY", 1e-3),
)
