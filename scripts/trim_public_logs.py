"""Derive the small test fixtures in tests/data/public-logs/ from ../shared/data/public-logs/.

Run once by hand (``python scripts/trim_public_logs.py``); the outputs are committed.

- ArduCopter dataflash (.BIN): only the message types the log reader uses (plus the
  format, unit and parameter messages), SIM2 truth decimated from 400 Hz to 50 Hz. The
  messages are copied byte for byte (walked with the lengths their FMT messages give), so
  the result is a valid dataflash log that any reader parses.
- PX4 ULog: only the topics the reader uses, rewritten with pyulog's ``write_ulog``.

Both are gzip-compressed; tests decompress them into a temporary directory.
"""

from __future__ import annotations

import gzip
import struct
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO.parent / "shared" / "data" / "public-logs"
DST = REPO / "tests" / "data" / "public-logs"

DATAFLASH_KEEP = {
    "FMT", "FMTU", "UNIT", "MULT", "PARM", "VER", "MSG", "MODE", "EV",
    "ATT", "IMU", "GPS", "XKF1", "NKF1", "SIM", "SIM2",
}  # fmt: skip
SIM2_EVERY = 8  # 400 Hz -> 50 Hz
ULOG_TOPICS = [
    "vehicle_attitude",
    "sensor_combined",
    "vehicle_gps_position",
    "sensor_gps",
    "vehicle_local_position",
]


def trim_dataflash(data: bytes) -> bytes:
    lengths = {0x80: 89}
    names = {0x80: "FMT"}
    out = bytearray()
    i = 0
    n_sim2 = 0
    while i + 3 <= len(data):
        if data[i] != 0xA3 or data[i + 1] != 0x95:
            i += 1  # resynchronise on the next header
            continue
        mtype = data[i + 2]
        length = lengths.get(mtype)
        if length is None or i + length > len(data):
            i += 1
            continue
        msg = data[i : i + length]
        if mtype == 0x80:
            t, ln = msg[3], msg[4]
            lengths[t] = ln
            names[t] = struct.unpack("4s", msg[5:9])[0].rstrip(b"\0").decode()
        name = names[mtype]
        keep = name in DATAFLASH_KEEP
        if name == "SIM2":
            keep = n_sim2 % SIM2_EVERY == 0
            n_sim2 += 1
        if keep:
            out += msg
        i += length
    return bytes(out)


def trim_ulog(src: Path, dst: Path) -> None:
    from pyulog import ULog

    ULog(str(src), message_name_filter_list=ULOG_TOPICS).write_ulog(str(dst))


def main() -> int:
    DST.mkdir(parents=True, exist_ok=True)
    bin_out = trim_dataflash((SRC / "arducopter_sitl_00000001.BIN").read_bytes())
    (DST / "arducopter_sitl_trimmed.BIN.gz").write_bytes(gzip.compress(bin_out, mtime=0))
    tmp = DST / "px4_sitl_trimmed.ulg"
    trim_ulog(SRC / "px4_sitl_sample_events.ulg", tmp)
    (DST / "px4_sitl_trimmed.ulg.gz").write_bytes(gzip.compress(tmp.read_bytes(), mtime=0))
    tmp.unlink()
    for p in sorted(DST.glob("*.gz")):
        print(f"{p.name}: {p.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
