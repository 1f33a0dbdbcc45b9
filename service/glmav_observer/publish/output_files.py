"""Opening an output file the user named, without following links (issue 31, D6).

Every output (``--out``, ``--rrd``, ``--rerun save:PATH``) is a regular file this
process creates, or, with ``force``, an existing regular file it overwrites:

- a symbolic link is refused, with or without ``force`` (``O_NOFOLLOW``: a link planted
  at the output's name cannot redirect the write to another file);
- anything else that is not a regular file (a FIFO, a device, a directory, a socket) is
  refused: a FIFO would block the process, a device would be written to;
- a regular file with other hard links is refused (it is someone else's file too);
- an existing regular file is refused unless ``force`` (``--force``): a mistyped name
  must not overwrite an earlier result;
- a new file is created with ``O_EXCL``, so it is the file this process made.

Every refusal is an :class:`OutputFileError` naming the path and the reason; the
commands print it and exit 2.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from pathlib import Path

from glmav_toml import file_kind


class OutputFileError(ValueError):
    """An output path that is refused (the message names it and says why)."""


def _refuse_existing(path: Path, st: os.stat_result, force: bool) -> None:
    """Raise for an existing ``path`` (``st``: its ``lstat``) that may not be overwritten."""
    if not stat.S_ISREG(st.st_mode):
        raise OutputFileError(
            f"{path}: is {file_kind(st.st_mode)}: refused (an output is a regular file it creates)"
        )
    if st.st_nlink > 1:
        raise OutputFileError(f"{path}: has {st.st_nlink} hard links: refused")
    if not force:
        raise OutputFileError(f"{path}: exists: refused (--force to overwrite it)")


def check_output_target(path: str | Path, *, force: bool = False) -> None:
    """Refuse ``path`` as the target of a file written elsewhere and renamed into place
    (the ``.rrd``): its directory must exist and take new files, and an existing entry
    must be a regular file that ``force`` allows overwriting."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise OutputFileError(f"{p}: directory {parent} does not exist (it is not created)")
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        st = None
    except OSError as err:
        raise OutputFileError(f"{p}: cannot write: {err.strerror}") from None
    if st is not None:
        _refuse_existing(p, st, force)
        return
    os.close(open_output(p))  # the directory takes a new file there (then removed)
    p.unlink(missing_ok=True)


def open_output(path: str | Path, *, force: bool = False) -> int:
    """A descriptor open for writing on ``path``, a new empty regular file (or, with
    ``force``, an existing one truncated); :class:`OutputFileError` when refused."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise OutputFileError(f"{p}: directory {parent} does not exist (it is not created)")
    flags = os.O_WRONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        return os.open(p, flags | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        pass
    except OSError as err:
        raise OutputFileError(f"{p}: cannot write: {err.strerror}") from None
    try:
        st = os.lstat(p)
    except OSError as err:
        raise OutputFileError(f"{p}: cannot write: {err.strerror}") from None
    _refuse_existing(p, st, force)
    return open_existing(p, truncate=True, expect=st)


def open_existing(
    path: str | Path,
    *,
    truncate: bool = False,
    append: bool = False,
    expect: os.stat_result | None = None,
) -> int:
    """Open the existing regular file ``path`` for writing, never through a link
    (``append``: ``O_APPEND``); ``expect``: its ``lstat``, which the opened file must be
    (not replaced in between)."""
    p = Path(path)
    flags = os.O_WRONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    if append:
        flags |= os.O_APPEND
    try:
        fd = os.open(p, flags)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise OutputFileError(f"{p}: is a symbolic link: refused") from None
        raise OutputFileError(f"{p}: cannot write: {err.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise OutputFileError(f"{p}: is {file_kind(st.st_mode)}: refused")
        if expect is not None and (st.st_dev, st.st_ino) != (expect.st_dev, expect.st_ino):
            raise OutputFileError(f"{p}: was replaced while being opened: refused")
        if truncate:
            os.ftruncate(fd, 0)
        os.set_blocking(fd, True)
    except BaseException:
        with contextlib.suppress(OSError):
            os.close(fd)
        raise
    return fd
