"""Rerun logging cost added to the daemon per MAVLink message, live and batched, and the
viewer-side data rate.

Input: a SITL flight (``fault-bias`` scenario: a bias on the east velocity measurement
that the service isolates) written to a tlog and decoded once. Every case runs the
daemon's pipeline, ``glmav_observer.app.Service.feed_message`` over every message (what
``replay`` does, without reading the file), to the end and until the Rerun sink has
handed everything to Rerun; the baseline is the same run without sinks, measured in the
same process, in paired rounds (baseline, then every case; the added cost is the median
over rounds of case − baseline of the same round). Costs are CPU time per message, the
process time (the sink's sender thread and Rerun's threads included): on a shared
machine wall time moves with the load, CPU time much less. common.time_per_call_s
measures wall time only, hence this loop; it still gives the baseline's wall time.

Cases: ``save`` (batched columns into an .rrd, what ``replay --rrd`` does); ``serve``
(live, a gRPC server with no viewer attached, which buffers) at the default flush of
0.5 s of vehicle time and at 0.1, 0.25 and 1.0 s, and with decimation 5. A Rerun chunk
costs about the same whatever its rows, so the flush period sets the cost and
decimation hardly does.

The sink alone: the records the daemon produced, fed to a fresh sink (every write and
the flush until handed to Rerun, in CPU time), in the same rounds. The goals compare it
with the baseline: on a loaded machine the difference of two whole runs moves by more
than the sink costs.

Viewer-side data rate: the bytes a real receiver (``rerun --save`` on 127.0.0.1) stored
for the flight streamed with the default live settings, per second of vehicle time.
"""

from __future__ import annotations

import signal
import socket
import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for, time_per_call_s
from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.framing import iter_tlog
from glmav_observer.publish.rerun import (
    RerunSink,
    open_rerun_sink,
    read_recording,
    rerun_executable,
)
from glmav_observer.records import Record, VelocityRecord
from glmav_sitl.runner import run as sitl_run

SCENARIO = "fault-bias"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _service_run(msgs: list[tuple[Any, float]], sink: RerunSink | None = None) -> list[Record]:
    """The daemon's pipeline (app.Service, as ``replay`` runs it) over decoded messages."""
    records: list[Record] = []
    service = Service(ServiceConfig(), [sink] if sink is not None else [])
    service.on_records = records.extend  # (a hook reads every record)
    for msg, t_host_s in msgs:
        service.feed_message(msg, t_host_s, "bench")
    if sink is not None and not sink.flush(timeout_s=600):  # until handed to Rerun
        raise RuntimeError("the sender did not drain")
    service.close()
    if sink is not None and sink.stats.batches_dropped:
        raise RuntimeError(f"dropped {sink.stats.batches_dropped} batches")
    return records


def _cpu_wall(fn: Callable[[], object]) -> tuple[float, float]:
    """Process CPU time and wall time of one call of ``fn`` (s)."""
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c0, time.perf_counter() - t0


def _sink_run(msgs: list[tuple[Any, float]], mode: str, options: dict[str, Any]) -> None:
    """The daemon's pipeline with a fresh Rerun sink, until everything is sent."""
    kwargs = dict(options)
    if mode == "serve":
        kwargs.update(grpc_port=_free_port(), web_port=None)
    _service_run(msgs, open_rerun_sink(mode, max_queued_batches=1_000_000, **kwargs))


def _sink_alone(records: list[Record], mode: str, options: dict[str, Any]) -> float:
    """CPU time (s) of a fresh sink taking the daemon's records: every ``write``, then the
    flush until the sender has handed everything to Rerun (opening and closing excluded)."""
    kwargs = dict(options)
    if mode == "serve":
        kwargs.update(grpc_port=_free_port(), web_port=None)
    sink = open_rerun_sink(mode, max_queued_batches=1_000_000, **kwargs)
    c0 = time.process_time()
    for r in records:
        sink.write(r)
    if not sink.flush(timeout_s=600):
        raise RuntimeError("the sender did not drain")
    cpu_s = time.process_time() - c0
    sink.close()
    if sink.stats.batches_dropped:
        raise RuntimeError(f"dropped {sink.stats.batches_dropped} batches")
    return cpu_s


def _received_bytes(records: list[Record], tmp: Path) -> int:
    """Bytes a real receiver stored for the flight streamed with the default live settings."""
    exe = rerun_executable()
    if exe is None:
        raise RuntimeError("no rerun executable")
    port = _free_port()
    out = tmp / "received.rrd"
    proc = subprocess.Popen(
        [exe, "--bind", "127.0.0.1", "--port", str(port), "--save", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        sink = open_rerun_sink(
            f"connect:rerun+http://127.0.0.1:{port}/proxy", max_queued_batches=1_000_000
        )
        for r in records:
            sink.write(r)
        sink.flush(timeout_s=120)
        sink.close()
        n_full = sum(1 for r in records if isinstance(r, VelocityRecord) and r.config == "full")
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the receiver has written everything
            try:
                got = read_recording(out).get("/vehicle/1/estimate/v_body/u", {})
                if len(got.get("Scalars:scalars", [])) >= n_full:
                    break
            except Exception:
                pass
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
    return out.stat().st_size


def run(quick: bool = False) -> dict[str, Any]:
    duration_s = 10.0 if quick else 30.0
    repeats = 2 if quick else 5
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        tlog = tmp / "flight.tlog"
        sitl_run(SCENARIO, [], duration_s=duration_s, speed="max", seed=1, tlog_path=tlog)
        msgs = [(r.msg, r.t_host_us * 1e-6) for r in iter_tlog(tlog.read_bytes())]
        records = _service_run(msgs)
        n_msg, n_rec = len(msgs), len(records)
        cases: list[tuple[str, str, dict[str, Any]]] = [
            ("save (batched, replay --rrd)", f"save:{tmp / 'save.rrd'}", {}),
            ("serve live, default (flush 0.5 s, decimation 1)", "serve", {}),
            ("serve live, flush 0.1 s", "serve", {"flush_period_s": 0.1}),
            ("serve live, flush 0.25 s", "serve", {"flush_period_s": 0.25}),
            (
                "serve live, flush 0.25 s, decimation 5",
                "serve",
                {"flush_period_s": 0.25, "decimation": 5},
            ),
            ("serve live, flush 1.0 s", "serve", {"flush_period_s": 1.0}),
        ]
        # Paired rounds: each round runs the baseline and then every case, and the added cost
        # is the median over rounds of (case - baseline of the same round), so that a change
        # of the machine's load between cases does not show as a cost.
        base_cpu: list[float] = []
        base_wall: list[float] = []
        added: dict[str, list[float]] = {name: [] for name, _, _ in cases}
        wall: dict[str, list[float]] = {name: [] for name, _, _ in cases}
        alone: dict[str, list[float]] = {name: [] for name, _, _ in cases}
        _sink_run(msgs, "serve", {})  # warm-up (imports, first server)
        for _ in range(repeats):
            cpu_b, wall_b = _cpu_wall(lambda: _service_run(msgs))
            base_cpu.append(cpu_b)
            base_wall.append(wall_b)
            for name, mode, options in cases:
                cpu_c, wall_c = _cpu_wall(lambda m=mode, o=options: _sink_run(msgs, m, o))
                added[name].append(cpu_c - cpu_b)
                wall[name].append(wall_c)
                alone[name].append(_sink_alone(records, mode, options))
        base_us = statistics.median(base_cpu) / n_msg * 1e6
        # the common helper's wall-clock median of the baseline, for reference
        base_wall_tpc = time_per_call_s(lambda: _service_run(msgs), number=1, repeats=3)
        rows: list[dict[str, Any]] = [
            {
                "case": "baseline: the daemon (app.Service) without sinks",
                "wall_us_per_msg": base_wall_tpc["median_s"] / n_msg * 1e6,
                "cpu_us_per_msg": base_us,
                "added_cpu_us_per_msg": 0.0,
                "added_cpu_us_per_record": 0.0,
                "added_ratio": 0.0,
                "sink_alone_cpu_us_per_msg": 0.0,
                "sink_alone_ratio": 0.0,
            }
        ]
        sink_alone: dict[str, float] = {}
        results: dict[str, float] = {}
        for name, _, _ in cases:
            added_us = statistics.median(added[name]) / n_msg * 1e6
            results[name] = added_us
            alone_us = statistics.median(alone[name]) / n_msg * 1e6
            sink_alone[name] = alone_us
            rows.append(
                {
                    "case": name,
                    "wall_us_per_msg": statistics.median(wall[name]) / n_msg * 1e6,
                    "cpu_us_per_msg": base_us + added_us,
                    "added_cpu_us_per_msg": added_us,
                    "added_cpu_us_per_record": added_us * n_msg / n_rec,
                    "added_ratio": added_us / base_us,
                    "sink_alone_cpu_us_per_msg": alone_us,
                    "sink_alone_ratio": alone_us / base_us,
                }
            )
        rrd_bytes = (tmp / "save.rrd").stat().st_size
        live_bytes = _received_bytes(records, tmp)

    live_default = sink_alone["serve live, default (flush 0.5 s, decimation 1)"]
    saved = sink_alone["save (batched, replay --rrd)"]
    return {
        "name": "bench_rerun",
        "scenario": SCENARIO,
        "vehicle_s": duration_s,
        "messages": n_msg,
        "records": n_rec,
        "rows": rows,
        "data_rate": {
            "live_viewer_kB_per_vehicle_s": live_bytes / duration_s / 1e3,
            "rrd_kB_per_vehicle_s": rrd_bytes / duration_s / 1e3,
        },
        "goals": [
            goal(
                "live Rerun logging (default), the sink alone / daemon per-message cost",
                live_default / base_us,
                0.20,
                higher_is_better=False,
            ),
            goal(
                "batched Rerun logging (save), the sink alone / daemon per-message cost",
                saved / base_us,
                0.20,
                higher_is_better=False,
            ),
        ],
    }


def to_markdown(result: dict[str, Any]) -> str:
    rate = result["data_rate"]
    return "\n".join(
        [
            "## Rerun logging (bench_rerun)",
            "",
            f"`python -m benchmarks.bench_rerun`: {result['vehicle_s']:.0f} s of the "
            f"`{result['scenario']}` SITL flight, {result['messages']} MAVLink messages, "
            f"{result['records']} records (one vehicle, default rates). Costs are medians of "
            "the daemon's pipeline (`app.Service.feed_message`) with the sink minus without "
            "it, in CPU time (the sink's sender thread included), per MAVLink message and per "
            "record. `sink_alone`: the CPU time of the same sink taking the daemon's records "
            "(every write, then the flush until handed to Rerun), median over the rounds: "
            "a difference of two runs moves with the machine's load, this much less; the "
            "goals use it.",
            "",
            format_table(result["rows"]),
            "",
            f"Viewer-side data rate, live defaults: {rate['live_viewer_kB_per_vehicle_s']:.0f} kB "
            f"per second of flight (what a connected viewer receives); the .rrd of `save` mode: "
            f"{rate['rrd_kB_per_vehicle_s']:.0f} kB per second of flight.",
            "",
            format_goals(result["goals"]),
        ]
    )


if __name__ == "__main__":
    import sys

    sys.exit(main_for(sys.modules[__name__]))
