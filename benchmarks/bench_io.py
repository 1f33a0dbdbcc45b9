"""The fleet's datagram I/O per datagram: the generator's sends and the service's reads.

Two costs of ``bench_fleet`` that are system calls more than Python (issue 30):

1. ``generator``: ``glmav-sitl fleet`` sending 100 vehicles at the design rates (381
   datagrams/s each, 38,100/s) to a UDP port on 127.0.0.1 for ``seconds``: its own CPU
   time (the summary's ``generator CPU``) per datagram sent and as % of a core. With
   ``--before-tree`` (a checkout of the code before, e.g. ``git worktree add
   ../before main`` from the repo), the same run of that tree's ``glmav_sitl.fleet`` (its Python
   send loop: a ``sock.send`` per frame) alternates with this tree's (``fleet_send.pyx``:
   ``send(2)`` on the descriptors in C), one repeat of each in turn;
2. ``read``: one thread that waits on the port (``select``) and reads what the generator
   sends at that load, with its kernel stamps, as the service's loops do: ``Link.read``
   (one ``recvmsg`` a datagram, the loops before) against ``Link.read_datagrams`` (one
   ``recvmmsg`` per 64: ``ingest/udp_drain.pyx``), alternating. The reader thread's own
   CPU time (``time.thread_time``) per datagram read.

Medians of the repeats. The machine is shared: the load average is recorded; the two
sides of each comparison run back to back so that the load hits them alike.

    python -m benchmarks.bench_io --before-tree ../before
    python -m benchmarks.bench_io --quick        # 5 s, 2 repeats, this tree only
"""

from __future__ import annotations

import argparse
import os
import re
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, machine, main_for
from glmav_observer.ingest.links import UDP_DRAIN_BATCH, Link

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = 100
DATAGRAMS_PER_VEHICLE_S = 381
GOAL_GENERATOR_CORE_PCT = 25.0
#: the generator run from a tree's ``sim_bridge`` (only its fleet module and what that
#: imports: pure Python before, the compiled send loop after)
_GENERATOR = (
    "import argparse, sys; from glmav_sitl import fleet; "
    "ns = argparse.Namespace(tlog=[sys.argv[1]], link=[sys.argv[2]], vehicles=int(sys.argv[3]), "
    "sysid_base=1, duration=float(sys.argv[4]), speed=1.0, stagger=1.0); "
    "sys.exit(fleet.main(ns))"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--before-tree", help="a checkout of the code before: its generator runs alternately"
    )
    parser.add_argument("--seconds", type=float, help="seconds per run (default 10, quick 5)")
    parser.add_argument("--repeats", type=int, help="runs of each side (default 3, quick 2)")


def _generate(tree: Path, tlog: Path, port: int, seconds: float) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(tree / "sim_bridge")}
    out = subprocess.run(
        [sys.executable, "-c", _GENERATOR, str(tlog), f"udpout:127.0.0.1:{port}",
         str(VEHICLES), str(seconds)],
        check=True, capture_output=True, text=True, timeout=seconds + 120, env=env,
    ).stdout  # fmt: skip
    m = re.search(r"(\d+) frames sent .* (\d+) failed sends; generator CPU ([\d.]+) s", out)
    if m is None:
        raise RuntimeError(f"no generator summary: {out[-300:]}")
    sent, failed, cpu = int(m.group(1)), int(m.group(2)), float(m.group(3))
    return {"sent": sent, "failed": failed, "cpu_s": cpu}


def _with_reader(
    tree: Path, tlog: Path, seconds: float, *, drain: bool
) -> tuple[dict[str, float], int, float]:
    """A generator run of ``tree`` into a port read by a thread (``drain``: by
    ``read_datagrams``, else ``read``): (generator, datagrams read, reader CPU s)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    link = Link(f"udpin:127.0.0.1:{port}")
    stop = threading.Event()
    got = [0, 0.0]

    def reader() -> None:
        fd = link.fileno()
        n = 0
        cpu0 = time.thread_time()
        while not stop.is_set():
            ready, _, _ = select.select([fd], [], [], 0.05)
            if not ready:
                continue
            if drain:
                while len(batch := link.read_datagrams(UDP_DRAIN_BATCH)) == UDP_DRAIN_BATCH:
                    n += len(batch)
                n += len(batch)
            else:
                while link.read():
                    n += 1
        got[0], got[1] = n, time.thread_time() - cpu0

    th = threading.Thread(target=reader)
    th.start()
    try:
        gen = _generate(tree, tlog, port, seconds)
        time.sleep(0.2)  # the last datagrams are read
    finally:
        stop.set()
        th.join()
        link.close()
    return gen, int(got[0]), float(got[1])


def run(
    quick: bool = False,
    before_tree: str | None = None,
    seconds: float | None = None,
    repeats: int | None = None,
) -> dict[str, Any]:
    from glmav_sitl.fleet import record_tlog

    secs = seconds or (5.0 if quick else 10.0)
    reps = repeats or (2 if quick else 3)
    load_before = os.getloadavg()
    trees: list[tuple[str, Path]] = [("after", ROOT)]
    if before_tree:
        trees.insert(0, ("before", Path(before_tree).resolve()))
    gen_runs: dict[str, list[dict[str, float]]] = {name: [] for name, _ in trees}
    read_runs: dict[str, list[float]] = {"recvmsg (Link.read)": [], "recvmmsg drain": []}
    read_counts: dict[str, list[int]] = {k: [] for k in read_runs}
    with tempfile.TemporaryDirectory(prefix="glmav-bench-io-") as tmp:
        tlog = record_tlog(Path(tmp) / "design.tlog", secs + 2.0, truth=False)
        for _ in range(reps):
            # the generator: before and after in turn (the reader drains, the same for both)
            for name, tree in trees:
                gen, _n, _cpu = _with_reader(tree, tlog, secs, drain=True)
                gen_runs[name].append(gen)
            # the reads: one by one and drained in turn, this tree's generator as the load
            for label, drain in (("recvmsg (Link.read)", False), ("recvmmsg drain", True)):
                _gen, n, cpu = _with_reader(ROOT, tlog, secs, drain=drain)
                read_runs[label].append(1e6 * cpu / max(1, n))
                read_counts[label].append(n)
    rows: list[dict[str, Any]] = []
    for name, runs in gen_runs.items():
        us = [1e6 * r["cpu_s"] / max(1.0, r["sent"]) for r in runs]
        pct = [100.0 * r["cpu_s"] / secs for r in runs]
        rows.append({
            "what": f"generator, {name}",
            "us_per_datagram": statistics.median(us),
            "core_pct": statistics.median(pct),
            "datagrams": int(statistics.median(r["sent"] for r in runs)),
            "failed": int(sum(r["failed"] for r in runs)),
            "runs_us": [round(u, 2) for u in us],
        })  # fmt: skip
    for label, us in read_runs.items():
        per_s = statistics.median(read_counts[label]) / secs
        rows.append({
            "what": f"read, {label}",
            "us_per_datagram": statistics.median(us),
            "core_pct": statistics.median(us) * per_s / 1e4,
            "datagrams": int(statistics.median(read_counts[label])),
            "failed": 0,
            "runs_us": [round(u, 2) for u in us],
        })  # fmt: skip
    after = next(r for r in rows if r["what"] == "generator, after")
    return {
        "name": "bench_io",
        "quick": quick,
        "seconds_per_run": secs,
        "repeats": reps,
        "vehicles": VEHICLES,
        "offered_per_s": VEHICLES * DATAGRAMS_PER_VEHICLE_S,
        # relative to this tree, so that the result names no path of the machine it ran on
        "before_tree": None if before_tree is None else os.path.relpath(before_tree, ROOT),
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "machine": machine(),
        "rows": rows,
        "goals": [
            goal(
                f"generator at {VEHICLES} vehicles (% of a core)",
                after["core_pct"],
                GOAL_GENERATOR_CORE_PCT,
                higher_is_better=False,
            )
        ],
    }


def to_markdown(result: dict[str, Any]) -> str:
    head = (
        f"{result['vehicles']} vehicles ({result['offered_per_s']} datagrams/s offered), "
        f"{result['seconds_per_run']:.0f} s a run, median of {result['repeats']}; load "
        f"{result['loadavg_before'][0]:.1f} before, {result['loadavg_after'][0]:.1f} after\n\n"
    )
    return head + format_table(result["rows"]) + "\n\n" + format_goals(result["goals"])


if __name__ == "__main__":
    raise SystemExit(main_for(sys.modules[__name__]))
