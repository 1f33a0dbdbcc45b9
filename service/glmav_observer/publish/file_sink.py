"""The file sink: every record as one flat row (``records.flatten``), CSV or JSON lines.

Deterministic: rows are written in the order received, floats with ``repr`` (the
shortest round-trip form), so two runs over the same input give byte-identical files.

CSV: records of different kinds have different columns, so the CSV has the union of
the columns of every record kind (fixed, in the order below) and a ``kind`` column
(the record's ``schema``); columns a kind does not have are empty. JSON lines: one
object per line, keys in the record's own order, NaN as null.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import IO, Any

from glmav_observer.records import Record, flatten

#: The CSV columns, fixed so that files do not depend on which records came first.
CSV_COLUMNS: tuple[str, ...] = (
    "schema", "sysid", "config", "t_boot_s", "seq",
    "v_body_mps_u", "v_body_mps_v", "v_body_mps_w",
    "v_ned_mps_n", "v_ned_mps_e", "v_ned_mps_d",
    "lost_axis", "health", "source_config", "sigma_lost_mps",
    "position_ned_m_n", "position_ned_m_e", "position_ned_m_d",
    "euler_rad_roll", "euler_rad_pitch", "euler_rad_yaw",
    "active_config",
    "residual_ned_mps_n", "residual_ned_mps_e", "residual_ned_mps_d",
    "test_ratio_n", "test_ratio_e", "test_ratio_d",
    "axis_state.n", "axis_state.e", "axis_state.d",
    "isolated_faults",
)  # fmt: skip


class FileSinkError(ValueError):
    """An output path the sink cannot write (bad suffix)."""


def _cell(x: Any) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return repr(x) if math.isfinite(x) else ""
    if isinstance(x, list | dict):
        return json.dumps(x, sort_keys=True, separators=(",", ":"))
    return str(x)


class FileSink:
    """Writes records to ``path`` (``.csv`` or ``.jsonl``); ``close`` flushes and closes."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in (".csv", ".jsonl"):
            raise FileSinkError(f"{self.path}: output must end in .csv or .jsonl")
        self._csv = suffix == ".csv"
        self._f: IO[str] | None = self.path.open("w", encoding="utf-8", newline="")
        self.rows = 0
        if self._csv:
            self._writer = csv.writer(self._f, lineterminator="\n")
            self._writer.writerow(CSV_COLUMNS)

    def write(self, record: Record) -> None:
        if self._f is None:
            return
        row = flatten(record)
        if self._csv:
            self._writer.writerow([_cell(row.get(c)) for c in CSV_COLUMNS])
        else:
            clean = {
                k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in row.items()
            }
            self._f.write(json.dumps(clean, separators=(",", ":"), allow_nan=False) + "\n")
        self.rows += 1

    def flush(self) -> None:
        if self._f is not None:
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None
