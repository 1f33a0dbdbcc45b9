"""The file sink: CSV with fixed columns, JSON lines, NaN as empty/null, close flushes."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from glmav_observer.publish.file_sink import CSV_COLUMNS, FileSink, FileSinkError
from glmav_observer.records import FaultEvent, HealthRecord, VelocityRecord

VEL = VelocityRecord(1, "active", 1.25, (1.0, 2.0, 3.0), (0.1, math.nan, 0.3), "d", "ok", 7,
                     "c1", 0.05)  # fmt: skip
HEALTH = HealthRecord(1, 1.3, 2, "c1", (0.01, 0.02, math.nan), (0.1, 0.2, 1.5),
                      {"n": "ok", "e": "ok", "d": "faulty"},
                      (FaultEvent("d", "bias", 1.2),), {"ATTITUDE": 100.0}, {"late": 1})  # fmt: skip


def test_csv_rows(tmp_path: Path) -> None:
    p = tmp_path / "o.csv"
    sink = FileSink(p)
    sink.write(VEL)
    sink.write(HEALTH)
    sink.close()
    rows = list(csv.DictReader(p.open()))
    assert list(rows[0]) == list(CSV_COLUMNS)
    assert rows[0]["v_ned_mps_n"] == "0.1"
    assert rows[0]["v_ned_mps_e"] == ""  # NaN
    assert rows[0]["source_config"] == "c1"
    assert rows[1]["axis_state.d"] == "faulty"
    assert json.loads(rows[1]["isolated_faults"])[0]["kind"] == "bias"


def test_jsonl_rows(tmp_path: Path) -> None:
    p = tmp_path / "o.jsonl"
    sink = FileSink(p)
    sink.write(VEL)
    sink.close()
    sink.close()  # idempotent
    (row,) = [json.loads(line) for line in p.read_text().splitlines()]
    assert row["v_ned_mps_e"] is None
    assert row["sigma_lost_mps"] == 0.05


def test_bad_suffix() -> None:
    with pytest.raises(FileSinkError, match=r"\.csv or \.jsonl"):
        FileSink("out.txt")


def test_shared_writers_append_whole_lines_to_one_file_with_one_header(tmp_path: Path) -> None:
    """``serve --workers N``: the parent makes the file (CSV header), each worker appends
    its buffers to it; no part files, every line whole, nobody's rows lost or repeated."""
    p = tmp_path / "o.csv"
    FileSink(p).close()  # the parent: the header only
    a, b = FileSink(p, shared=True), FileSink(p, shared=True)
    for i in range(300):
        (a if i % 3 else b).write(VEL if i % 2 else HEALTH)
        if i % 7 == 0:
            a.flush()
        if i % 11 == 0:
            b.flush()
    a.close()
    b.close()
    rows = list(csv.DictReader(p.open()))
    assert len(rows) == 300 and [r["schema"] for r in rows].count("glmav.velocity/1") == 150
    assert p.read_text().count("schema,sysid") == 1  # one header
    assert [f.name for f in tmp_path.iterdir()] == ["o.csv"]
    with pytest.raises(ValueError, match="cannot write: No such file"):
        FileSink(tmp_path / "missing.csv", shared=True)  # shared: made by the parent
