"""The sender: one thread that makes every Rerun call, behind a bounded queue.

``submit`` never waits on a viewer in live modes: a full queue drops the batch (counted,
with a warning at 1, 10, 100, ... drops). In ``save`` mode it waits (a file does not go
away). Columns go out through Rerun's public columnar API, ``rr.send_columns`` with an
``rr.TimeColumn`` on the ``vehicle_time`` timeline: one call, one chunk, per entity.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from glmav_observer.publish.rerun.blueprint import build_blueprint, log_styles
from glmav_observer.publish.rerun.items import (
    ArrowRows,
    Batch,
    DocumentRow,
    Item,
    PoseRows,
    ScalarRows,
    Setup,
    TextRows,
)
from glmav_observer.publish.rerun.paths import TIMELINE

if TYPE_CHECKING:
    import rerun as rr

log = logging.getLogger(__name__)


@dataclass(slots=True)
class RerunStats:
    """Counters of what the sink did (all since it was opened)."""

    records: int = 0
    rows_logged: int = 0
    batches_sent: int = 0
    batches_dropped: int = 0
    rows_dropped: int = 0
    error_rows_without_truth: int = 0
    send_errors: int = 0


def time_column(t_s: npt.NDArray[np.float64]) -> rr.TimeColumn:
    """``vehicle_time`` as a duration column, rounded to the nanosecond.

    (``rr.TimeColumn(duration=float seconds)`` truncates toward zero: 0.005 s would become
    4 999 999 ns; an int64 nanosecond array passed as ``timedelta64[ns]`` is taken as is.)
    """
    import rerun as rr

    t_ns = np.rint(t_s * 1e9).astype(np.int64).astype("timedelta64[ns]")
    return rr.TimeColumn(TIMELINE, duration=t_ns)


def send_scalars(rec: rr.RecordingStream, item: ScalarRows) -> None:
    """One ``send_columns`` per entity of the group, sharing the time column.

    Each row of an entity is a batch of ``k`` scalars (its instances): an
    ``rr.ComponentColumn`` of the ``Scalars:scalars`` component partitioned in
    ``k``-long rows (what ``rr.Scalars.columns(scalars=values)`` builds from a
    (rows, k) array, without its per-call validation, a third of the cost).
    """
    import rerun as rr

    times = [time_column(item.t_s)]
    descriptor = rr.Scalars.descriptor_scalars()
    n = len(item.t_s)
    for path, values in item.columns:
        k = values.shape[1]
        flat = rr.components.ScalarBatch(np.ascontiguousarray(values, dtype=np.float64).ravel())
        offsets = np.arange(0, k * n + 1, k, dtype=np.int32)
        column = rr.ComponentColumn(descriptor, flat, offsets=offsets)
        rr.send_columns(path, indexes=times, columns=[column], recording=rec, strict=True)


def send_item(rec: rr.RecordingStream, item: Item, configs: Sequence[str]) -> int:
    """Send one item; returns its rows."""
    import rerun as rr

    if isinstance(item, ScalarRows):
        send_scalars(rec, item)
        return len(item.t_s)
    if isinstance(item, PoseRows):
        columns = rr.Transform3D.columns(translation=item.translation, quaternion=item.quaternion)
        rr.send_columns(
            item.path, indexes=[time_column(item.t_s)], columns=columns, recording=rec, strict=True
        )
        return len(item.t_s)
    if isinstance(item, ArrowRows):
        columns = rr.Arrows3D.columns(vectors=item.vectors)
        rr.send_columns(
            item.path, indexes=[time_column(item.t_s)], columns=columns, recording=rec, strict=True
        )
        return len(item.t_s)
    if isinstance(item, TextRows):
        rec.set_time(TIMELINE, duration=item.t_s)
        for text, level in item.entries:
            rec.log(item.path, rr.TextLog(text, level=level), strict=True)
        return len(item.entries)
    if isinstance(item, DocumentRow):
        rec.set_time(TIMELINE, duration=item.t_s)
        doc = rr.TextDocument(item.markdown, media_type=rr.MediaType.MARKDOWN)
        rec.log(item.path, doc, strict=True)
        return 1
    assert isinstance(item, Setup)  # the last kind of Item
    log_styles(rec, item.sysid, configs)
    rec.send_blueprint(build_blueprint(item.sysids, configs))
    return 0


_Job = Callable[["rr.RecordingStream"], object]


class Sender:
    """The thread that sends :class:`Batch` objects to one recording stream."""

    def __init__(
        self,
        recording: rr.RecordingStream,
        configs: Sequence[str],
        stats: RerunStats,
        *,
        live: bool,
        max_queued_batches: int = 64,
    ) -> None:
        self._configs = tuple(configs)
        self._stats = stats
        self._live = live
        self._queue: queue.Queue[Batch | _Job | None] = queue.Queue(maxsize=max_queued_batches)
        self._thread = threading.Thread(
            target=self._run, name="rerun-sender", args=(recording,), daemon=True
        )
        self._thread.start()

    def qsize(self) -> int:
        return self._queue.qsize()

    def submit(self, batch: Batch) -> None:
        """Queue a batch; live modes drop it when the queue is full (unless ``batch.keep``)."""
        stats = self._stats
        if self._live and not batch.keep:
            try:
                self._queue.put_nowait(batch)
            except queue.Full:
                stats.batches_dropped += 1
                stats.rows_dropped += batch.rows
                if stats.batches_dropped in (1, 10, 100) or stats.batches_dropped % 1000 == 0:
                    log.warning(
                        "rerun: viewer not keeping up, dropped %d batches (%d rows) so far",
                        stats.batches_dropped,
                        stats.rows_dropped,
                    )
                return
        else:
            try:
                self._queue.put(batch, timeout=1.0 if self._live else None)
            except queue.Full:
                stats.batches_dropped += 1
                stats.rows_dropped += batch.rows
                return
        stats.rows_logged += batch.rows

    def drain(self, timeout_s: float) -> bool:
        """Wait until everything queued so far was handed to Rerun; False on timeout."""
        done = threading.Event()
        try:
            self._queue.put(lambda _rec: done.set(), timeout=timeout_s)
        except queue.Full:
            return False
        return done.wait(timeout_s)

    def stop(self, timeout_s: float | None) -> bool:
        """Finish what is queued and stop; False if the thread is still busy after the timeout."""
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            log.warning("rerun: sender queue full at close; dropping what is queued")
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _run(self, rec: rr.RecordingStream) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            try:
                if isinstance(job, Batch):
                    for item in job.items:
                        send_item(rec, item, self._configs)
                    self._stats.batches_sent += 1
                else:
                    job(rec)
            except Exception:
                self._stats.send_errors += 1
                log.exception("rerun: logging a batch failed; carrying on")
