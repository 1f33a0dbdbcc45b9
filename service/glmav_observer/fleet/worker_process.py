"""One worker process of ``serve --workers N`` (:mod:`glmav_observer.fleet.workers`): its
own :class:`~glmav_observer.app.Service` and sinks (:class:`WorkerSpec`), fed by the
parent's batches, sending back rate requests, a latency histogram and its summary
(:class:`WorkerResult`). Workers ignore SIGINT/SIGTERM: the parent stops them by closing
their pipe.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path

from glmav_observer.app import RATE_CHECK_PERIOD_S, Service
from glmav_observer.app_sinks import open_sinks
from glmav_observer.app_summary import ServiceSummary
from glmav_observer.config import ServiceConfig
from glmav_observer.fleet.latency import LatencyHistogram


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
    log_format: str = "text"


@dataclass
class WorkerResult:
    index: int
    summary: ServiceSummary
    latency: LatencyHistogram
    batches: int
    items: int
    cpu_s: float = 0.0  # the worker's CPU time (user + system), s
    wall_s: float = 0.0  # from ready to stop, s


def part_path(out: str, index: int) -> str:
    """``F.w<i>.<ext>``: worker ``index``'s part of the output ``F.<ext>``."""
    p = Path(out)
    return str(p.with_name(f"{p.stem}.w{index}{p.suffix}"))


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
) -> None:
    """A worker process: its own Service and sinks, fed by the parent's batches."""
    from glmav_observer.logs import configure_logging

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    configure_logging(spec.log_level, spec.log_format)
    try:
        if spec.index > 0:  # wait until worker 0 has checked the service id on Zenoh
            try:
                if inbox.recv() != "go":
                    return
            except EOFError:  # the parent gave up starting
                return
        service = build_service(spec)
    except Exception as err:  # reported to the parent, which exits 2 with it
        outbox.send(("error", str(err)))
        return
    outbox.send(("ready", os.getpid()))
    cpu0, wall0 = time.process_time(), time.monotonic()
    latency = LatencyHistogram()
    batches = items = 0
    n_vehicles = 0
    next_rate_check = time.monotonic()
    clock = time.monotonic
    try:
        while True:
            if inbox.poll(0.05):
                try:
                    batch = inbox.recv()
                except EOFError:
                    break
                if batch is None:
                    break
                batches += 1
                for link_id, t_arrival_s, data, peer in batch:
                    service.current_peer = peer
                    service.feed_bytes(link_id, data, t_arrival_s, datagram=True)
                    latency.add(clock() - t_arrival_s)
                items += len(batch)
            now = clock()
            nv = len(service.ingest.vehicles)
            if nv != n_vehicles or now >= next_rate_check:
                n_vehicles = nv
                service.rate_requests(now)
                next_rate_check = now + RATE_CHECK_PERIOD_S
            if service.outbox:
                outbox.send(("out", list(service.outbox)))
                service.outbox.clear()
    finally:
        service.close()
    result = WorkerResult(
        spec.index,
        service.summary(),
        latency,
        batches,
        items,
        cpu_s=time.process_time() - cpu0,
        wall_s=time.monotonic() - wall0,
    )
    with contextlib.suppress(BrokenPipeError, OSError):  # the parent may be gone
        outbox.send(("result", result))


def build_service(spec: WorkerSpec) -> Service:
    """The worker's Service with its sinks (a claiming one with ``spec.claim``)."""
    sinks = open_sinks(
        spec.config,
        out=None if spec.out is None else part_path(spec.out, spec.index),
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

        return ClaimingService(spec.config, sinks)
    return Service(spec.config, sinks)
