"""The product on a real autopilot's telemetry: the ArduPilot SITL corpus, in full.

Every log of ``tests/data/ardupilot_sitl`` replayed through the service with the default
configuration (``glmav_testkit.fault_replay.replay``), scored against SIM_STATE; then every
velocity fault kind (bias 0.5 and 1 m/s, freeze, NaN, noise σ 0.5 m/s) on every NED axis of
the four flights without a velocity-relevant autopilot fault, 10 s long, at two onset
times. The test suite runs 15 of these cases; this is the table. The 15 cases of one log and
onset share the replay before the onset (``fault_replay.replay_cases``, equal to separate
replays bit for bit): 2 min 41 s on 2 cores, from about 5 min with one replay per case.

The held-out flights (``tests/data/ardupilot_sitl_heldout``: other frames, winds, speeds,
IMU rates and faults) are replayed the same way and printed next to the tuning flights,
with the best-fit lag of the estimate and of the autopilot against truth. They are never
tuned on (docs/design/observer-notes.md, "The held-out set"); no goal below reads them.

    python -m benchmarks.corpus [--quick] [--flights-only]
    # writes results/corpus.json, docs/benchmarks/corpus.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import format_table, goal, main_for
from benchmarks.down_floor import latest_arrived

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardupilot_sitl"
HELDOUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardupilot_sitl_heldout"
#: lags tried for the best fit against truth: -50..+150 ms in 1 ms steps (the estimate and
#: the autopilot lag truth by 0-40 ms; a fit at either end of the range is reported as such)
LAGS_S = np.arange(-0.050, 0.1505, 0.001)
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


def _windows(name: str, data: Path = DATA) -> list[tuple[float, float]]:
    side = json.loads((data / f"{name}.json").read_text())
    return [
        (f["start_time_boot_ms"] / 1e3, f["end_time_boot_ms"] / 1e3)
        for f in side["faults"]
        if f.get("end_time_boot_ms") is not None
    ]


def best_fit_lag_s(r: Any, config: str) -> float | None:
    """The delay τ (s) that makes ``config``'s series fit truth best: the τ in
    :data:`LAGS_S` minimising the summed squared error of v(t) against truth(t - τ), over
    the samples scored for RMSE (from ``skip_s`` after the first estimate). Positive: the
    series lags truth. None without samples."""
    from glmav_observer.evaluation import interpolate_truth

    s = r.collector.series.get(config)
    if s is None or not s.t_s:
        return None
    t, v = s.arrays()
    keep = t >= t[0] + r.skip_s
    t, v = t[keep], v[keep]
    tt, vt = r.collector.truth.arrays()
    costs = []
    for lag in LAGS_S:
        ok, truth = interpolate_truth(t - lag, tt, vt)
        costs.append(float(np.mean((v[ok] - truth[ok]) ** 2)) if ok.any() else np.inf)
    return float(LAGS_S[int(np.argmin(costs))])


def held_rmse(r: Any, at: str = "full") -> Any:
    """RMSE against truth of the autopilot's velocity as its consumer has it at the
    instants ``at``'s estimates are published: the latest measurement (LOCAL_POSITION_NED)
    at or before each, held; over the samples scored for RMSE (from ``skip_s`` after the
    first estimate). The autopilot scored at its own samples only is always fresh; an
    estimate published between them is compared with what was to be had then."""
    from glmav_observer.evaluation import errors_against_truth, rmse

    s, m = r.collector.series.get(at), r.collector.series.get("measurement")
    if s is None or m is None or not s.t_s or not m.t_s:
        return None
    t, _ = s.arrays()
    t = t[t >= t[0] + r.skip_s]
    tm, vm = m.arrays()
    k = latest_arrived(tm, t)
    ok = k >= 0
    tt, vt = r.collector.truth.arrays()
    return rmse(errors_against_truth(t[ok], vm[k[ok]], tt, vt)[1])


def _r3(v: Any) -> list[float] | None:
    return None if v is None else [round(float(x), 4) for x in v]


def _flight_in(args: tuple[str, Path]) -> tuple[dict[str, Any], dict[str, Any]]:
    """One flight's row (the tuning table's) and its side-by-side row (with lags)."""
    from glmav_testkit.fault_replay import replay

    name, data = args
    r = replay(data / f"{name}.tlog.xz")
    windows = [(a, b + 3.0) for a, b in _windows(name, data)]
    row = _flight_row(name, r, windows)
    lag_full, lag_ap = best_fit_lag_s(r, "full"), best_fit_lag_s(r, "measurement")
    side = {
        "set": "held-out" if data == HELDOUT else "tuning",
        "log": name,
        "full": row["full"],
        "active": row["active"],
        "autopilot": row["measurement"],
        "autopilot_held": _r3(held_rmse(r)),
        "isolations": len([i for i in r.isolations if i.kind in AXIS_KINDS]),
        "isolations_outside_windows": row["axis_isolations_outside_windows"],
        "lag_full_ms": None if lag_full is None else round(lag_full * 1e3),
        "lag_autopilot_ms": None if lag_ap is None else round(lag_ap * 1e3),
    }
    return row, side


def _flight_row(name: str, r: Any, windows: list[tuple[float, float]]) -> dict[str, Any]:
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--flights-only",
        action="store_true",
        help="replay the flights only (no injected velocity faults)",
    )


def _logs(data: Path) -> list[str]:
    return sorted(p.name.split(".")[0] for p in data.glob("*.tlog.xz"))


def run(quick: bool = False, flights_only: bool = False) -> dict[str, Any]:
    flights = [(n, DATA) for n in _logs(DATA)] + [(n, HELDOUT) for n in _logs(HELDOUT)]
    logs = CLEAN[:1] if quick else CLEAN
    onsets = ONSETS_S[:1] if quick else ONSETS_S
    jobs = [] if flights_only else [(n, t) for n in logs for t in onsets]
    workers = max(1, min(max(len(jobs), 2), os.cpu_count() or 1))
    with ProcessPoolExecutor(workers) as ex:
        both = list(ex.map(_flight_in, flights))
        cases = [row for rows in ex.map(_cases_at, jobs) for row in rows]
    flight_rows = [row for (row, side) in both if side["set"] == "tuning"]
    side_by_side = [side for (_, side) in both]
    n_ok = sum(c["isolated"] for c in cases)
    in_time = sum(c["isolated"] and c["delay_s"] is not None and c["delay_s"] <= 0.5 for c in cases)
    n_cases = max(1, len(cases))
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
        goal("injected faults isolated right within 0.5 s (fraction)", in_time / n_cases, 1.0, higher_is_better=True),
        goal("injected faults: other isolations (count)", extra, 0, higher_is_better=False),
        goal("largest switch jump (m/s)", jumps, 0.05, higher_is_better=False),
    ]  # fmt: skip
    if not cases:  # --flights-only: no injected-fault goals to judge
        goals = [g for g in goals if "injected" not in g["goal"]]
    result = {
        "name": "corpus",
        "quick": quick,
        "flights": flight_rows,
        "cases": cases,
        "isolated": n_ok,
        "n_cases": len(cases),
        "goals": goals,
        "side_by_side": side_by_side,
    }
    if not flights_only:  # the doc is the whole table
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
    if result.get("side_by_side"):
        lines += ["", *side_by_side_markdown(result["side_by_side"])]
    return "\n".join(lines)


def side_by_side_markdown(rows: list[dict[str, Any]]) -> list[str]:
    """Tuning and held-out flights in one table (nothing is tuned on the held-out set)."""

    def fmt(v: Any) -> str:
        return "-" if v is None else "/".join(f"{x:.3f}" for x in v)

    table = [
        {
            "set": r["set"],
            "log": r["log"],
            "full RMSE": fmt(r["full"]),
            "active RMSE": fmt(r["active"]),
            "autopilot's RMSE": fmt(r["autopilot"]),
            "autopilot's, held at full's instants": fmt(r.get("autopilot_held")),
            "isolations (outside windows)": f"{r['isolations']} ({r['isolations_outside_windows']})",
            "lag full / autopilot (ms)": f"{r['lag_full_ms']} / {r['lag_autopilot_ms']}",
        }
        for r in rows
    ]
    return [
        "### Tuning and held-out flights side by side (RMSE N/E/D m/s against SIM_STATE; "
        "lag: best-fit delay against truth)",
        "",
        "The autopilot's RMSE is over its own samples (LOCAL_POSITION_NED, 10-30 Hz), "
        "each fresh when scored; the estimates are scored at every IMU sample, between "
        "them too. The column beside it scores the autopilot's velocity as its consumer "
        "has it at full's instants (its latest sample, held): the same instants for both.",
        "",
        format_table(table),
    ]


def write_doc(result: dict[str, Any]) -> None:
    DOC.parent.mkdir(parents=True, exist_ok=True)
    head = (
        "# The ArduPilot SITL corpus, in full\n\n"
        "Regenerated by `python -m benchmarks.corpus` (see its docstring). Do not edit by hand.\n\n"
    )
    DOC.write_text(head + to_markdown(result) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main_for(sys.modules[__name__], sys.argv[1:]))
