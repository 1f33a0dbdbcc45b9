"""``serve --workers N``: datagrams routed by system id to N worker processes.

A vehicle belongs to one worker, by a fixed rule on its system id
(:func:`~glmav_observer.fleet.routing.worker_of_sysid`), so each vehicle's samples are
estimated in order by one :class:`~glmav_observer.app.Service`. The system id is read
from the frame header without parsing the message (MAVLink 2, magic 0xFD: byte 5;
MAVLink 1, magic 0xFE: byte 3); bytes without a MAVLink header go to worker 0 (its
decoder counts them as garbage).

``udpin:`` links are routed by the kernel (:mod:`glmav_observer.fleet.reuseport`): each
worker reads its own socket of the port, and this process does not touch their
datagrams (it only forwards the rare datagram whose header came after other bytes, which
the kernel's program sends to worker 0). The other links (TCP, serial, ``udpout:``, and
``udpin:`` where the OS cannot route by program) are read here, as :meth:`Service.run`
does, and each item goes to its vehicle's worker with its arrival time and sender.

Datagrams go one per frame batch through a ``multiprocessing`` pipe per worker: the
parent gathers what it reads (at most ``BATCH`` items per worker, for at most
``FLUSH_AFTER_S`` = 1 ms) and sends the list at once; to a worker that got nothing for
``FLUSH_AFTER_S`` (idle, at low rates) what was read goes at once, not 1 ms later. Stream links (TCP, serial) are cut into frames here by the header's
length (a frame is taken when a magic byte follows it or the buffer ends with it, as the
decoder's own resync rule does), and each frame goes to its vehicle's worker.

What workers send back: SET_MESSAGE_INTERVAL frames for their vehicles on links read here
(the parent writes them to the link and address the vehicle was heard on; on a
kernel-routed link the worker sends them from its own socket of the port), an
arrival-to-publish latency histogram, and their :class:`ServiceSummary` at the end,
merged here.

Outputs, as seen by the user:

- Zenoh: every worker opens its own session with the same prefix and service id; keys
  per vehicle are unchanged (a vehicle is on one worker), the ``state`` queryable
  answers for all vehicles together, ``@alive/<service-id>`` and ``@config/<service-id>``
  are declared by each worker (same key, same payload); only worker 0 checks that no
  other service holds the id, and the others build their sinks once it has (``go``);
- ``--out F.jsonl|.csv``: one file, made by the parent (with the CSV header); every worker
  appends its buffers of whole records to it (``O_APPEND``, each buffer under an
  exclusive ``flock``, cut back to the file's size before it if the write fails:
  :mod:`glmav_observer.publish.file_sink`), so ``F`` ends on a whole record at any
  moment, a kill -9 of the parent leaves the records in ``F`` (the workers see their
  pipe close and flush), and there are no part files; each vehicle's rows stay in order;
- Rerun: ``save:PATH`` gives one file per worker (``PATH.w<i>.rrd``; open them together);
  ``connect:URL`` connects every worker to the viewer; ``spawn`` and ``serve`` (one
  viewer, one port) need ``--workers 1``.

Workers ignore SIGINT/SIGTERM/SIGHUP: the parent stops them by closing their pipe after
the last batch, so nothing read is lost; a worker whose parent died sees the pipe close
too.

This module is the parent's side; the frames are cut and their system ids read in
:mod:`glmav_observer.fleet.routing`, and a worker's side is
:mod:`glmav_observer.fleet.worker_process`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import multiprocessing
import multiprocessing.connection
import select
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from glmav_observer.app import RATE_CHECK_PERIOD_S, stop_on_signals
from glmav_observer.app_summary import ServiceSummary
from glmav_observer.config import ServiceConfig
from glmav_observer.fleet.admission import SharedAdmission
from glmav_observer.fleet.latency import LatencyHistogram
from glmav_observer.fleet.reuseport import (
    PortGuard,
    ReuseportUnavailableError,
    bind_group,
    is_kernel_routable,
)
from glmav_observer.fleet.routing import StreamSplitter, datagram_sysid, worker_of_sysid
from glmav_observer.fleet.worker_process import (
    WorkerError,
    WorkerResult,
    WorkerSpec,
    worker_main,
    worker_rerun_mode,
)
from glmav_observer.ingest.links import (
    DEFAULT_UDP_RECEIVE_BUFFER_BYTES,
    KERNEL_DROPS_COUNTER,
    UDP_DRAIN_BATCH,
    KernelDrops,
    Link,
)

logger = logging.getLogger(__name__)

#: the summary's per-link counter of :class:`PortGuard`: the most foreign sockets seen
FOREIGN_SOCKETS_COUNTER = "foreign_sockets_on_port"

#: items per worker gathered before a pipe send
BATCH = 64
#: the longest an item waits in the parent for its batch to fill, s: one pipe send (and
#: one worker wake-up) per millisecond instead of per datagram at moderate rates
FLUSH_AFTER_S = 0.001


@dataclass
class ShardedSummary:
    """The merged summary of all workers plus the router's own counters."""

    summary: ServiceSummary
    latency: LatencyHistogram
    routed: dict[int, int] = field(default_factory=dict)  # items per worker
    worker_cpu_s: dict[int, float] = field(default_factory=dict)
    vehicles_per_worker: dict[int, list[int]] = field(default_factory=dict)
    #: the links the kernel routed to the workers' own sockets
    kernel_routed: list[str] = field(default_factory=list)

    def to_text(self) -> str:
        lines = [self.summary.to_text()]
        for conn in self.kernel_routed:
            lines.append(f"link {conn}: routed by the kernel to the workers (SO_REUSEPORT)")
        for w, sysids in sorted(self.vehicles_per_worker.items()):
            lines.append(
                f"worker {w}: {len(sysids)} vehicles {sysids}, {self.routed.get(w, 0)} items, "
                f"CPU {self.worker_cpu_s.get(w, 0.0):.2f} s"
            )
        lat = self.latency.summary_ms()
        lines.append(
            f"arrival to publish: p50 {lat['p50_ms']:.3f} ms, p99 {lat['p99_ms']:.3f} ms, "
            f"max {lat['max_ms']:.1f} ms over {int(lat['n'])} items"
        )
        return "\n".join(lines)


# ---------------------------------------------------------------------- parent side
@dataclass
class _Worker:
    index: int
    process: Any
    inbox: multiprocessing.connection.Connection  # parent writes
    results: multiprocessing.connection.Connection  # parent reads
    vehicles: list[int] = field(default_factory=list)
    batch: list[tuple[str, float, bytes, Any]] = field(default_factory=list)
    #: arrival time (the loop's clock) of the newest item of the last batch sent
    flushed_s: float = -math.inf
    result: WorkerResult | None = None


class ShardedServer:
    """The parent of ``serve --workers N``: starts workers, routes, merges their results.

    ``udp_links``: ``udpin:`` connection strings the kernel routes to the workers
    (:mod:`glmav_observer.fleet.reuseport`; bound here, before the workers start: a taken
    port raises :class:`LinkError`); those it cannot route are left in
    :attr:`router_links` for the caller to open and pass to :meth:`run`."""

    def __init__(
        self,
        specs: Sequence[WorkerSpec],
        *,
        udp_links: Sequence[str] = (),
        udp_receive_buffer_bytes: int = DEFAULT_UDP_RECEIVE_BUFFER_BYTES,
        start_timeout_s: float = 60.0,
    ) -> None:
        ctx = multiprocessing.get_context("spawn")  # no inherited sessions or threads
        self.workers: list[_Worker] = []
        self.owner: dict[int, int] = {}
        self.counters: Counter[str] = Counter()
        #: datagrams the kernel dropped on the links the parent reads (the workers count
        #: those on their own sockets)
        self.kernel_drops = KernelDrops()
        self.out = specs[0].out if specs else None
        #: links the kernel routes to the workers' own sockets
        self.kernel_routed: list[str] = []
        #: UDP links the kernel could not route: the caller opens them for :meth:`run`
        self.router_links: list[str] = []
        #: ``max_vehicles`` counted over all workers (issue 31 D12)
        self.admission = SharedAdmission(specs[0].config.ingest.max_vehicles if specs else 1, ctx)
        #: sockets of other processes on the kernel-routed ports (issue 31 D3)
        self.port_guard = PortGuard()
        groups: dict[str, list[socket.socket]] = {}
        try:
            for conn in udp_links:
                try:
                    groups[conn] = bind_group(conn, len(specs), udp_receive_buffer_bytes)
                except ReuseportUnavailableError as err:
                    logger.warning(
                        "UDP link read by the router: the kernel cannot route it",
                        extra={"link": conn, "error": str(err)},
                    )
                    self.router_links.append(conn)
            self.kernel_routed = list(groups)
            for conn, socks in groups.items():
                self.port_guard.watch(conn, socks)
            for i, spec in enumerate(specs):
                inbox_r, inbox_w = ctx.Pipe(duplex=False)
                res_r, res_w = ctx.Pipe(duplex=False)
                proc = ctx.Process(
                    target=worker_main,
                    args=(
                        dataclasses.replace(spec, workers=len(specs)),
                        inbox_r,
                        res_w,
                        {conn: socks[i] for conn, socks in groups.items()},
                        self.admission,
                    ),
                    name=f"glmav-worker-{spec.index}",
                    daemon=True,
                )
                proc.start()  # the worker's sockets are passed to it here
                inbox_r.close()
                res_w.close()
                self.workers.append(_Worker(spec.index, proc, inbox_w, res_r))
            # the workers hold their sockets: a worker that dies leaves the group
            for socks in groups.values():
                for sk in socks:
                    sk.close()
            groups.clear()
            deadline = time.monotonic() + start_timeout_s
            for i, w in enumerate(self.workers):
                if i == 1:
                    for later in self.workers[1:]:  # worker 0 is ready: the id is ours
                        later.inbox.send("go")
                left = max(0.0, deadline - time.monotonic())
                if not w.results.poll(left):
                    raise WorkerError(f"worker {w.index} did not start in {start_timeout_s:.0f} s")
                try:
                    kind, payload = w.results.recv()
                except EOFError:
                    raise WorkerError(f"worker {w.index} exited while starting") from None
                if kind == "error":
                    raise WorkerError(str(payload))
        except BaseException:
            for socks in groups.values():
                for sk in socks:
                    sk.close()
            self._stop_workers(timeout_s=10.0)
            raise

    # -- routing -----------------------------------------------------------------------
    def worker_of(self, sysid: int | None) -> _Worker:
        """The worker owning ``sysid`` (:func:`worker_of_sysid`, the kernel's rule too)."""
        if sysid is None:
            return self.workers[0]
        w = self.owner.get(sysid)
        if w is None:
            w = worker_of_sysid(sysid, len(self.workers))
            self.owner[sysid] = w
            self.workers[w].vehicles.append(sysid)
            logger.info("vehicle routed", extra={"sysid": sysid, "worker": w})
        return self.workers[w]

    def _queue(self, w: _Worker, item: tuple[str, float, bytes, Any]) -> None:
        w.batch.append(item)
        if len(w.batch) >= BATCH:
            self._flush(w)

    def _flush(self, w: _Worker) -> None:
        if not w.batch:
            return
        try:
            w.inbox.send(w.batch)
        except (BrokenPipeError, OSError):
            self.counters["items_lost_worker_gone"] += len(w.batch)
        w.flushed_s = w.batch[-1][1]
        w.batch = []

    def route_datagram(self, link_id: str, data: bytes, t_arrival_s: float, peer: Any) -> None:
        self._queue(self.worker_of(datagram_sysid(data)), (link_id, t_arrival_s, data, peer))

    # -- the loop ----------------------------------------------------------------------
    def run(
        self,
        links: dict[str, Link],
        stop_event: threading.Event,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Read ``links`` until ``stop_event`` is set, routing to the workers."""
        splitters: dict[str, StreamSplitter] = {}
        by_result = {w.results.fileno(): w for w in self.workers}
        next_drop_check = clock() + RATE_CHECK_PERIOD_S
        while not stop_event.is_set():
            by_fd: dict[int, tuple[str, Link]] = {}
            for lid, lk in links.items():
                fd = lk.fileno()
                if fd is None:
                    lk.read()  # down: reconnect with backoff
                else:
                    by_fd[fd] = (lid, lk)
            # a batch goes when its oldest item has waited FLUSH_AFTER_S, or at once when
            # the worker got nothing for that long (idle: nothing to gather for)
            pending = [min(w.batch[0][1], w.flushed_s) for w in self.workers if w.batch]
            wait_s = 0.05
            if pending:
                wait_s = max(0.0, min(pending) + FLUSH_AFTER_S - clock())
            try:
                ready, _, _ = select.select([*by_fd, *by_result], [], [], wait_s)
            except (InterruptedError, ValueError, OSError):
                continue
            for fd in ready:
                if fd in by_result:
                    self._from_worker(by_result[fd], links)
                    continue
                lid, lk = by_fd[fd]
                if lk.datagram:  # drain the socket, UDP_DRAIN_BATCH a system call
                    while True:
                        got = lk.read_datagrams(UDP_DRAIN_BATCH)
                        for data, arrival_s, peer in got:
                            if data:
                                # its arrival: the kernel's stamp (the wait in the queue
                                # counts)
                                self.route_datagram(lid, data, min(clock(), arrival_s), peer)
                        if len(got) < UDP_DRAIN_BATCH:
                            break
                    continue
                data = lk.read()  # a stream: what it holds now
                if data:
                    t = clock()
                    sp = splitters.get(lid)
                    if sp is None:
                        sp = splitters[lid] = StreamSplitter()
                    for sysid, piece in sp.feed(data):
                        self._queue(self.worker_of(sysid), (lid, t, piece, None))
            now = clock()
            for w in self.workers:
                if w.batch and now - min(w.batch[0][1], w.flushed_s) >= FLUSH_AFTER_S:
                    self._flush(w)
            if now >= next_drop_check:
                self.kernel_drops.check(links)
                for conn in self.port_guard.check():
                    # a foreign program replaced ours: worker 0 attaches ours again
                    with contextlib.suppress(BrokenPipeError, OSError):
                        self.workers[0].inbox.send(("reattach", conn))
                next_drop_check = now + RATE_CHECK_PERIOD_S
        self.kernel_drops.check(links)
        for w in self.workers:
            self._flush(w)

    def _from_worker(self, w: _Worker, links: dict[str, Link]) -> None:
        try:
            kind, payload = w.results.recv()
        except (EOFError, OSError):
            return
        if kind == "out":
            for lid, frame, peer in payload:
                if lid in links:
                    links[lid].write(frame, peer)
        elif kind == "route":  # read by a worker, owned by another (see worker_process)
            for lid, t_arrival_s, data, peer in payload:
                self.route_datagram(lid, data, t_arrival_s, peer)
        elif kind == "result":
            w.result = payload

    # -- stop --------------------------------------------------------------------------
    def _stop_workers(self, *, timeout_s: float) -> None:
        for w in self.workers:
            self._flush(w)
            with contextlib.suppress(BrokenPipeError, OSError):
                w.inbox.send(None)
        deadline = time.monotonic() + timeout_s
        for w in self.workers:
            while w.result is None:
                left = deadline - time.monotonic()
                if left <= 0 or not w.results.poll(left):
                    break
                try:
                    kind, payload = w.results.recv()
                except (EOFError, OSError):
                    break
                if kind == "result":
                    w.result = payload
            w.process.join(max(0.1, deadline - time.monotonic()))
            if w.process.is_alive():
                logger.warning("worker did not stop: killed", extra={"worker": w.index})
                w.process.kill()
                w.process.join(5.0)
            w.inbox.close()
            w.results.close()

    def close(self, *, timeout_s: float = 60.0) -> ShardedSummary:
        """Stop the workers (they flush and close their sinks), merge parts and summaries."""
        self._stop_workers(timeout_s=timeout_s)
        results = [w.result for w in self.workers if w.result is not None]
        missing = [w.index for w in self.workers if w.result is None]
        if missing:
            self.counters["workers_without_summary"] += len(missing)
        latency = LatencyHistogram()
        for r in results:
            latency.merge(r.latency)
        summary = merge_summaries([r.summary for r in results], self.counters)
        for lid, n in self.port_guard.foreign.items():
            c = summary.link_counters.setdefault(lid, {})
            c[FOREIGN_SOCKETS_COUNTER] = max(c.get(FOREIGN_SOCKETS_COUNTER, 0), n)
        for lid, n in self.kernel_drops.drops.items():  # the parent's own reads
            c = summary.link_counters.setdefault(lid, {})
            c[KERNEL_DROPS_COUNTER] = c.get(KERNEL_DROPS_COUNTER, 0) + n
        return ShardedSummary(
            summary=summary,
            latency=latency,
            # datagrams each worker estimated: routed here, or read from its own socket
            routed={r.index: r.items for r in results},
            vehicles_per_worker={
                w.index: sorted(
                    set(w.vehicles) | set(w.result.summary.vehicles if w.result else ())
                )
                for w in self.workers
            },
            kernel_routed=list(self.kernel_routed),
            worker_cpu_s={r.index: r.cpu_s for r in results},
        )


def merge_summaries(parts: Iterable[ServiceSummary], extra: Counter[str]) -> ServiceSummary:
    """One summary from the workers': vehicles are disjoint, counters add up."""
    vehicles = {}
    links: dict[str, Counter[str]] = {}
    service: Counter[str] = Counter(extra)
    records = messages = 0
    failed: list[tuple[str, str]] = []
    for s in parts:
        failed.extend(s.failed_sinks)
        vehicles.update(s.vehicles)
        for lid, c in s.link_counters.items():
            links.setdefault(lid, Counter()).update(c)
        service.update(s.service_counters)
        records += s.records
        messages += s.messages
    return ServiceSummary(
        vehicles=dict(sorted(vehicles.items())),
        link_counters={k: dict(sorted(v.items())) for k, v in sorted(links.items())},
        service_counters=dict(sorted(service.items())),
        records=records,
        messages=messages,
        failed_sinks=failed,
    )


def worker_specs(
    config: ServiceConfig,
    workers: int,
    *,
    out: str | None = None,
    zenoh_config: str | None = None,
    zenoh_enabled: bool | None = None,
    rerun_mode: str | None = None,
    claim: bool = False,
    force: bool = False,
) -> list[WorkerSpec]:
    """One spec per worker; raises WorkerError for a Rerun mode workers cannot share, or
    ``--mavlink-out`` (one sender per link: every worker opened it, the second found the
    port taken and serve said another process held it)."""
    level = logging.getLevelName(logging.getLogger().getEffectiveLevel())
    mode = rerun_mode if rerun_mode is not None else config.rerun.mode
    worker_rerun_mode(mode, 0)  # checks it
    if workers > 1 and config.mavlink_out.enabled:
        raise WorkerError(
            f"--mavlink-out {config.mavlink_out.link}: one sender per link needs one "
            "process; use --workers 1 (serve's choice with --mavlink-out when --workers "
            "is not given)"
        )
    path = out if out is not None else (config.out or None)
    return [
        WorkerSpec(
            index=i,
            config=dataclasses.replace(config),
            out=path,
            zenoh_config=zenoh_config,
            zenoh_enabled=zenoh_enabled,
            rerun_mode=mode,
            claim=claim,
            log_level=level if isinstance(level, str) else "INFO",
            workers=workers,
            force=force,
        )
        for i in range(workers)
    ]


def serve_sharded(
    specs: Sequence[WorkerSpec],
    links: Iterable[str],
    stop_event: threading.Event | None = None,
) -> ShardedSummary:
    """Start the workers, open ``links``, route until SIGINT/SIGTERM/SIGHUP (or the event)."""
    stop = stop_event if stop_event is not None else threading.Event()
    opened: dict[str, Link] = {}
    server: ShardedServer | None = None
    links = list(links)
    with stop_on_signals(stop):
        try:
            config = specs[0].config
            server = ShardedServer(
                specs,
                udp_links=[c for c in links if is_kernel_routable(c)],
                udp_receive_buffer_bytes=config.udp_receive_buffer_bytes,
            )
            for conn in server.kernel_routed:
                logger.info("link open, routed by the kernel", extra={"link": conn})
            for conn in links:
                if conn in server.kernel_routed:
                    continue
                opened[conn] = Link(conn, udp_receive_buffer_bytes=config.udp_receive_buffer_bytes)
                logger.info("link open", extra={"link": conn, "workers": len(specs)})
            server.run(opened, stop)
        finally:
            for lk in opened.values():
                lk.close()
            result = server.close() if server is not None else None
    assert result is not None
    for lk in opened.values():
        for k, v in lk.counters.items():
            result.summary.service_counters[k] = result.summary.service_counters.get(k, 0) + v
    return result
