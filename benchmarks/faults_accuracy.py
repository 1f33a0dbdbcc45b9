"""Accuracy of the active estimate when the radio link drops, reorders, duplicates, delays.

Each row flies the ``cruise`` scenario in real time (seed 1) from the simulator through
the loopback fault proxy (``glmav_testkit.faultproxy``) to the service, and reports the
service's RMSE of the active estimate against SIM_STATE truth per NED axis, the share of
frames delivered, and the ingest counters (late, reordered, duplicate, gaps, restarts).
The first row (no faults) is the baseline of the same run.

    python -m benchmarks.faults_accuracy           # 20 s flights (record)
    python -m benchmarks.faults_accuracy --quick   # 8 s flights
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for
from glmav_testkit.faultproxy import FaultSpec
from glmav_testkit.faultrun import fly_through_proxy

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks" / "faults_accuracy.md"

CASES: tuple[tuple[str, FaultSpec, tuple[float, float] | None], ...] = (
    ("none", FaultSpec(seed=1), None),
    ("drop 5 %", FaultSpec(drop=0.05, seed=1), None),
    ("drop 10 %", FaultSpec(drop=0.10, seed=1), None),
    ("drop 20 %", FaultSpec(drop=0.20, seed=1), None),
    ("reorder 5 % (held 20 ms)", FaultSpec(reorder=0.05, seed=1), None),
    ("duplicate 10 %", FaultSpec(duplicate=0.10, seed=1), None),
    ("delay 50 ms", FaultSpec(delay_s=0.05, seed=1), None),
    ("delay 20 ms ± 10 ms jitter", FaultSpec(delay_s=0.02, jitter_s=0.01, seed=1), None),
    (
        "all: drop 20 %, reorder 5 %, dup 5 %, 20±10 ms",
        FaultSpec(drop=0.2, reorder=0.05, duplicate=0.05, delay_s=0.02, jitter_s=0.01, seed=1),
        None,
    ),
    ("outage 1.5 s at t = 6 s", FaultSpec(seed=1), (6.0, 1.5)),
)


def run(quick: bool = False) -> dict[str, Any]:
    duration = 8.0 if quick else 20.0
    rows = []
    for label, spec, blackout in CASES:
        r = fly_through_proxy(
            spec, scenario="cruise", duration_s=duration, speed=1.0, seed=1, blackout=blackout
        )
        row = r.row()
        row["faults"] = label
        row["max_rmse_mps"] = max(r.rmse_active_mps) if r.rmse_active_mps else float("nan")
        row["velocity_records"] = r.velocity_records
        rows.append(row)
    base = rows[0]["max_rmse_mps"]
    worst = max(r["max_rmse_mps"] for r in rows)
    goals = [
        goal(
            "max RMSE of any faulted run / fault-free run",
            worst / base,
            2.0,
            higher_is_better=False,
        ),
        goal("max RMSE of any faulted run (m/s)", worst, 0.1, higher_is_better=False),
    ]
    return {
        "name": "faults_accuracy",
        "quick": quick,
        "duration_s": duration,
        "rows": rows,
        "goals": goals,
    }


def to_markdown(result: dict[str, Any]) -> str:
    keep = (
        "faults",
        "rmse_n_mps",
        "rmse_e_mps",
        "rmse_d_mps",
        "delivered_%",
        "late",
        "reordered",
        "duplicate",
        "gaps",
        "restarts",
        "velocity_records",
    )
    rows = [{k: r[k] for k in keep} for r in result["rows"]]
    return (
        f"Command: `python -m benchmarks.faults_accuracy{' --quick' if result['quick'] else ''}`"
        f" — cruise scenario, {result['duration_s']:.0f} s flights in real time, seed 1, "
        "simulator -> fault proxy -> service on loopback; RMSE of the active estimate vs "
        "SIM_STATE (after the 3 s settling), per NED axis.\n\n"
        + format_goals(result["goals"])
        + "\n\n"
        + format_table(rows)
        + "\n"
    )


if __name__ == "__main__":
    code = main_for(sys.modules[__name__])
    res = ROOT / "benchmarks" / "results" / "faults_accuracy.json"
    if res.exists():
        DOC.parent.mkdir(parents=True, exist_ok=True)
        DOC.write_text(
            "# faults_accuracy\n\n" + to_markdown(json.loads(res.read_text())), encoding="utf-8"
        )
    sys.exit(code)
