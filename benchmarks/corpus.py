"""The product on a real autopilot's telemetry: the ArduPilot SITL corpus, in full.

Every log of ``tests/data/ardupilot_sitl`` replayed through the service with the default
configuration (``glmav_testkit.fault_replay.replay``), scored against SIM_STATE; then every
velocity fault kind (bias 0.5 and 1 m/s, freeze, NaN, noise σ 0.5 m/s) on every NED axis of
the four flights without a velocity-relevant autopilot fault, 10 s long, at two onset
times. The test suite runs 15 of these cases; this is the table. The 15 cases of one log and
onset share the replay before the onset (``fault_replay.replay_cases``, equal to separate
replays bit for bit): 2 min 41 s on 2 cores, from about 5 min with one replay per case.

    python -m benchmarks.corpus [--quick]    # writes results/corpus.json, docs/benchmarks/corpus.md
"""

from __future__ import annotations

import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from benchmarks.common import format_table, goal, main_for

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardupilot_sitl"
DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "corpus.md"
CLEAN = ("a_quad_wind", "f_coax_clean", "g_heli_clean", "h_quad_gps_glitch")
KINDS: tuple[tuple[str, float], ...] = (
    ("bias", 0.5),
    ("bias", 1.0),
    ("freeze", 0.0),
    ("nan", 0.0),
    ("noise", 0.5),
)
ONSETS_S = (85.0, 110.0)
LENGTH_S = 10.0
AXIS_KINDS = ("dropout", "freeze", "bias", "noise", "unaided")


def _windows(name: str) -> list[tuple[float, float]]:
    side = json.loads((DATA / f"{name}.json").read_text())
    return [(f["start_time_boot_ms"] / 1e3, f["end_time_boot_ms"] / 1e3) for f in side["faults"]]


def _r3(v: Any) -> list[float] | None:
    return None if v is None else [round(float(x), 4) for x in v]


def _flight(name: str) -> dict[str, Any]:
    from glmav_testkit.fault_replay import replay

    r = replay(DATA / f"{name}.tlog.xz")
    windows = [(a, b + 3.0) for a, b in _windows(name)]
    return {
        "log": name,
        "full": _r3(r.rmse_ned_mps.get("full")),
        "active": _r3(r.rmse_ned_mps.get("active")),
        "measurement": _r3(r.rmse_ned_mps.get("measurement")),
        "events": [(round(i.t_s, 2), i.axis, i.kind) for i in r.isolations],
        "axis_isolations_outside_windows": len(
            [i for i in r.isolations_outside(windows) if i.kind in AXIS_KINDS]
        ),
        "max_jump_mps": round(r.max_jump_mps(), 4),
    }


def _cases_at(args: tuple[str, float]) -> list[dict[str, Any]]:
    """Every axis and kind at one onset of one log, replayed from a shared prefix
    (``replay_cases``: the same results as one ``replay`` per case)."""
    from glmav_testkit.fault_replay import VelocityFault, replay_cases

    name, t_on = args
    faults = [
        VelocityFault(axis, kind, t_on, t_on + LENGTH_S, size)  # type: ignore[arg-type]
        for axis in range(3)
        for kind, size in KINDS
    ]
    results = replay_cases(DATA / f"{name}.tlog.xz", [(f,) for f in faults])
    return [_row(name, f, r) for f, r in zip(faults, results, strict=True)]


def _row(name: str, f: Any, r: Any) -> dict[str, Any]:
    axis, kind, size, t_on = f.axis, f.kind, f.size_mps, f.t_on_s
    iso = [i for i in r.isolations if i.kind in AXIS_KINDS]
    first = iso[0] if iso else None
    right = first is not None and (first.axis, first.kind) == (f.axis_name, f.expected_kind)
    delay = None if first is None else round(first.t_s - t_on, 3)
    back = [s for s in r.switches if s.to_config == "full"]
    t, err = r.errors("active")
    lost = err[:, axis]
    at = {}
    for dt in (1.0, 5.0, 10.0):
        k = int((t >= t_on + dt).argmax()) if (t >= t_on + dt).any() else -1
        at[f"lost_err_{int(dt)}s"] = round(float(abs(lost[k])), 4) if k >= 0 else None
    return {
        "log": name,
        "axis": "ned"[axis],
        "kind": kind if kind != "bias" else f"bias {size:g}",
        "t_on_s": t_on,
        "isolated": right,
        "delay_s": delay,
        "extra_isolations": max(0, len(iso) - 1) if right else len(iso),
        "max_jump_mps": round(r.max_jump_mps(), 4),
        "recovered_after_s": None if not back else round(back[-1].t_s - t_on - LENGTH_S, 2),
        **at,
        "active_rmse": _r3(r.rmse_ned_mps.get("active")),
    }


def run(quick: bool = False) -> dict[str, Any]:
    flights = sorted(p.name.split(".")[0] for p in DATA.glob("*.tlog.xz"))
    logs = CLEAN[:1] if quick else CLEAN
    onsets = ONSETS_S[:1] if quick else ONSETS_S
    jobs = [(n, t) for n in logs for t in onsets]  # each: 3 axes x KINDS, one shared prefix
    workers = max(1, min(len(jobs), os.cpu_count() or 1))
    with ProcessPoolExecutor(workers) as ex:
        flight_rows = list(ex.map(_flight, flights))
        cases = [row for rows in ex.map(_cases_at, jobs) for row in rows]
    n_ok = sum(c["isolated"] for c in cases)
    in_time = sum(c["isolated"] and c["delay_s"] is not None and c["delay_s"] <= 0.5 for c in cases)
    jumps = max([c["max_jump_mps"] for c in cases] + [f["max_jump_mps"] for f in flight_rows])
    extra = sum(c["extra_isolations"] for c in cases)
    clean = [f for f in flight_rows if f["log"] in ("a_quad_wind", "f_coax_clean", "g_heli_clean")]
    worst = [max(f["full"][i] for f in clean) for i in range(3)]
    outside = sum(f["axis_isolations_outside_windows"] for f in flight_rows)
    goals = [
        goal("clean flights: worst `full` RMSE north (m/s)", worst[0], 0.05, higher_is_better=False),
        goal("clean flights: worst `full` RMSE east (m/s)", worst[1], 0.05, higher_is_better=False),
        goal("clean flights: worst `full` RMSE down (m/s)", worst[2], 0.03, higher_is_better=False),
        goal("axis isolations outside fault windows (+3 s), all flights", outside, 0, higher_is_better=False),
        goal("injected faults isolated right within 0.5 s (fraction)", in_time / len(cases), 1.0, higher_is_better=True),
        goal("injected faults: other isolations (count)", extra, 0, higher_is_better=False),
        goal("largest switch jump (m/s)", jumps, 0.05, higher_is_better=False),
    ]  # fmt: skip
    result = {
        "name": "corpus",
        "quick": quick,
        "flights": flight_rows,
        "cases": cases,
        "isolated": n_ok,
        "n_cases": len(cases),
        "goals": goals,
    }
    write_doc(result)
    return result


def to_markdown(result: dict[str, Any]) -> str:
    def fmt(v: Any) -> Any:
        return (
            "/".join(f"{x:.3f}" for x in v)
            if isinstance(v, list) and v and isinstance(v[0], float)
            else v
        )

    flights = [
        {
            "log": f["log"],
            "full RMSE": fmt(f["full"]),
            "active RMSE": fmt(f["active"]),
            "autopilot's velocity RMSE": fmt(f["measurement"]),
            "events (t, axis, kind)": "; ".join(f"{t} {a} {k}" for t, a, k in f["events"]) or "none",
            "max jump": f["max_jump_mps"],
        }
        for f in result["flights"]
    ]  # fmt: skip
    cases = [{k: fmt(v) for k, v in c.items()} for c in result["cases"]]
    lines = [
        f"Injected faults isolated on the right axis and kind: {result['isolated']} of "
        f"{result['n_cases']}.",
        "",
        "### Flights (default configuration; RMSE N/E/D m/s against SIM_STATE)",
        "",
        format_table(flights),
        "",
        "### Injected velocity faults (10 s each; lost-axis error of the active estimate "
        "N s after the onset)",
        "",
        format_table(cases),
    ]
    return "\n".join(lines)


def write_doc(result: dict[str, Any]) -> None:
    DOC.parent.mkdir(parents=True, exist_ok=True)
    head = (
        "# The ArduPilot SITL corpus, in full\n\n"
        "Regenerated by `python -m benchmarks.corpus` (see its docstring). Do not edit by hand.\n\n"
    )
    DOC.write_text(head + to_markdown(result) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main_for(sys.modules[__name__], sys.argv[1:]))
