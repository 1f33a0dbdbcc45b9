"""Simulator speed: real-time factor of ``glmav-sitl`` as fast as possible, one core.

Each case runs ``glmav_sitl.runner.run`` on the ``cruise`` scenario (closed loop, default
sensors, all seven streams at their design.md rates encoded to MAVLink 2 and written to
a tlog, no network link) for a fixed sim time; the real-time factor is sim time / wall
time (median over repeats). Baseline in the same run: ``Simulator.run_for`` at the same
step without MAVLink (the physics and the controller; with the ``autopilot`` profile its
sensors too, which run inside every step), so the ratio shows what the streams cost.
The last row flies the scenario with the ``autopilot`` sensor profile (a 1 kHz IMU with
vibration, an attitude estimator and a filtered GPS; ArduPilot rates, ~210 messages/s
instead of ~930). ``cpu_real_time_factor``: sim time / the process's CPU time in the
same runs (what a run gives alone on a core when the machine is shared with other jobs;
the goals are on the wall-clock factor). A cProfile of the default step (dt = 1e-3 s,
ideal sensors) shows where the time goes.
"""

from __future__ import annotations

import cProfile
import dataclasses
import io
import pstats
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for, time_per_call_s
from glmav_sitl.runner import run as sitl_run
from glmav_sitl.scenario import load_scenario
from glmav_sitl.simulator import Simulator

SCENARIO = "cruise"


def _profile(sim_s: float, dt_s: float, tlog: Path, top: int = 15) -> list[dict[str, Any]]:
    prof = cProfile.Profile()
    prof.enable()
    sitl_run(SCENARIO, [], duration_s=sim_s, speed="max", seed=1, tlog_path=tlog, dt_s=dt_s)
    prof.disable()
    st = pstats.Stats(prof, stream=io.StringIO())
    total = st.total_tt  # type: ignore[attr-defined]
    rows = []
    entries = sorted(st.stats.items(), key=lambda kv: kv[1][2], reverse=True)  # type: ignore[attr-defined]
    for (file, line, func), (_cc, nc, tt, ct, _callers) in entries[:top]:
        short = Path(file).name if file != "~" else ""
        rows.append(
            {
                "function": f"{short}:{line}({func})" if short else func,
                "calls": nc,
                "tottime_s": tt,
                "share_%": 100.0 * tt / total,
                "cumtime_s": ct,
            }
        )
    return rows


def run(quick: bool = False) -> dict[str, Any]:
    repeats = 3 if quick else 5
    rows: list[dict[str, Any]] = []
    rtf: dict[tuple[str, float], float] = {}
    sc = load_scenario(SCENARIO)
    with tempfile.TemporaryDirectory() as d:
        tlog = Path(d) / "bench.tlog"
        for dt, prof in ((1e-4, "ideal"), (1e-3, "ideal"), (1e-3, "autopilot")):
            sim_s = (1.0 if quick else 4.0) * (1.0 if dt == 1e-4 else 5.0)
            flown = dataclasses.replace(sc, sensor_profile=prof)

            cpu_s: list[float] = []

            def full(
                dt: float = dt, sim_s: float = sim_s, flown: Any = flown, cpu_s: Any = cpu_s
            ) -> None:
                c0 = time.process_time()
                sitl_run(flown, [], duration_s=sim_s, speed="max", seed=1, tlog_path=tlog, dt_s=dt)
                cpu_s.append(time.process_time() - c0)

            t_full = time_per_call_s(full, number=1, repeats=repeats)

            def physics(dt: float = dt, sim_s: float = sim_s, flown: Any = flown) -> None:
                Simulator(flown, seed=1, dt_s=dt).run_for(sim_s)

            t_phys = time_per_call_s(physics, number=1, repeats=repeats)
            rtf_row = sim_s / t_full["median_s"]
            rtf[(prof, dt)] = rtf_row
            n_steps = sim_s / dt
            rows.append(
                {
                    "sensor_profile": prof,
                    "dt_s": dt,
                    "sim_s": sim_s,
                    "real_time_factor": rtf_row,
                    "cpu_real_time_factor": sim_s / statistics.median(cpu_s[1:]),
                    "physics_only_rtf": sim_s / t_phys["median_s"],
                    "us_per_step_total": t_full["median_s"] / n_steps * 1e6,
                    "us_per_step_physics": t_phys["median_s"] / n_steps * 1e6,
                    "streams_share_%": 100.0 * (1 - t_phys["median_s"] / t_full["median_s"]),
                    "tlog_bytes_per_sim_s": tlog.stat().st_size / sim_s,
                }
            )
        profile = _profile(2.0 if quick else 10.0, 1e-3, tlog)
    goals = [
        goal(
            "real-time factor at dt = 1e-4 s (sensors + MAVLink to tlog)",
            rtf[("ideal", 1e-4)],
            20.0,
            higher_is_better=True,
        ),
        goal(
            "real-time factor at dt = 1e-3 s (the default step), ideal sensors",
            rtf[("ideal", 1e-3)],
            100.0,
            higher_is_better=True,
        ),
        goal(
            "real-time factor at dt = 1e-3 s, autopilot sensors",
            rtf[("autopilot", 1e-3)],
            20.0,
            higher_is_better=True,
        ),
    ]
    return {"name": "bench_sitl", "quick": quick, "rows": rows, "goals": goals, "profile": profile}


def to_markdown(result: dict[str, Any]) -> str:
    return (
        "### Simulator (bench_sitl)\n\n"
        "`cruise` scenario, as fast as possible, one core; median of repeats. "
        "`physics_only_rtf`: the same steps without MAVLink (baseline, same run); "
        "`cpu_real_time_factor`: sim time / the process's CPU time.\n\n"
        + format_table(result["rows"])
        + "\n\n"
        + format_goals(result["goals"])
        + "\n\ncProfile of the dt = 1e-3 s case, ideal sensors (top entries by own time):\n\n"
        + format_table(result["profile"])
    )


if __name__ == "__main__":
    import sys

    sys.exit(main_for(sys.modules[__name__]))
