"""Where a worker's CPU goes, per datagram of design-rate traffic (issue 16).

One vehicle's traffic at the design rates (``glmav_sitl.fleet.record_tlog``: ATTITUDE
100 Hz, HIGHRES_IMU 250 Hz, LOCAL_POSITION_NED 30 Hz, HEARTBEAT 1 Hz: 381 datagrams/s),
20 s of a hover, one frame per datagram, through each stage of the path a worker runs,
stage by stage with the modules' own APIs (no stage is patched out):

1. ``decode``: :class:`~glmav_observer.ingest.framing.FrameDecoder` (datagram mode), bytes
   to messages (the high-rate ones compiled, ``ingest/fastframe.pyx``; the rest by
   pymavlink); the baseline beside it is pymavlink's own ``parse_char`` loop (what
   ``mavutil`` does per datagram);
2. ``ingest``: :class:`~glmav_observer.ingest.pipeline.Ingest`, messages to samples
   (clock, rates, vetting);
3. ``estimate``: :class:`~glmav_observer.estimation.vehicle.VehicleEstimator`, samples to
   records (the bank's step at every sample, the FDI at every measurement, the records of
   every configuration at every IMU sample);
4. ``1-3 interleaved``: the three, datagram by datagram, as a worker runs them: more than
   their sum alone (each stage's code and data no longer stay in the CPU's caches);
5. ``service``: the whole :meth:`~glmav_observer.app.Service.feed_bytes` path, which is
   the interleaved stages plus the glue (routing events, scoring, handing the records to
   the sinks; no sink here: the baseline);
6. ``service + default outputs``: the same with the sinks ``serve`` opens by default with
   Zenoh on (:func:`benchmarks.outputs.default_output_sinks`: the product's ``open_sinks``,
   whatever it publishes), once with one real subscriber on ``glmav/**`` in another process
   (the headline: the publishers have a consumer) and once without. Their difference
   to ``service`` is the outputs' cost, per datagram and per record handed over.

The stages are measured round-robin (one repeat of each in turn), so that the load of the
shared machine hits the pairs alike.

CPU time (``process_time``) per datagram of the whole log, median of repeats, one core.
The budget: 100 vehicles x 381 datagrams/s on 2 cores leave 2 s / 38,100 = 52.5 µs of CPU
per datagram for everything, the generator and the workers (which read their own sockets
of the port: the kernel routes it, glmav_observer.fleet.reuseport).
"""

from __future__ import annotations

import gc
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for
from benchmarks.outputs import default_outputs, sinks_summary, with_unique_id
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
#: the stages' names the rows and goals refer to
SERVICE = "service (whole path, no sink)"
OUTPUTS = "service + default outputs, subscribed"
OUTPUTS_UNSUBSCRIBED = "service + default outputs, no subscriber"


def _cpu_per_item_us(fn: Callable[[], int]) -> float:
    """The CPU time (this process, every thread) of ``fn()`` per item it reports, µs."""
    t0 = time.process_time()
    n = fn()
    return (time.process_time() - t0) / n * 1e6


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
        for d in datagrams:
            dec.feed(d)
        return n

    dec = FrameDecoder(datagram=True, counters=FrameCounters())
    messages = [m for d in datagrams for m in dec.feed(d)]
    assert len(messages) == n, (len(messages), n)

    def ingest() -> int:
        ing = Ingest(IngestConfig())
        for m, t in zip(messages, t_host, strict=True):
            ing.on_message(m, t)
        return n

    ing = Ingest(IngestConfig())
    samples_in: list[Sample] = [
        ev  # type: ignore[misc]
        for m, t in zip(messages, t_host, strict=True)
        for ev in ing.on_message(m, t)
        if hasattr(ev, "t_boot_s")
    ]
    sysid = samples_in[0].sysid
    est_cfg = ServiceConfig().estimation
    n_records = 0

    def estimate() -> int:
        nonlocal n_records
        est = VehicleEstimator(sysid, est_cfg)
        n_records = 0
        for s in samples_in:
            n_records += len(est.on_sample(s))
        return n

    def interleaved() -> int:
        """1-3 per datagram, without the service around them."""
        dec = FrameDecoder(datagram=True, counters=FrameCounters())
        ing = Ingest(IngestConfig())
        est = VehicleEstimator(sysid, est_cfg)
        for d, t in zip(datagrams, t_host, strict=True):
            for m in dec.feed(d):
                for ev in ing.on_message(m, t):
                    if hasattr(ev, "t_boot_s"):
                        est.on_sample(ev)  # type: ignore[arg-type]
        return n

    config = ServiceConfig(request_rates=False)
    service_records = [0]

    def service_with(sinks: list[Any]) -> Callable[[], int]:
        def service() -> int:
            svc = Service(config, sinks)
            for d, t in zip(datagrams, t_host, strict=True):
                svc.feed_bytes("udp", d, t, datagram=True)
            service_records[0] = svc.records
            return n

        return service

    del records
    load_before = os.getloadavg()
    with (
        default_outputs(with_unique_id(config, "worker"), subscriber=True) as subscribed,
        default_outputs(with_unique_id(config, "worker-nosub")) as unsubscribed,
    ):
        stages_fns: dict[str, Callable[[], int]] = {
            "pymavlink parse_buffer (baseline)": pymavlink_parse,
            "decode": decode,
            "ingest": ingest,
            "estimate": estimate,
            "1-3 interleaved per datagram": interleaved,
            SERVICE: service_with([]),
            OUTPUTS_UNSUBSCRIBED: service_with(unsubscribed.sinks),
            OUTPUTS: service_with(subscribed.sinks),
        }
        for fn in stages_fns.values():
            fn()  # warm-up (and the outputs' publishers declared)
        # the inputs of the stages (~23,000 messages and samples) are not a worker's heap: out
        # of the collector's sight, or every full collection would scan them (the whole path,
        # which allocates the most, paid for that most: +25 µs per datagram measured)
        gc.collect()
        gc.freeze()
        samples: dict[str, list[float]] = {name: [] for name in stages_fns}
        for r in range(repeats):  # round-robin: the machine's load hits the pairs alike
            for name, fn in stages_fns.items():
                samples[name].append(_cpu_per_item_us(fn))
            print(f"repeat {r + 1}/{repeats}: " + ", ".join(
                f"{k}: {v[-1]:.1f}" for k, v in samples.items()), file=sys.stderr, flush=True)  # fmt: skip
        gc.unfreeze()
        outputs_opened = sinks_summary(subscribed.sinks)
    load_after = os.getloadavg()
    stages = {name: (statistics.median(v), v) for name, v in samples.items()}
    records_per_datagram = service_records[0] / n
    whole = stages[SERVICE][0]
    with_outputs = stages[OUTPUTS][0]
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
    # the outputs' cost: each repeat's pair (same moment of the machine's load)
    cost = [o - b for o, b in zip(samples[OUTPUTS], samples[SERVICE], strict=True)]
    cost_unsub = [o - b for o, b in zip(samples[OUTPUTS_UNSUBSCRIBED], samples[SERVICE],
                                        strict=True)]  # fmt: skip
    for name, c in (("the default outputs, subscribed (− no sink)", cost),
                    ("the default outputs, no subscriber (− no sink)", cost_unsub)):  # fmt: skip
        med = statistics.median(c)
        rows.append({"stage": name, "us_per_datagram": med, "share_of_whole": med / whole,
                     "min_us": min(c), "max_us": max(c)})  # fmt: skip
    sub_stats = subscribed.stats.get("subscriber", {})
    zenoh_stats = subscribed.stats.get("ZenohSink", {})
    published = sum(zenoh_stats.get("published", {}).values())
    outputs = {
        "sinks": outputs_opened,
        "records_per_datagram_handed_over": records_per_datagram,
        "us_per_record_subscribed": statistics.median(cost) / max(records_per_datagram, 1e-9),
        "us_per_record_no_subscriber": statistics.median(cost_unsub)
        / max(records_per_datagram, 1e-9),
        "published_subscribed_sinks": published,
        "published_by_kind": zenoh_stats.get("published", {}),
        "subscriber_samples": sub_stats.get("samples", 0),
        "subscriber_bytes": sub_stats.get("bytes", 0),
        "subscriber_by_kind": sub_stats.get("by_kind", {}),
        "subscriber_cpu_s": sub_stats.get("cpu_s", float("nan")),
        "delivered_fraction": sub_stats.get("samples", 0) / max(1, published),
        "sink_stats": {k: v for k, v in subscribed.stats.items() if k != "subscriber"},
    }
    goals = [
        goal(f"worker CPU per design-rate datagram, default outputs on (µs; budget "
             f"{BUDGET_US:.1f})", with_outputs, BUDGET_US, higher_is_better=False),
        goal("over the 100-vehicle budget, default outputs on (x)", with_outputs / BUDGET_US,
             1.0, higher_is_better=False),
        goal(f"worker CPU per design-rate datagram, no outputs (baseline; µs; budget "
             f"{BUDGET_US:.1f})", whole, BUDGET_US, higher_is_better=False),
    ]  # fmt: skip
    return {
        "name": "bench_worker",
        "quick": quick,
        "datagrams": n,
        "samples": len(samples_in),
        "records_per_datagram": n_records / n,
        "budget_us": BUDGET_US,
        "outputs": outputs,
        "loadavg_before": load_before,
        "loadavg_after": load_after,
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
            *([f"Label: {result['label']}."] if result.get("label") else []),
            format_goals(result["goals"]),
            # the JSON's keys come back sorted: the columns in their own order
            format_table([{k: r[k] for k in COLUMNS} for r in result["rows"]]),
            _outputs_text(result),
            "The budget: 100 vehicles × 381 datagrams/s on 2 cores leave "
            f"{result['budget_us']:.1f} µs of CPU per datagram for the generator and the "
            "workers together (the workers read their own sockets of the port, and a live "
            "worker pays the reads too: see bench_fleet). `estimate` runs the bank at every "
            "sample and builds the records of every configuration at every IMU sample (250 "
            "of the 381 datagrams/s); trimming it will not close the gap, vectorising the "
            "bank and the records across vehicles or compiling them would have to.",
        ]
    )


def _outputs_text(result: dict[str, Any]) -> str:
    """The default outputs' cost per record (empty for a result from before they were on)."""
    o = result.get("outputs")
    if not o:
        return ""
    lb, la = result["loadavg_before"], result["loadavg_after"]
    return (
        f"Default outputs (`open_sinks(config, zenoh_enabled=True)`: {', '.join(o['sinks'])}): "
        f"{o['records_per_datagram_handed_over']:.2f} records handed over per datagram; "
        f"their CPU {o['us_per_record_subscribed']:.2f} µs per record with a subscriber, "
        f"{o['us_per_record_no_subscriber']:.2f} µs without (this process, Zenoh's threads "
        f"included; the subscriber's own CPU, in its process, is not: "
        f"{o['subscriber_cpu_s']:.1f} s for {o['subscriber_samples']:,} samples, "
        f"{o['delivered_fraction']:.1%} of the {o['published_subscribed_sinks']:,} published "
        "at this replay's speed; congestion control drops what it cannot take). Published "
        "per kind, all repeats: "
        + ", ".join(f"{k} {v:,}" for k, v in o["published_by_kind"].items())
        + f". Load average {lb[0]:.2f} before, {la[0]:.2f} after (a shared machine: the pairs "
        "compare, measured round-robin; the absolute figures move with the load)."
    )


if __name__ == "__main__":
    sys.exit(main_for(sys.modules[__name__]))
