"""Issue 31, D6: outputs never write through a link or onto a file that is not theirs.

``replay --out`` used to overwrite a symbolic link's target (10 MB into ``victim.txt``);
every refusal here is an :class:`OutputFileError` naming the path and the reason."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from glmav_observer.publish.file_sink import FileSink
from glmav_observer.publish.output_files import (
    OutputFileError,
    check_output_target,
    open_output,
)
from glmav_observer.records import VelocityRecord

VEL = VelocityRecord(1, "active", 1.25, (1.0, 2.0, 3.0), (0.1, 0.2, 0.3), "", "ok", 7, "c1", 0.05)


def test_a_symbolic_link_is_refused_even_with_force_and_its_target_is_untouched(
    tmp_path: Path,
) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    link = tmp_path / "out.jsonl"
    link.symlink_to(victim)
    dangling = tmp_path / "new.jsonl"
    dangling.symlink_to(tmp_path / "created-through-the-link.jsonl")
    for force in (False, True):
        for path in (link, dangling):
            with pytest.raises(OutputFileError, match=rf"{path}: is a symbolic link: refused"):
                FileSink(path, force=force)
            with pytest.raises(OutputFileError, match="is a symbolic link: refused"):
                check_output_target(path, force=force)
    assert victim.read_text() == "precious\n"
    assert not (tmp_path / "created-through-the-link.jsonl").exists()


def test_an_existing_regular_file_needs_force(tmp_path: Path) -> None:
    out = tmp_path / "out.jsonl"
    out.write_text("earlier result\n")
    with pytest.raises(OutputFileError, match=rf"{out}: exists: refused \(--force to overwrite"):
        FileSink(out)
    assert out.read_text() == "earlier result\n"
    sink = FileSink(out, force=True)
    sink.write(VEL)
    sink.close()
    assert out.read_text().count("\n") == 1 and '"schema":"glmav.velocity/1"' in out.read_text()
    check_output_target(out, force=True)  # a rename over it is allowed with --force


def test_what_is_not_a_regular_file_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.jsonl"
    os.mkfifo(fifo)  # opening it for writing without O_NONBLOCK waits for a reader forever
    (tmp_path / "dir.jsonl").mkdir()
    for path, kind in ((fifo, "a FIFO"), (tmp_path / "dir.jsonl", "a directory")):
        with pytest.raises(OutputFileError, match=f"is {kind}: refused"):
            FileSink(path, force=True)
        with pytest.raises(OutputFileError, match=f"is {kind}: refused"):
            check_output_target(path, force=True)


def test_a_file_with_another_hard_link_is_refused(tmp_path: Path) -> None:
    victim = tmp_path / "victim.csv"
    victim.write_text("x\n")
    out = tmp_path / "out.csv"
    os.link(victim, out)
    with pytest.raises(OutputFileError, match=f"{out}: has 2 hard links: refused"):
        FileSink(out, force=True)
    assert victim.read_text() == "x\n"


def test_a_new_file_is_created_exclusively(tmp_path: Path) -> None:
    out = tmp_path / "new.csv"
    fd = open_output(out)
    os.close(fd)
    assert out.stat().st_size == 0
    with pytest.raises(OutputFileError, match="exists"):
        open_output(out)
    with pytest.raises(OutputFileError, match="does not exist"):
        open_output(tmp_path / "no" / "x.csv")
