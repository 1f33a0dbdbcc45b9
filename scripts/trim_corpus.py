"""Trim the ArduPilot SITL corpus (``../shared/data/ardupilot-sitl``) into the repo's test data.

Keeps only the messages the service and the corpus tests use, as tlog records (8-byte time
stamp + the frame's original bytes, so CRCs and signatures are unchanged), xz-compressed,
and the sidecar JSON as it is. Run from the repo root:

    python scripts/trim_corpus.py ../shared/data/ardupilot-sitl tests/data/ardupilot_sitl

``--multi-imu`` also keeps the second and third IMU (SCALED_IMU2, SCALED_IMU3), as the
held-out corpus does:

    python scripts/trim_corpus.py --multi-imu RAW_DIR tests/data/ardupilot_sitl_heldout

``--aero`` keeps only what the lost-axis benchmark reads (the wind tuning flights):

    python scripts/trim_corpus.py --aero RAW_DIR tests/data/ardupilot_sitl_wind
"""

from __future__ import annotations

import argparse
import lzma
import shutil
import sys
from pathlib import Path

from pymavlink import mavutil

KEEP = frozenset(
    {
        "HEARTBEAT",
        "ATTITUDE",
        "RAW_IMU",
        "SCALED_IMU2",  # the vehicle's other IMUs: accelerometer faults (imu_monitor)
        "SCALED_IMU3",
        "LOCAL_POSITION_NED",
        "SIM_STATE",
        "GPS_RAW_INT",
        "EKF_STATUS_REPORT",
        "STATUSTEXT",
    }
)
#: the other IMUs an ArduPilot sends: in KEEP now (imu_monitor); ``--multi-imu`` is kept
#: for the recipes that name it
MULTI_IMU = frozenset({"SCALED_IMU2", "SCALED_IMU3"})
#: ``--aero``: what the lost-axis benchmark reads (benchmarks/aero.py: the service's
#: inputs and the truth), for flights kept for it alone (tests/data/ardupilot_sitl_wind)
AERO = frozenset({"HEARTBEAT", "ATTITUDE", "RAW_IMU", "LOCAL_POSITION_NED", "SIM_STATE"})


def trim(src: Path, dst: Path, keep: frozenset[str] = KEEP) -> tuple[int, int]:
    mlog = mavutil.mavlink_connection(str(src), robust_parsing=True)
    out = bytearray()
    kept = total = 0
    while True:
        m = mlog.recv_match()
        if m is None:
            break
        total += 1
        if m.get_type() not in keep:
            continue
        t_us = round(m._timestamp * 1e6)
        out += t_us.to_bytes(8, "big") + m.get_msgbuf()
        kept += 1
    dst.write_bytes(lzma.compress(bytes(out), preset=9 | lzma.PRESET_EXTREME))
    return kept, total


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument(
        "--multi-imu", action="store_true", help="also keep SCALED_IMU2 and SCALED_IMU3"
    )
    ap.add_argument("--aero", action="store_true", help="keep only what benchmarks/aero.py reads")
    a = ap.parse_args()
    keep = AERO if a.aero else (KEEP | MULTI_IMU if a.multi_imu else KEEP)
    a.dst.mkdir(parents=True, exist_ok=True)
    for tlog in sorted(a.src.glob("*.tlog")):
        kept, total = trim(tlog, a.dst / (tlog.name + ".xz"), keep)
        shutil.copyfile(tlog.with_suffix(".json"), a.dst / tlog.with_suffix(".json").name)
        size = (a.dst / (tlog.name + ".xz")).stat().st_size
        print(f"{tlog.name}: kept {kept} of {total} messages, {size / 1e6:.2f} MB xz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
