"""Where a worker's CPU goes, per datagram of design-rate traffic (issue 16).

One vehicle's traffic at the design rates (``glmav_sitl.fleet.record_tlog``: ATTITUDE
100 Hz, HIGHRES_IMU 250 Hz, LOCAL_POSITION_NED 30 Hz, HEARTBEAT 1 Hz: 381 datagrams/s),
20 s of a hover, one frame per datagram, through each stage of the path a worker runs,
stage by stage with the modules' own APIs (no stage is patched out):

1. ``decode``: :class:`~glmav_observer.ingest.framing.FrameDecoder` (datagram mode), bytes
   to pymavlink messages; the baseline beside it is pymavlink's own ``parse_char`` loop
   (what ``mavutil`` does per datagram);
2. ``ingest``: :class:`~glmav_observer.ingest.pipeline.Ingest`, messages to samples
   (clock, rates, vetting);
3. ``estimate``: :class:`~glmav_observer.estimation.vehicle.VehicleEstimator`, samples to
   records (the bank's step at every sample, the FDI at every measurement, the records of
   every configuration at every IMU sample);
4. ``1-3 interleaved``: the three, datagram by datagram, as a worker runs them: more than
   their sum alone (each stage's code and data no longer stay in the CPU's caches);
5. ``service``: the whole :meth:`~glmav_observer.app.Service.feed_bytes` path, which is
   the interleaved stages plus the glue (routing events, scoring, handing the records to
   the sinks; no sink here).

CPU time (``process_time``) per datagram of the whole log, median of repeats, one core.
The budget: 100 vehicles x 381 datagrams/s on 2 cores leave 2 s / 38,100 = 52.5 µs of CPU
per datagram for everything, the generator and the workers (which read their own sockets
of the port: the kernel routes it, glmav_observer.fleet.reuseport).
"""

from __future__ import annotations

import gc
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for
from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.ingest.framing import FrameCounters, FrameDecoder, iter_tlog
from glmav_observer.ingest.pipeline import Ingest, IngestConfig
from glmav_observer.ingest.samples import Sample

#: flight recorded, s (the first 2 s are the estimator's start, included)
SECONDS = 20.0
#: datagrams per vehicle and second at the design rates (issue 16)
DESIGN_DATAGRAMS_PER_S = 381.0
#: 100 vehicles on 2 cores: CPU µs per datagram for everything
BUDGET_US = 2.0e6 / (100 * DESIGN_DATAGRAMS_PER_S)
#: the stage table's columns
COLUMNS = ("stage", "us_per_datagram", "share_of_whole", "min_us", "max_us")


def _cpu_per_item_us(fn: Callable[[], int], repeats: int) -> tuple[float, list[float]]:
    """Median over ``repeats`` of the CPU time of ``fn()`` per item it reports, µs."""
    samples = []
    for _ in range(repeats):
        t0 = time.process_time()
        n = fn()
        samples.append((time.process_time() - t0) / n * 1e6)
    return statistics.median(samples), samples


def run(quick: bool = False) -> dict[str, Any]:
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    from glmav_sitl.fleet import record_tlog

    repeats = 3 if quick else 7
    with tempfile.TemporaryDirectory(prefix="glmav-bench-worker-") as tmp:
        tlog = record_tlog(Path(tmp) / "design.tlog", SECONDS, truth=False)
        records = list(iter_tlog(tlog.read_bytes(), FrameCounters()))
    datagrams = [bytes(r.msg.get_msgbuf()) for r in records]
    t_host = [r.t_host_us * 1e-6 for r in records]
    n = len(datagrams)

    def pymavlink_parse() -> int:
        mav = dialect.MAVLink(None)
        for d in datagrams:
            mav.parse_buffer(d)
        return n

    def decode() -> int:
        dec = FrameDecoder(datagram=True, counters=FrameCounters())
        for d, t in zip(datagrams, t_host, strict=True):
            dec.feed(d, t)
        return n

    dec = FrameDecoder(datagram=True, counters=FrameCounters())
    messages = [m for d, t in zip(datagrams, t_host, strict=True) for m in dec.feed(d, t)]
    assert len(messages) == n, (len(messages), n)

    def ingest() -> int:
        ing = Ingest(IngestConfig())
        for m, t in zip(messages, t_host, strict=True):
            ing.on_message(m, t)
        return n

    ing = Ingest(IngestConfig())
    samples: list[Sample] = [
        ev  # type: ignore[misc]
        for m, t in zip(messages, t_host, strict=True)
        for ev in ing.on_message(m, t)
        if hasattr(ev, "t_boot_s")
    ]
    sysid = samples[0].sysid
    est_cfg = ServiceConfig().estimation
    n_records = 0

    def estimate() -> int:
        nonlocal n_records
        est = VehicleEstimator(sysid, est_cfg)
        n_records = 0
        for s in samples:
            n_records += len(est.on_sample(s))
        return n

    def interleaved() -> int:
        """1-3 per datagram, without the service around them."""
        dec = FrameDecoder(datagram=True, counters=FrameCounters())
        ing = Ingest(IngestConfig())
        est = VehicleEstimator(sysid, est_cfg)
        for d, t in zip(datagrams, t_host, strict=True):
            for m in dec.feed(d, t):
                for ev in ing.on_message(m, t):
                    if hasattr(ev, "t_boot_s"):
                        est.on_sample(ev)  # type: ignore[arg-type]
        return n

    def service() -> int:
        svc = Service(ServiceConfig(request_rates=False))
        for d, t in zip(datagrams, t_host, strict=True):
            svc.feed_bytes("udp", d, t, datagram=True)
        return n

    del records
    # the inputs of the stages (~23,000 messages and samples) are not a worker's heap: out of
    # the collector's sight, or every full collection would scan them (the whole path,
    # which allocates the most, paid for that most: +25 µs per datagram measured)
    gc.collect()
    gc.freeze()
    stages: dict[str, tuple[float, list[float]]] = {}
    for name, fn in (
        ("pymavlink parse_buffer (baseline)", pymavlink_parse),
        ("decode", decode),
        ("ingest", ingest),
        ("estimate", estimate),
        ("1-3 interleaved per datagram", interleaved),
        ("service (whole path)", service),
    ):
        fn()  # warm-up
        stages[name] = _cpu_per_item_us(fn, repeats)
        print(f"{name}: {stages[name][0]:.1f} µs/datagram", file=sys.stderr, flush=True)
    gc.unfreeze()
    whole = stages["service (whole path)"][0]
    parts = stages["decode"][0] + stages["ingest"][0] + stages["estimate"][0]
    rows: list[dict[str, Any]] = [
        {"stage": name, "us_per_datagram": med, "share_of_whole": med / whole,
         "min_us": min(s), "max_us": max(s)}
        for name, (med, s) in stages.items()
    ]  # fmt: skip
    inter = stages["1-3 interleaved per datagram"][0]
    rows.append(
        {"stage": "interleaving (1-3 interleaved − 1-3 alone: caches)", "us_per_datagram":
         inter - parts, "share_of_whole": (inter - parts) / whole, "min_us": float("nan"),
         "max_us": float("nan")}
    )  # fmt: skip
    rows.append(
        {"stage": "the service's glue (whole path − 1-3 interleaved)", "us_per_datagram":
         whole - inter, "share_of_whole": (whole - inter) / whole, "min_us": float("nan"),
         "max_us": float("nan")}
    )  # fmt: skip
    goals = [
        goal(f"worker CPU per design-rate datagram (µs; budget {BUDGET_US:.1f})", whole,
             BUDGET_US, higher_is_better=False),
        goal("over the 100-vehicle budget (x)", whole / BUDGET_US, 1.0, higher_is_better=False),
    ]  # fmt: skip
    return {
        "name": "bench_worker",
        "quick": quick,
        "datagrams": n,
        "samples": len(samples),
        "records_per_datagram": n_records / n,
        "budget_us": BUDGET_US,
        "rows": rows,
        "goals": goals,
    }


def to_markdown(result: dict[str, Any]) -> str:
    return "\n\n".join(
        [
            f"Command: `python -m benchmarks.bench_worker{' --quick' if result['quick'] else ''}`"
            f" — {result['datagrams']} datagrams ({SECONDS:.0f} s of one vehicle at the design "
            f"rates), {result['samples']} samples, {result['records_per_datagram']:.2f} records "
            "per datagram; CPU time per datagram, median of repeats, one core.",
            format_goals(result["goals"]),
            # the JSON's keys come back sorted: the columns in their own order
            format_table([{k: r[k] for k in COLUMNS} for r in result["rows"]]),
            "The budget: 100 vehicles × 381 datagrams/s on 2 cores leave "
            f"{result['budget_us']:.1f} µs of CPU per datagram for the generator and the "
            "workers together (the workers read their own sockets of the port, and a live "
            "worker pays the reads too: see bench_fleet). `estimate` runs the bank at every "
            "sample and builds the records of every configuration at every IMU sample (250 "
            "of the 381 datagrams/s); trimming it will not close the gap, vectorising the "
            "bank and the records across vehicles or compiling them would have to.",
        ]
    )


if __name__ == "__main__":
    sys.exit(main_for(sys.modules[__name__]))
