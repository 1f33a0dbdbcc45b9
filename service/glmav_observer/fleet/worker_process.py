"""One worker process of ``serve --workers N`` (:mod:`glmav_observer.fleet.workers`): its
own :class:`~glmav_observer.app.Service` and sinks (:class:`WorkerSpec`), fed by the
parent's batches, sending back rate requests, a latency histogram and its summary
(:class:`WorkerResult`). Workers ignore SIGINT/SIGTERM/SIGHUP: the parent stops them by
closing their pipe; a worker also reads its own socket of each UDP link the kernel routes
(:mod:`glmav_observer.fleet.reuseport`) and answers its vehicles on it.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import select
import signal
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from glmav_observer.app import DRAIN_MAX_READS, RATE_CHECK_PERIOD_S, STOP_DRAIN_S, Service
from glmav_observer.app_sinks import open_sinks
from glmav_observer.app_summary import ServiceSummary
from glmav_observer.config import ServiceConfig
from glmav_observer.fleet.admission import SharedAdmission
from glmav_observer.fleet.latency import LatencyHistogram
from glmav_observer.fleet.reuseport import attach_program
from glmav_observer.fleet.routing import datagram_sysid, worker_of_sysid
from glmav_observer.ingest.links import Link

logger = logging.getLogger(__name__)


class WorkerError(RuntimeError):
    """A worker could not start (its sinks failed to open); the message says why."""


@dataclass(frozen=True)
class WorkerSpec:
    """What a worker needs to build its Service and sinks (picklable)."""

    index: int
    config: ServiceConfig
    out: str | None
    zenoh_config: str | None
    zenoh_enabled: bool | None
    rerun_mode: str | None
    claim: bool = False
    log_level: str = "INFO"
    #: how many workers share the fleet (the routing rule's n)
    workers: int = 1
    log_format: str = "text"
    #: overwrite an existing Rerun save file (``--force``)
    force: bool = False


@dataclass
class WorkerResult:
    index: int
    summary: ServiceSummary
    latency: LatencyHistogram
    batches: int
    items: int
    cpu_s: float = 0.0  # the worker's CPU time (user + system), s
    wall_s: float = 0.0  # from ready to stop, s


def worker_rerun_mode(mode: str | None, index: int) -> str | None:
    """The Rerun mode of worker ``index`` for the user's ``mode`` (see the module doc)."""
    if mode is None or mode == "off":
        return mode
    if mode.startswith("save:"):
        p = Path(mode[5:])
        return "save:" + str(p.with_name(f"{p.stem}.w{index}{p.suffix or '.rrd'}"))
    if mode.startswith("connect"):
        return mode
    raise WorkerError(
        f"--rerun {mode}: with several workers Rerun can only save:PATH (one file per "
        "worker) or connect:URL; use --workers 1 for spawn or serve"
    )


def worker_main(
    spec: WorkerSpec,
    inbox: multiprocessing.connection.Connection,
    outbox: multiprocessing.connection.Connection,
    sockets: dict[str, socket.socket] | None = None,
    admission: SharedAdmission | None = None,
) -> None:
    """A worker process: its own Service and sinks, fed by the parent's batches and, for
    the UDP links the kernel routes (``sockets``: link id -> this worker's socket of the
    group, :mod:`glmav_observer.fleet.reuseport`), by its own reads."""
    from glmav_observer.logs import configure_logging

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a closed terminal: the parent stops us
    configure_logging(spec.log_level, spec.log_format)
    direct = {lid: Link(lid, sock=s) for lid, s in (sockets or {}).items()}
    try:
        if spec.index > 0:  # wait until worker 0 has checked the service id on Zenoh
            try:
                if inbox.recv() != "go":
                    return
            except EOFError:  # the parent gave up starting
                return
        service = build_service(spec, admission)
    except Exception as err:  # reported to the parent, which exits 2 with it
        outbox.send(("error", str(err)))
        return
    outbox.send(("ready", os.getpid()))
    loop = _WorkerLoop(spec, service, outbox, direct)
    try:
        loop.run(inbox)
    finally:
        service.close()
        for lk in direct.values():
            lk.close()
    result = WorkerResult(
        spec.index,
        service.summary(),
        loop.latency,
        loop.batches,
        loop.items,
        cpu_s=time.process_time() - loop.cpu0,
        wall_s=time.monotonic() - loop.wall0,
    )
    with contextlib.suppress(BrokenPipeError, OSError):  # the parent may be gone
        outbox.send(("result", result))


class _WorkerLoop:
    """A worker's loop: the parent's batches, its own sockets, rate requests, answers."""

    def __init__(
        self,
        spec: WorkerSpec,
        service: Service,
        outbox: multiprocessing.connection.Connection,
        direct: dict[str, Link],
    ) -> None:
        self.spec = spec
        self.service = service
        self.outbox = outbox
        self.direct = direct
        self.latency = LatencyHistogram()
        self.batches = self.items = 0
        self.cpu0, self.wall0 = time.process_time(), time.monotonic()

    def run(self, inbox: multiprocessing.connection.Connection) -> None:
        service, latency, clock = self.service, self.latency, time.monotonic
        by_fd: dict[int, tuple[str, Link]] = {}
        for lid, lk in self.direct.items():
            fd = lk.fileno()
            assert fd is not None  # a UDP socket: never down
            by_fd[fd] = (lid, lk)
        inbox_fd = inbox.fileno()
        n_vehicles = 0
        next_rate_check = clock()
        stop = False
        while not stop:
            try:
                ready, _, _ = select.select([inbox_fd, *by_fd], [], [], 0.05)
            except InterruptedError:
                continue
            for fd in ready:
                if fd != inbox_fd:
                    self._read(*by_fd[fd], DRAIN_MAX_READS)
                    continue
                try:
                    batch = inbox.recv()
                except EOFError:
                    batch = None
                if batch is None:  # the parent stops us: what our sockets hold is read
                    stop = True
                    break
                if isinstance(batch, tuple):  # ("reattach", link): see fleet/reuseport.py
                    self._reattach(batch[1])
                    continue
                self.batches += 1
                for link_id, t_arrival_s, data, peer in batch:
                    service.current_peer = peer
                    service.feed_bytes(link_id, data, t_arrival_s, datagram=True)
                    latency.add(clock() - t_arrival_s)
                self.items += len(batch)
            now = clock()
            nv = len(service.ingest.vehicles)
            if nv != n_vehicles or now >= next_rate_check:
                if now >= next_rate_check:
                    service.kernel_drops.check(self.direct)
                n_vehicles = nv
                service.rate_requests(now)
                next_rate_check = now + RATE_CHECK_PERIOD_S
            self._answer()
        deadline = time.monotonic() + STOP_DRAIN_S
        for lid, lk in self.direct.items():
            while time.monotonic() < deadline and self._read(lid, lk, 64, at_stop=True):
                pass
        service.kernel_drops.check(self.direct)
        self._answer()
        # the rates set on our own sockets' vehicles back to what they were (the parent's
        # links are closed by now: a TCP or serial link with rate requests runs in one
        # process by default, which restores them itself)
        service.restore_rates(self.direct, clock)

    def _reattach(self, lid: str) -> None:
        """Attach the routing program to the group of ``lid`` again: a foreign socket
        joined it and may have replaced ours (:class:`~glmav_observer.fleet.reuseport.
        PortGuard`)."""
        lk = self.direct.get(lid)
        fd = lk.fileno() if lk is not None else None
        if fd is None:
            return
        with socket.socket(fileno=os.dup(fd)) as sock:  # the same socket, our own fd
            try:
                attach_program(sock, self.spec.workers)
            except OSError as err:
                self.service.counters["routing_program_reattach_failed"] += 1
                logger.warning("routing program not attached again: %s", err)
                return
        self.service.counters["routing_program_reattached"] += 1

    def _read(self, lid: str, lk: Link, max_reads: int, *, at_stop: bool = False) -> int:
        """Read and estimate up to ``max_reads`` datagrams of a kernel-routed link; those
        of another worker's vehicle (bytes before the header hid its system id from the
        kernel's program) go to their owner through the parent. Returns datagrams read."""
        service, clock = self.service, time.monotonic
        n_workers, me = self.spec.workers, self.spec.index
        foreign = []
        # up to max_reads datagrams, UDP_DRAIN_BATCH a system call (ingest/udp_drain.pyx)
        got = lk.read_datagrams(max_reads)
        for data, arrival_s, peer in got:
            if not data:
                continue
            t = clock()
            sysid = datagram_sysid(data)
            if (0 if sysid is None else worker_of_sysid(sysid, n_workers)) != me:
                foreign.append((lid, t, data, peer))
                continue
            service.current_peer = peer
            service.feed_bytes(lid, data, t, datagram=True)
            # from the kernel's receive stamp: the wait in the socket's queue counts
            self.latency.add(clock() - arrival_s)
            self.items += 1
        if foreign:
            if at_stop:  # the parent no longer routes: counted, not lost silently
                service.counters["datagrams_rerouted_too_late"] += len(foreign)
            else:
                with contextlib.suppress(BrokenPipeError, OSError):
                    self.outbox.send(("route", foreign))
                service.counters["datagrams_rerouted"] += len(foreign)
        return len(got)

    def _answer(self) -> None:
        """Send what the service queued (rate requests): on our own socket for a
        kernel-routed link, else through the parent, which holds the link."""
        service = self.service
        if not service.outbox:
            return
        via_parent = []
        for lid, frame, peer in service.outbox:
            lk = self.direct.get(lid)
            if lk is not None:
                lk.write(frame, peer)
            else:
                via_parent.append((lid, frame, peer))
        service.outbox.clear()
        if via_parent:
            with contextlib.suppress(BrokenPipeError, OSError):
                self.outbox.send(("out", via_parent))


def build_service(spec: WorkerSpec, admission: SharedAdmission | None = None) -> Service:
    """The worker's Service with its sinks (a claiming one with ``spec.claim``);
    ``admission``: the service's ``max_vehicles``, shared by its workers."""
    sinks = open_sinks(
        spec.config,
        # the one file of the service, made by the parent: every worker appends to it
        out=spec.out,
        out_shared=True,
        force=spec.force,
        zenoh_config=spec.zenoh_config,
        zenoh_enabled=spec.zenoh_enabled,
        rerun_mode=worker_rerun_mode(spec.rerun_mode, spec.index),
        recording_name=f"glmav-observer worker {spec.index}",
        # the workers share one service id: worker 0 checks it is free on Zenoh before
        # the others start (ShardedServer), who would otherwise see each other's token
        zenoh_check_unique=spec.index == 0,
    )
    if spec.claim:
        from glmav_observer.fleet.claims import ClaimingService

        return ClaimingService(spec.config, sinks, admission=admission)
    return Service(spec.config, sinks, admission=admission)
