"""The ``.rrd`` file of ``save`` mode: written under a temporary name, checked, renamed.

Rerun writes the file from its own thread; a write that fails there (a full disk, a
file-size limit) is logged by Rerun on stderr and never reaches the caller, and the
file left behind looks like a recording. So the recording goes to a hidden file beside
the target (``.NAME.partial-XXXXXXXX``, same directory, so the rename is atomic); at
close it must read back with Rerun's own reader *with its footer* (the manifest Rerun
writes last, after every chunk: a file cut anywhere, even between two messages, has
none), and only then is it renamed to the target. Otherwise the partial file is removed,
an earlier file at the target is left as it was, and :class:`RrdSaveError` says why.
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import rerun as rr

log = logging.getLogger(__name__)

#: ``flush_file`` gives up when the file has not grown for this long (s): when Rerun's
#: writer thread dies on a failed write, its flush can wait out its whole timeout (a
#: 600 s one, in 4 of about 100 runs under a file-size limit) instead of failing
STALL_S = 10.0


class RrdSaveError(OSError):
    """The recording could not be written completely (the message names the file and why)."""


def partial_path(target: str | Path) -> Path:
    """Create and return the hidden temporary file for ``target`` (same directory).

    Raises ``OSError`` when the directory does not take new files."""
    t = Path(target)
    p = t.with_name(f".{t.name}.partial-{secrets.token_hex(4)}")
    with p.open("xb"):  # created here, with the permissions a new file gets (umask)
        pass
    return p


def flush_file(rec: rr.RecordingStream, path: Path, stall_s: float = STALL_S) -> str | None:
    """Flush ``rec`` into its file at ``path``; what went wrong, or None.

    Waits as long as the file keeps growing (a large recording on a slow disk), and no
    longer than ``stall_s`` without a byte written."""
    size = path.stat().st_size if path.exists() else 0
    while True:
        try:
            rec.flush(timeout_sec=stall_s)
            return None
        except Exception as err:  # RuntimeError: a timeout, or a writer that died
            grown = path.stat().st_size if path.exists() else 0
            if grown == size:  # no progress: the writer is gone or stuck
                log.warning("rerun: flush at close failed: %s", err)
                return f"Rerun's file writer failed ({err})"
            size = grown


def disconnect_bounded(rec: rr.RecordingStream, timeout_s: float = STALL_S) -> None:
    """Disconnect ``rec`` after its file writer failed, waiting at most ``timeout_s``.

    After a failed write, Rerun's ``disconnect`` can wait forever (after a flush that
    timed out, as above); the file is refused anyway, so the
    disconnect is left to a daemon thread, and Rerun's exit handler, which would wait on
    the same stuck stream, is unregistered (this sink has closed its stream itself)."""
    import threading

    import rerun as rr

    th = threading.Thread(target=rec.disconnect, name="rerun-disconnect", daemon=True)
    th.start()
    th.join(timeout_s)
    if th.is_alive():
        log.warning("rerun: disconnect after a failed write is stuck; left behind")
        rr.unregister_shutdown()


def rrd_problem(path: str | Path) -> str | None:
    """Why the ``.rrd`` at ``path`` is not a complete recording, or None if it is.

    Complete: Rerun's reader opens it from its footer (``RrdReader(path).store()``), which
    Rerun writes after everything else; a cut file has no footer or a frame that runs past
    the end of the file."""
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            # rerun warns about a file without a footer ("legacy format") before raising
            warnings.simplefilter("ignore")
            reader = RrdReader(path)
            if not reader.recordings():
                return "it holds no recording"
            reader.store()
    except (RuntimeError, ValueError, OSError) as err:
        return f"it does not read back whole ({err})"
    return None


def finish(partial: Path, target: str | Path, write_error: str | None = None) -> None:
    """Rename ``partial`` to ``target`` if it is a complete recording; otherwise remove it
    and raise :class:`RrdSaveError`. ``write_error``: what Rerun reported at flush, if
    anything (the file is then refused whatever it looks like)."""
    problem = write_error or rrd_problem(partial)
    if problem is None:
        try:
            os.replace(partial, target)
            return
        except OSError as err:
            problem = f"renaming {partial.name} to it failed: {err.strerror}"
    size = partial.stat().st_size if partial.exists() else 0
    partial.unlink(missing_ok=True)
    t = Path(target)
    try:
        free = f"{shutil.disk_usage(t.parent if str(t.parent) else '.').free:,} bytes free there"
    except OSError:
        free = "free space unknown"
    kept = "an earlier file there is left as it was" if t.exists() else "no file was left there"
    raise RrdSaveError(
        f"{t}: the Rerun recording was not saved: {problem}; the {size:,} bytes written "
        f"were removed and {kept} ({free}; a full disk or a file-size limit?)"
    )
