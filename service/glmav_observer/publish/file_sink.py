"""The file sink: every record as one flat row (``records.flatten``), CSV or JSON lines.

Deterministic: rows are written in the order received, floats with ``repr`` (the
shortest round-trip form), so two runs over the same input give byte-identical files.

CSV: records of different kinds have different columns, so the CSV has the union of
the columns of every record kind (fixed, in the order below) and a ``kind`` column
(the record's ``schema``); columns a kind does not have are empty. JSON lines: one
object per line, keys in the record's own order, NaN as null.

Whole lines only: rows are buffered in memory (up to ``FLUSH_BYTES``) and written with
``os.write``; the size of the file after the last fully written buffer is remembered.
When a write fails (a full disk, a file size limit, an I/O error) the file is cut back
to that size, so it ends on a whole line, and :class:`FileSinkWriteError` says so; the
service then isolates the sink and carries on with the others.

The file is opened by :mod:`glmav_observer.publish.output_files` (never through a link;
an existing file only with ``force``). ``shared=True``: the file already exists (made by
``serve``'s parent, with the CSV header) and several workers append to it, each with
``O_APPEND`` and each buffer written under an exclusive ``flock``; a failed write cuts
the file back to its size before that buffer, so the one file ends on a whole record at
any moment, whatever the number of writers.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import io
import json
import math
import os
from pathlib import Path
from typing import Any

from glmav_observer.publish.output_files import open_existing, open_output
from glmav_observer.records import Record, flatten

#: The CSV columns, fixed so that files do not depend on which records came first.
CSV_COLUMNS: tuple[str, ...] = (
    "schema", "sysid", "config", "t_boot_s", "seq",
    "v_body_mps_u", "v_body_mps_v", "v_body_mps_w",
    "v_ned_mps_n", "v_ned_mps_e", "v_ned_mps_d",
    "lost_axis", "health", "source_config", "sigma_lost_mps", "dead_reckoned_axes",
    "sigma_ned_mps_n", "sigma_ned_mps_e", "sigma_ned_mps_d",
    "position_ned_m_n", "position_ned_m_e", "position_ned_m_d",
    "euler_rad_roll", "euler_rad_pitch", "euler_rad_yaw",
    "active_config",
    "residual_ned_mps_n", "residual_ned_mps_e", "residual_ned_mps_d",
    "test_ratio_n", "test_ratio_e", "test_ratio_d",
    "axis_state.n", "axis_state.e", "axis_state.d",
    "isolated_faults",
)  # fmt: skip


#: Buffered bytes that trigger a write (one syscall per ~64 kB, not one per row).
FLUSH_BYTES = 64 * 1024


class FileSinkError(ValueError):
    """An output path the sink cannot write (bad suffix)."""


class FileSinkWriteError(OSError):
    """Writing failed (e.g. the disk is full); the file was cut back to its last whole line."""


def _cell(x: Any) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return repr(x) if math.isfinite(x) else ""
    if isinstance(x, list | dict):
        return json.dumps(x, sort_keys=True, separators=(",", ":"))
    return str(x)


class FileSink:
    """Writes records to ``path`` (``.csv`` or ``.jsonl``); ``close`` flushes and closes.

    ``force``: overwrite an existing regular file; ``shared``: append to the existing
    file other writers append to (see the module doc)."""

    def __init__(self, path: str | Path, *, force: bool = False, shared: bool = False) -> None:
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in (".csv", ".jsonl"):
            raise FileSinkError(f"{self.path}: output must end in .csv or .jsonl")
        self._csv = suffix == ".csv"
        self.shared = shared
        self._fd: int | None = (
            open_existing(self.path, append=True) if shared else open_output(self.path, force=force)
        )
        self._buf = io.StringIO(newline="")
        #: bytes on disk that end on a whole line; rows in them
        self.committed_bytes = 0
        self.committed_rows = 0
        self.rows = 0
        self._writer = csv.writer(self._buf, lineterminator="\n")
        if self._csv and not shared:
            self._writer.writerow(CSV_COLUMNS)

    def write(self, record: Record) -> None:
        if self._fd is None:
            return
        row = flatten(record)
        if self._csv:
            self._writer.writerow([_cell(row.get(c)) for c in CSV_COLUMNS])
        else:
            clean = {
                k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in row.items()
            }
            self._buf.write(json.dumps(clean, separators=(",", ":"), allow_nan=False) + "\n")
        self.rows += 1
        if self._buf.tell() >= FLUSH_BYTES:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows; on failure cut the file to its last whole line and raise."""
        if self._fd is None:
            return
        data = self._buf.getvalue().encode("utf-8")
        self._buf.seek(0)
        self._buf.truncate(0)
        if not data:
            return
        fd = self._fd
        if self.shared:
            fcntl.flock(fd, fcntl.LOCK_EX)  # the other writers wait: no buffer is cut
        try:
            start = os.fstat(fd).st_size if self.shared else self.committed_bytes
            view = memoryview(data)
            try:
                while view:
                    n = os.write(fd, view)
                    view = view[n:]
            except OSError as err:
                self._fd = None
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, start)
                raise self._write_error(err, start) from None
        finally:
            if self.shared:
                with contextlib.suppress(OSError):
                    fcntl.flock(fd, fcntl.LOCK_UN)
            if self._fd is None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.committed_bytes += len(data)
        self.committed_rows = self.rows

    def _write_error(self, err: OSError, size: int) -> FileSinkWriteError:
        lost = self.rows - self.committed_rows
        if self.shared:
            whole = f"({size} bytes; {self.committed_rows} rows from this writer)"
        else:
            whole = f"({self.committed_rows} rows, {size} bytes)"
        return FileSinkWriteError(
            err.errno,
            f"{self.path}: write failed ({err.strerror}); the file ends at its last "
            f"whole line {whole}; {lost} rows not written",
        )

    def close(self) -> None:
        if self._fd is None:
            return
        try:
            self.flush()
        finally:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
