"""The ``save`` file: written under a temporary name, renamed only when it reads back
whole (issue 18.2: Rerun writes from its own thread and a failed write never reached
the caller, so ``replay --rrd`` on a full disk reported success)."""

from __future__ import annotations

from pathlib import Path

import pytest

from glmav_observer.publish.rerun import open_rerun_sink, read_recording
from glmav_observer.publish.rerun.savefile import RrdSaveError, finish, partial_path, rrd_problem
from glmav_observer.records import TruthRecord


def _recording(path: Path, n: int = 200) -> None:
    sink = open_rerun_sink(f"save:{path}", recording_name="unit", batch_rows=50)
    for k in range(n):
        t = 0.01 * k
        sink.write(TruthRecord(1, t, (t, 0.0, 0.0), (1.0, 0.0, 0.0), (0, 0, 0), (0, 0, 0), k))
    sink.close()


@pytest.fixture(scope="module")
def whole(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("rrd") / "whole.rrd"
    _recording(path)
    return path.read_bytes()


def test_a_saved_recording_appears_only_under_its_name(tmp_path: Path) -> None:
    path = tmp_path / "rec.rrd"
    _recording(path)
    assert [p.name for p in tmp_path.iterdir()] == ["rec.rrd"]  # no temporary file left
    assert rrd_problem(path) is None
    # every truth row made it (the rename is of the finished file)
    assert len(read_recording(path)["/vehicle/1/truth/v_ned/n"]["vehicle_time"]) == 200


@pytest.mark.parametrize(
    "cut",
    [
        pytest.param(-1, id="last byte of the footer"),
        pytest.param(-16, id="inside the footer"),
        pytest.param(0.5, id="half way, inside a message"),
        pytest.param(12, id="header only"),
        pytest.param(0, id="empty"),
    ],
)
def test_a_cut_recording_is_refused_and_removed(cut: float, whole: bytes, tmp_path: Path) -> None:
    n = len(whole)
    keep = n + int(cut) if cut < 0 else int(cut * n) if cut < 1 else int(cut)
    target = tmp_path / "rec.rrd"
    partial = partial_path(target)
    partial.write_bytes(whole[:keep])
    problem = rrd_problem(partial)
    assert problem is not None and problem.startswith(("it does not read back", "it holds no"))
    with pytest.raises(RrdSaveError) as info:
        finish(partial, target)
    msg = str(info.value)
    assert msg.startswith(f"{target}: the Rerun recording was not saved: ")
    assert f"the {keep:,} bytes written were removed and no file was left there" in msg
    assert list(tmp_path.iterdir()) == []


def test_a_failed_save_leaves_an_earlier_file_as_it_was(whole: bytes, tmp_path: Path) -> None:
    target = tmp_path / "rec.rrd"
    target.write_bytes(b"an earlier recording")
    partial = partial_path(target)
    partial.write_bytes(whole)  # complete, but the writer reported an error: refused
    with pytest.raises(RrdSaveError, match="an earlier file there is left as it was"):
        finish(partial, target, write_error="Rerun's file writer failed (test)")
    assert target.read_bytes() == b"an earlier recording"
    assert [p.name for p in tmp_path.iterdir()] == ["rec.rrd"]


def test_a_directory_that_takes_no_new_file_is_refused_at_open() -> None:
    # /proc takes no new file (as a read-only file system): refused before anything runs
    with pytest.raises(ValueError, match=r"/proc/rec\.rrd: cannot write: "):
        open_rerun_sink("save:/proc/rec.rrd")
