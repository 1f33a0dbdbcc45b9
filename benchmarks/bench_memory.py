"""Memory per vehicle in the service (issue 30: <= 2 MB).

One :class:`~glmav_observer.app.Service` with the default configuration (``max_vehicles``
raised to the fleet's size) is fed the same 20 s of design-rate traffic
(``glmav_sitl.fleet.record_tlog``: ATTITUDE 100 Hz, HIGHRES_IMU 250 Hz,
LOCAL_POSITION_NED 30 Hz) as N vehicles (the frames rewritten with sysids 1..N,
``glmav_sitl.fleet.rewrite``), vehicle after vehicle, through ``feed_bytes`` as datagrams.
Measured: the Python heap the vehicles hold at the end (``tracemalloc``, after a
``gc.collect()``; the frames fed are freed first), and the process's RSS growth, both
divided by N; for N = 1, 10 and 50 (the difference between two N gives the marginal cost
of a vehicle, free of the service's fixed part).
"""

from __future__ import annotations

import dataclasses
import gc
import tempfile
import tracemalloc
from pathlib import Path
from typing import Any

import psutil

from benchmarks.common import format_goals, format_table, git_head, goal, machine, main_for
from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig

SECONDS = 20.0
#: issue 30's goal, bytes per vehicle
TARGET_BYTES = 2e6


def _measure(n: int, frames: list[Any]) -> dict[str, float]:
    from glmav_sitl.fleet import rewrite

    gc.collect()
    proc = psutil.Process()
    rss0 = proc.memory_info().rss
    tracemalloc.start()
    base = ServiceConfig()
    config = dataclasses.replace(base, ingest=dataclasses.replace(base.ingest, max_vehicles=n))
    service = Service(config)
    heap0, _ = tracemalloc.get_traced_memory()
    for sysid in range(1, n + 1):
        for fr in frames:
            service.feed_bytes("bench", rewrite(fr, sysid), fr.t_s)
    gc.collect()
    heap1, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss1 = proc.memory_info().rss
    vehicles = len(service.estimators)
    del service
    gc.collect()
    return {
        "vehicles": float(vehicles),
        "heap_bytes": float(heap1 - heap0),
        "heap_per_vehicle_bytes": (heap1 - heap0) / max(vehicles, 1),
        "rss_growth_bytes": float(rss1 - rss0),
        "rss_per_vehicle_bytes": (rss1 - rss0) / max(vehicles, 1),
        "peak_heap_bytes": float(peak),
    }


def run(quick: bool = False) -> dict[str, Any]:
    from glmav_sitl.fleet import load_tlog, record_tlog

    sizes = [1, 10] if quick else [1, 10, 50]
    with tempfile.TemporaryDirectory() as tmp:
        tlog = record_tlog(Path(tmp) / "design.tlog", SECONDS, truth=False)
        frames = load_tlog(tlog).frames
    rows = []
    for n in sizes:
        r = _measure(n, frames)
        rows.append({"N": n, **r})
    last, first = rows[-1], rows[0]
    marginal = (last["heap_bytes"] - first["heap_bytes"]) / (last["vehicles"] - first["vehicles"])
    marginal_rss = (last["rss_growth_bytes"] - first["rss_growth_bytes"]) / (
        last["vehicles"] - first["vehicles"]
    )
    return {
        "name": "bench_memory",
        "machine": machine(),
        "git_head": git_head(),
        "quick": quick,
        "rows": rows,
        "marginal_heap_per_vehicle_bytes": marginal,
        "marginal_rss_per_vehicle_bytes": marginal_rss,
        "goals": [
            goal(
                "service memory per vehicle, Python heap, marginal (MB)",
                marginal / 1e6,
                TARGET_BYTES / 1e6,
                higher_is_better=False,
            ),
            goal(
                "service memory per vehicle, RSS growth, marginal (MB)",
                max(marginal_rss, 0.0) / 1e6,
                TARGET_BYTES / 1e6,
                higher_is_better=False,
            ),
        ],
    }


def to_markdown(result: dict[str, Any]) -> str:
    label = f"\n\nLabel: {result['label']}." if result.get("label") else ""
    return (
        "### Memory per vehicle (bench_memory)\n\n"
        "Command: `python -m benchmarks.bench_memory` — the default service fed 20 s of "
        "design-rate traffic per vehicle (sysids rewritten), vehicle after vehicle; "
        "`tracemalloc` heap and RSS at the end; marginal = (largest N − N = 1) / the "
        f"vehicles between.{label}\n\n"
        + format_goals(result["goals"])
        + "\n\n"
        + format_table(result["rows"])
    )


if __name__ == "__main__":
    raise SystemExit(main_for(__import__(__name__)))
