"""``max_vehicles`` for the whole service when ``serve --workers N`` splits the fleet.

Each worker's :class:`~glmav_observer.ingest.pipeline.Ingest` admits the vehicles routed
to it; alone, each would apply ``[ingest] max_vehicles`` to its own share, so N workers
admitted N times the cap (issue 31 D12: 16 of 255 churning system ids with the default 8
and 2 workers, and rate requests sent to all of them). :class:`SharedAdmission` is one
table of admitted system ids in shared memory, created by the parent and handed to every
worker: a vehicle is admitted while fewer than ``max_vehicles`` are, in all workers
together. A worker that evicts an idle vehicle of its own (the ingest's rule) frees its
slot first. The table is one byte per system id (0-255) plus the count, under one lock:
an admission attempt is a few hundred nanoseconds, and only a vehicle not yet admitted
makes one.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from multiprocessing import resource_tracker
from typing import Any

#: system ids 0-255, and the count of admitted ones at index 256
_SLOTS = 256


def start_resource_tracker_ignoring_sighup() -> None:
    """Start multiprocessing's resource tracker (the process that owns the table's lock's
    semaphore) with SIGHUP ignored. It ignores SIGINT and SIGTERM itself but not SIGHUP,
    which a closed terminal sends to the whole process group: it died, and at the
    service's clean stop a new tracker printed a KeyError traceback for the semaphore it
    had never seen. An ignored signal stays ignored across the tracker's exec."""
    if not hasattr(signal, "SIGHUP") or threading.current_thread() is not threading.main_thread():
        resource_tracker.ensure_running()
        return
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        resource_tracker.ensure_running()
    finally:
        signal.signal(signal.SIGHUP, previous)


class SharedAdmission:
    """The service's admitted vehicles, shared by its worker processes (picklable to a
    ``spawn`` child as a :class:`multiprocessing.Process` argument)."""

    def __init__(self, max_vehicles: int, ctx: Any = None) -> None:
        ctx = ctx if ctx is not None else multiprocessing.get_context("spawn")
        self.max_vehicles = max_vehicles
        start_resource_tracker_ignoring_sighup()
        self._table = ctx.Array("i", _SLOTS + 1, lock=True)

    def acquire(self, sysid: int) -> bool:
        """Admit ``sysid`` (True), or refuse it: the service holds ``max_vehicles``."""
        with self._table.get_lock():
            table = self._table.get_obj()
            if table[sysid]:
                return True
            if table[_SLOTS] >= self.max_vehicles:
                return False
            table[sysid] = 1
            table[_SLOTS] += 1
            return True

    def release(self, sysid: int) -> None:
        """``sysid`` left its worker (evicted): its slot is free."""
        with self._table.get_lock():
            table = self._table.get_obj()
            if table[sysid]:
                table[sysid] = 0
                table[_SLOTS] -= 1

    def admitted(self) -> int:
        with self._table.get_lock():
            return int(self._table.get_obj()[_SLOTS])
