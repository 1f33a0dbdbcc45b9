"""Replay speed on the corpus: how many times faster than the flight (issue 30).

For each ArduPilot SITL flight of the tuning corpus (``tests/data/ardupilot_sitl``, the
8 ``.tlog``), the CPU time (``process_time``, one core) of what ``glmav-observer replay
LOG`` runs (``app_replay.replay_tlog`` with the default configuration, no output file:
framing, decoding, ingest, the estimator, scoring against SIM_STATE) and, as the baseline
in the same run, of a bare pymavlink loop over the same file (``mavutil.mavlink_connection
(LOG).recv_msg()`` until the end: read and parse only). Stages beside them: the framing
and decoding alone (``iter_tlog``).

Real-time factor = the log's span (its first to last time stamp) / the CPU time; the
headline is the median over the 8 flights. Repeats are round-robin (one of each in turn),
so that the load of a shared machine hits them alike; medians of the repeats.
"""

from __future__ import annotations

import lzma
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for
from glmav_observer.app_replay import replay_tlog
from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.framing import iter_tlog

CORPUS = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardupilot_sitl"
#: issue 30's goal: replay >= 500x real time per core (median over the 8 flights)
TARGET_X = 500.0


def _span_s(data: bytes) -> float:
    stamps = [r.t_host_us for r in iter_tlog(data)]
    return (stamps[-1] - stamps[0]) * 1e-6


def _cpu(fn: Any) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def _mavutil(path: Path) -> None:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    while conn.recv_msg() is not None:
        pass
    conn.close()


def _frames(data: bytes) -> None:
    for _ in iter_tlog(data):
        pass


def _replay(path: Path) -> None:
    replay_tlog(path, ServiceConfig(), [])


def run(quick: bool = False) -> dict[str, Any]:
    repeats = 1 if quick else 3
    logs = sorted(CORPUS.glob("*.tlog.xz"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for xz in logs:
            path = Path(tmp) / xz.name.removesuffix(".xz")
            data = lzma.decompress(xz.read_bytes())
            path.write_bytes(data)
            span = _span_s(data)
            n = sum(1 for _ in iter_tlog(data))
            _replay(path)  # warm-up (imports, caches)
            cpu: dict[str, list[float]] = {"replay": [], "mavutil": [], "frames": []}
            for _ in range(repeats):
                cpu["replay"].append(_cpu(lambda p=path: _replay(p)))
                cpu["mavutil"].append(_cpu(lambda p=path: _mavutil(p)))
                cpu["frames"].append(_cpu(lambda d=data: _frames(d)))
            med = {k: statistics.median(v) for k, v in cpu.items()}
            rows.append(
                {
                    "flight": xz.name.removesuffix(".tlog.xz"),
                    "span_s": span,
                    "messages": n,
                    "replay_cpu_s": med["replay"],
                    "replay_x_realtime": span / med["replay"],
                    "replay_us_per_msg": med["replay"] / n * 1e6,
                    "mavutil_cpu_s": med["mavutil"],
                    "mavutil_x_realtime": span / med["mavutil"],
                    "frames_us_per_msg": med["frames"] / n * 1e6,
                    "replay_over_mavutil": med["mavutil"] / med["replay"],
                }
            )
    x_med = statistics.median(r["replay_x_realtime"] for r in rows)
    ratio_med = statistics.median(r["replay_over_mavutil"] for r in rows)
    from benchmarks.common import git_head, machine

    return {
        "name": "bench_replay",
        "machine": machine(),
        "git_head": git_head(),
        "quick": quick,
        "repeats": repeats,
        "rows": rows,
        "goals": [
            goal(
                "replay real-time factor per core, median over the 8 corpus flights (x)",
                x_med,
                TARGET_X,
                higher_is_better=True,
            ),
            goal(
                "replay speed / bare mavutil read of the same log, median (ratio)",
                ratio_med,
                1.0,
                higher_is_better=True,
            ),
        ],
    }


def to_markdown(result: dict[str, Any]) -> str:
    label = f"\n\nLabel: {result['label']}." if result.get("label") else ""
    return (
        "### Replay speed on the corpus (bench_replay)\n\n"
        f"Command: `python -m benchmarks.bench_replay` — CPU time (one core), median of "
        f"{result['repeats']} round-robin repeats per flight; `replay` = what "
        "`glmav-observer replay LOG` runs (default configuration, scoring against "
        "SIM_STATE, no output file); `mavutil` = a bare `recv_msg()` loop over the same "
        "file (the baseline); `frames` = framing and decoding alone. Where the time "
        "goes, and the history: docs/benchmarks/bench_replay.md."
        f"{label}\n\n" + format_goals(result["goals"]) + "\n\n" + format_table(result["rows"])
    )


if __name__ == "__main__":
    raise SystemExit(main_for(__import__(__name__)))
