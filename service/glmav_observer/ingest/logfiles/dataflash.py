"""ArduPilot dataflash logs (binary ``.bin`` and text ``.log``), read with pymavlink's DFReader.

Messages used (ArduPilot's log message reference; units as logged):

- ``ATT``: Roll, Pitch, Yaw in degrees (ZYX Euler angles of the AHRS), about 10 Hz.
- ``IMU`` (instance ``I`` = 0, the primary IMU): GyrX..Z rad/s, AccX..Z m/s², FRD, specific
  force (AccZ ≈ −9.8 at rest).
- ``GPS`` (instance 0): Spd (horizontal speed, m/s), GCrs (course over ground, degrees from
  north), VZ (vertical speed, m/s, positive down: AP_GPS logs the NED velocity's z),
  Status (3 = 3D fix or better). North = Spd cos(GCrs), east = Spd sin(GCrs).
- ``XKF1`` (EKF3) or ``NKF1`` (EKF2), core ``C`` = ``EK3_PRIMARY``/``EK2_PRIMARY``: VN, VE,
  VD m/s, PN, PE, PD m: the EKF's own estimate, used as the reference.
- ``SIM2`` (SITL only): VN, VE, VD m/s, the simulator's truth; ``SIM``: its attitude, deg.
- ``PARM``: parameters (the GPS latency: ``GPS1_DELAY_MS``/``GPS_DELAY_MS``, ``EK2_GPS_DELAY``).
- ``MSG``: the first text naming the firmware (``ArduCopter V4.6.0 ...``) names the vehicle.
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
    LogError,
    LogStreams,
    finite_rows,
    sort_by_time,
)

_TYPES = ("ATT", "IMU", "GPS", "XKF1", "NKF1", "SIM", "SIM2", "PARM", "MSG")
_DEG = math.pi / 180.0
#: ArduPilot's GPS fix status: 3 is a 3D fix (4 DGPS, 5 RTK float, 6 RTK fixed).
GPS_FIX_3D = 3


def _open(path: Path, text: bool) -> Any:
    from pymavlink import DFReader

    if text:
        return DFReader.DFReader_text(str(path), zero_time_base=False)
    return DFReader.DFReader_binary(str(path), zero_time_base=False)


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
    except Exception as err:  # DFReader raises whatever its parser hits on a damaged header
        raise LogError(f"{path}: damaged dataflash log: {type(err).__name__}: {err}") from err
    att: list[tuple[float, float, float, float]] = []
    imu: list[tuple[float, ...]] = []
    gps: list[tuple[float, float, float, float]] = []
    ekf: dict[str, dict[int, list[tuple[float, ...]]]] = {"XKF1": {}, "NKF1": {}}
    sim: list[tuple[float, float, float, float]] = []
    sim2: list[tuple[float, float, float, float]] = []
    params: dict[str, float] = {}
    vehicle = ""
    gps_no_fix = 0
    try:
        while True:
            m = reader.recv_match(type=list(_TYPES))
            if m is None:
                break
            name = m.get_type()
            t = m.TimeUS * 1e-6
            if name == "IMU":
                if getattr(m, "I", 0) == 0:
                    imu.append((t, m.AccX, m.AccY, m.AccZ, m.GyrX, m.GyrY, m.GyrZ))
            elif name == "ATT":
                att.append((t, m.Roll * _DEG, m.Pitch * _DEG, m.Yaw * _DEG))
            elif name == "GPS":
                if getattr(m, "I", 0) != 0:
                    continue
                if m.Status < GPS_FIX_3D:
                    gps_no_fix += 1
                    continue
                crs = m.GCrs * _DEG
                gps.append((t, m.Spd * math.cos(crs), m.Spd * math.sin(crs), m.VZ))
            elif name in ("XKF1", "NKF1"):
                core = int(getattr(m, "C", 0))
                ekf[name].setdefault(core, []).append((t, m.VN, m.VE, m.VD, m.PN, m.PE, m.PD))
            elif name == "SIM2":
                sim2.append((t, m.VN, m.VE, m.VD))
            elif name == "SIM":
                sim.append((t, m.Roll * _DEG, m.Pitch * _DEG, m.Yaw * _DEG))
            elif name == "PARM":
                params[str(m.Name)] = float(m.Value)
            elif name == "MSG" and not vehicle:
                text_msg = str(m.Message)
                if text_msg.startswith(("Ardu", "APM", "Rover", "Blimp")):
                    vehicle = text_msg.split(" (", maxsplit=1)[0].strip()
    except LogError:
        raise
    except Exception as err:  # a truncated or damaged message body
        raise LogError(f"{path}: damaged dataflash log: {type(err).__name__}: {err}") from err
    if not (att or imu or gps):
        raise LogError(f"{path}: no ATT, IMU or GPS messages: not a flight log this reads")
    s = LogStreams(format="dataflash", vehicle=vehicle or "ArduPilot", params=params)
    s.drop("gps_no_3d_fix", gps_no_fix)
    if att:
        a = np.asarray(att)
        ok = finite_rows("attitude", s, a)
        s.t_att_s, s.euler_rad = sort_by_time(a[ok, 0], a[ok, 1:4])
        s.sources["attitude"] = "ATT"
    if imu:
        a = np.asarray(imu)
        ok = finite_rows("imu", s, a)
        s.t_imu_s, s.f_body_mps2, s.omega_body_radps = sort_by_time(
            a[ok, 0], a[ok, 1:4], a[ok, 4:7]
        )
        s.sources["imu"] = "IMU[0]"
    if gps:
        a = np.asarray(gps)
        ok = finite_rows("gps", s, a)
        s.t_gps_s, s.v_gps_ned_mps = sort_by_time(a[ok, 0], a[ok, 1:4])
        s.sources["gps"] = "GPS[0] (Spd, GCrs, VZ)"
    name = "XKF1" if ekf["XKF1"] else "NKF1"
    if ekf[name]:
        primary_param = "EK3_PRIMARY" if name == "XKF1" else "EK2_PRIMARY"
        core = int(params.get(primary_param, 0))
        rows = ekf[name].get(core) or ekf[name][min(ekf[name])]
        a = np.asarray(rows)
        ok = finite_rows("ekf", s, a)
        s.t_ekf_s, s.v_ekf_ned_mps, s.p_ekf_ned_m = sort_by_time(a[ok, 0], a[ok, 1:4], a[ok, 4:7])
        s.sources["ekf"] = f"{name} core {core}"
    if sim2:
        a = np.asarray(sim2)
        ok = finite_rows("truth", s, a)
        s.t_truth_s, s.v_truth_ned_mps = sort_by_time(a[ok, 0], a[ok, 1:4])
        s.sources["truth"] = "SIM2"
        if sim:
            b = np.asarray(sim)
            s.t_truth_att_s, s.euler_truth_rad = sort_by_time(b[:, 0], b[:, 1:4])
    return s


#: Parameters giving the GPS latency, in the order they are trusted, with their scale to s.
#: ``GPSn_DELAY_MS`` = 0 means "the driver's default": not a value, so it is skipped.
DELAY_PARAMS: tuple[tuple[str, float], ...] = (
    ("GPS1_DELAY_MS", 1e-3),
    ("GPS_DELAY_MS", 1e-3),
    ("EK3_GPS_DELAY", 1e-3),
    ("EK2_GPS_DELAY", 1e-3),
)
