"""Derive the small test fixtures in tests/data/public-logs/ from ../shared/data/public-logs/.

Run once by hand (``python scripts/trim_public_logs.py``); the outputs are committed.

- ArduCopter dataflash (.BIN): only the message types the log reader uses (plus the
  format, unit and parameter messages), SIM2 truth decimated from 400 Hz to 50 Hz. The
  messages are copied byte for byte (walked with the lengths their FMT messages give), so
  the result is a valid dataflash log that any reader parses.
- PX4 ULog: only the topics the reader uses, rewritten with pyulog's ``write_ulog``.

Both are gzip-compressed; tests decompress them into a temporary directory.

``python scripts/trim_public_logs.py --matrix RAW_DIR [FILE...]`` derives the compatibility matrix's
logs (tests/data/public-logs/matrix.toml; each entry's ``raw`` file, fetched from the
public repository it names, in RAW_DIR) into tests/data/public-logs/matrix/, xz-compressed:
dataflash logs keep the messages any generation's reader uses (instance 0 of the IMU and
GPS, every EKF core), ULogs the topics the reader uses, telemetry logs are kept whole. An
entry with ``text_of`` is the text dump (``.log``) of another entry's trimmed binary log.
Given FILE names (matrix.toml's ``file``), only those entries are derived.
"""

from __future__ import annotations

import gzip
import lzma
import struct
import sys
import tomllib
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
#: The matrix's dataflash logs: every generation's messages (ArduPilot 3.1 to today).
MATRIX_DATAFLASH_KEEP = DATAFLASH_KEEP | {
    "EKF1", "EKF4", "NKF4", "XKF4", "AHR2", "POS",
}  # fmt: skip
#: Of these, only instance 0 (the ``I`` field) is kept.
FIRST_INSTANCE_ONLY = {"IMU", "GPS"}
MATRIX_ULOG_TOPICS = [*ULOG_TOPICS, "estimator_status", "vehicle_local_position_groundtruth"]
MANIFEST = DST / "matrix.toml"
MATRIX_DST = DST / "matrix"


def _instance_offset(fmt: str, columns: list[str]) -> int | None:
    """Byte offset (after the 3-byte header) of the ``I`` column, None without one."""
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    if "I" not in columns:
        return None
    k = columns.index("I")
    return struct.calcsize("<" + "".join(FORMAT_TO_STRUCT[c][0] for c in fmt[:k]))


def trim_dataflash(
    data: bytes, keep_names: set[str] = DATAFLASH_KEEP, first_instance: frozenset[str] = frozenset()
) -> bytes:
    lengths = {0x80: 89}
    names = {0x80: "FMT"}
    inst_ofs: dict[int, int | None] = {}
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
            fmt = msg[9:25].rstrip(b"\0").decode()
            cols = msg[25:89].rstrip(b"\0").decode().split(",")
            inst_ofs[t] = _instance_offset(fmt, cols) if names[t] in first_instance else None
        name = names[mtype]
        keep = name in keep_names
        if keep and (ofs := inst_ofs.get(mtype)) is not None:
            keep = msg[3 + ofs] == 0
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


def dataflash_as_text(data: bytes) -> str:
    """ArduPilot's text dump (``FMT, ...`` lines, then ``NAME, v1, v2, ...``) of a binary log."""
    import tempfile

    from pymavlink import DFReader

    with tempfile.NamedTemporaryFile(suffix=".bin") as f:
        f.write(data)
        f.flush()
        reader = DFReader.DFReader_binary(f.name, zero_time_base=False)
        lines: list[str] = []
        seen: set[str] = set()
        while (m := reader.recv_msg()) is not None:
            fm = m.fmt
            if fm.name in ("FMT", "FMTU", "UNIT", "MULT"):
                continue
            if fm.name not in seen:
                lines.append(
                    f"FMT, {fm.type}, {fm.len}, {fm.name}, {fm.format}, {','.join(fm.columns)}"
                )
                seen.add(fm.name)
            lines.append(f"{fm.name}, " + ", ".join(str(getattr(m, c)) for c in fm.columns))
    return "\n".join(lines) + "\n"


def trim_matrix(raw_dir: Path, only: frozenset[str] = frozenset()) -> None:
    """The matrix's logs (see the module docstring) from the raw files in ``raw_dir``;
    with ``only``, just the entries of those files (the others are left as they are)."""
    import tempfile

    from glmav_observer.ingest.logfiles import detect_format

    MATRIX_DST.mkdir(parents=True, exist_ok=True)
    entries = tomllib.loads(MANIFEST.read_text())["log"]
    trimmed: dict[str, bytes] = {}
    for e in entries:
        if "raw" not in e or (only and e["file"] not in only):
            continue  # a text dump (below), or an entry not asked for
        src = raw_dir / e["raw"]
        fmt = detect_format(src)
        if fmt == "dataflash":
            out = trim_dataflash(
                src.read_bytes(), MATRIX_DATAFLASH_KEEP, frozenset(FIRST_INSTANCE_ONLY)
            )
        elif fmt == "ulog":
            from pyulog import ULog

            with tempfile.TemporaryDirectory() as tmp:
                dst = Path(tmp) / "t.ulg"
                ULog(str(src), message_name_filter_list=MATRIX_ULOG_TOPICS).write_ulog(str(dst))
                out = dst.read_bytes()
        else:
            out = src.read_bytes()
        trimmed[e["file"]] = out
        (MATRIX_DST / f"{e['file']}.xz").write_bytes(lzma.compress(out, preset=9))
    for e in entries:
        if "text_of" in e and (not only or e["file"] in only):
            text = dataflash_as_text(trimmed[e["text_of"]]).encode()
            (MATRIX_DST / f"{e['file']}.xz").write_bytes(lzma.compress(text, preset=9))
    for p in sorted(MATRIX_DST.glob("*.xz")):
        print(f"{p.name}: {p.stat().st_size} bytes")


def main() -> int:
    if len(sys.argv) >= 3 and sys.argv[1] == "--matrix":
        trim_matrix(Path(sys.argv[2]), frozenset(sys.argv[3:]))
        return 0
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
