"""``batch``'s pure helpers: log ids, fault text and fault windows, folder expansion, the
report's escaping. (The batch itself: tests/integration/glmav_observer/test_batch.py.)"""

from __future__ import annotations

from pathlib import Path

from glmav_observer.commands.batch import expand_paths, log_ids
from glmav_observer.commands.batch_log import _fault_text
from glmav_observer.commands.batch_report import _fault_windows, _html


def test_log_ids_are_unique_for_repeated_file_names() -> None:
    files = [Path("a/flight.BIN"), Path("b/flight.BIN"), Path("c/other.ulg"), Path("d/flight.BIN")]
    assert log_ids(files) == ["flight.BIN", "flight.BIN-2", "other.ulg", "flight.BIN-3"]


def test_faults_isolated_together_are_grouped_and_windows_end_at_recovery() -> None:
    faults = [
        {"axis": "n", "kind": "freeze", "t_detect_s": 10.5},
        {"axis": "e", "kind": "freeze", "t_detect_s": 10.5},
        {"axis": "d", "kind": "bias", "t_detect_s": 30.25},
    ]
    switches = [
        {"t_boot_s": 10.5, "reason": "freeze_n"},
        {"t_boot_s": 14.0, "reason": "recovered"},
        {"t_boot_s": 30.25, "reason": "bias_d"},
    ]
    assert _fault_text(faults, t_start=10.0) == "n, e freeze at 0.50 s; d bias at 20.25 s"
    # the first two end at the recovery at 14 s; the bias is never recovered: log's end
    assert _fault_windows(faults, switches, t_end=40.0) == [
        (10.5, 14.0, "n freeze"),
        (10.5, 14.0, "e freeze"),
        (30.25, 40.0, "d bias"),
    ]


def test_folders_keep_only_logs_and_named_files_are_kept(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + bytes(8))
    (tmp_path / "notes.txt").write_text("campaign notes\n")
    (tmp_path / ".hidden.ulg").write_bytes(b"ULog\x01\x12\x35\x01")
    named = tmp_path / "notes.txt"
    files, skipped = expand_paths([str(tmp_path), str(named)])
    assert files == [tmp_path / "sub" / "a.ulg", named]
    assert skipped == 1  # notes.txt inside the folder; the hidden file is not looked at


def test_report_escapes_what_comes_from_files() -> None:
    row = {"log_id": "<b>x</b>.ulg", "path": "p", "format": "ulog", "error": "bad <script>"}
    page = _html([{"row": row, "table": None, "png": None}])
    assert "<script>" not in page and "bad &lt;script&gt;" in page
    assert "&lt;b&gt;x&lt;/b&gt;.ulg" in page
