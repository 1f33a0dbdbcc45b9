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

Idle vehicles of other workers. With the service full, a newcomer takes the slot of the
vehicle heard longest ago, in any worker, once that one has been silent for
``evict_idle_s`` (what one process does: it evicts its idle vehicle for the newcomer).
Each worker tells the table when its vehicles are heard (:meth:`SharedAdmission.heard`,
at most every half ``evict_idle_s`` and at most once a second per vehicle, under the
lock); the worker whose idle vehicle lost its slot learns it at that vehicle's next
message (``heard`` says False) and evicts it too. Before, a worker could evict only its
own vehicles: a worker whose share of the fleet came later (it started a moment after
the other, or its vehicles came up after the others' had gone silent) had its vehicles
refused for as long as the other worker's idle ones held every slot — a storm of spoofed
system ids at start locked a real vehicle out for good (found by the fuzz over ``serve``
in the default worker mode, ``benchmarks/fuzz_ingest.py --serve``).
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
        #: host time (monotonic, shared by the processes) each admitted id was last heard
        self._heard = ctx.Array("d", _SLOTS, lock=False)

    def acquire(self, sysid: int) -> bool:
        """Admit ``sysid`` (True), or refuse it: the service holds ``max_vehicles``."""
        return self.admit(sysid)[0]

    def admit(
        self, sysid: int, t_host_s: float | None = None, evict_idle_s: float | None = None
    ) -> tuple[bool, int | None]:
        """Admit ``sysid`` (True), or refuse it: the service holds ``max_vehicles`` and,
        given ``evict_idle_s``, none of them has been silent that long at ``t_host_s``;
        else the one heard longest ago loses its slot to ``sysid``: (True, its id)."""
        with self._table.get_lock():
            table = self._table.get_obj()
            heard = self._heard
            if table[sysid]:
                return True, None
            taken = None
            if table[_SLOTS] >= self.max_vehicles:
                if t_host_s is None or evict_idle_s is None:
                    return False, None
                idle = min((s for s in range(_SLOTS) if table[s]), key=heard.__getitem__)
                if t_host_s - heard[idle] < evict_idle_s:
                    return False, None
                table[idle] = 0  # its worker learns it at the idle vehicle's next message
                table[_SLOTS] -= 1
                taken = idle
            table[sysid] = 1
            table[_SLOTS] += 1
            if t_host_s is not None:
                heard[sysid] = t_host_s
            return True, taken

    def heard(self, sysid: int, t_host_s: float) -> bool:
        """``sysid`` was heard at ``t_host_s``; False when it no longer holds a slot (a
        newcomer of another worker took it while it was idle)."""
        with self._table.get_lock():
            if not self._table.get_obj()[sysid]:
                return False
            self._heard[sysid] = t_host_s
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
