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
