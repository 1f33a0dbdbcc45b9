"""Accuracy of the product against baselines, on simulated flights with truth.

Each run: ``glmav_sitl`` flies a scenario at max speed and writes the MAVLink stream to a
tlog; the service's ingest decodes it and its ``VehicleEstimator`` (default settings: the
bank, FDI, hand-over) consumes the samples. In the same pass, on the same held inputs,
three baselines from :mod:`benchmarks.baselines` run beside every configuration, each
seeing the NED axes that configuration used in that step (the bank's ``last_meas_mask``):
a filterpy Kalman filter, pure IMU dead reckoning and the raw measurement. Truth is
SIM_STATE (50 Hz), compared with the latest estimates.

Scenarios: hover, cruise, climbing-turn, gusts, launch; every velocity fault kind
(dropout, freeze, bias, noise) on each NED axis and an accelerometer bias on each body axis
(timing and magnitudes from the shipped ``fault-*`` scenarios); several seeds each.

Metrics per scenario and configuration: RMSE and max error per NED axis; the 5 %
convergence time (a second, cold-start pass over the first 10 s, every estimate started
2.7 m/s off, the KF with a matching prior: time until the measured-axis error first falls
below 5 % of its initial value); fault isolation delay; false isolations per hour;
the faulty axis's error at +1, +5, +10 s after the fault starts.

``python -m benchmarks.accuracy [--quick]`` or ``python -m benchmarks --only accuracy``:
prints the tables, writes ``benchmarks/results/accuracy.json`` and regenerates
``docs/benchmarks/accuracy.md``. ``--sensor-profile autopilot`` flies every case with the
simulator's ``autopilot`` sensors (vibrating 50 Hz RAW_IMU, estimated attitude, 10 Hz
filtered GPS velocity 150 ms late; docs/model.md) and writes ``accuracy-autopilot.json`` /
``accuracy-autopilot.md`` instead. ``--case LABEL`` (repeatable) runs only those cases and
prints the tables without writing anything.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, TimeoutError, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.accuracy_pass import convergence_time, measured_axes, run_pass
from benchmarks.accuracy_report import TIE, to_markdown
from benchmarks.common import goal, write_result
from benchmarks.paper import tlog_samples
from glmav_observer.records import CONFIGS, NED_AXES

DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "accuracy.md"
RESULTS = Path(__file__).resolve().parent / "results" / "accuracy.json"
NOMINAL = ("hover", "cruise", "climbing-turn", "gusts", "launch")
VELOCITY_FAULTS = ("dropout", "freeze", "bias", "noise")
BODY_AXES = ("x", "y", "z")
CONV_WINDOW_S = 10.0
AFTER_FAULT_S = (1.0, 5.0, 10.0)


@dataclasses.dataclass(frozen=True)
class Case:
    """One scenario to fly: a label, the shipped scenario name, the fault (if any)."""

    label: str
    base: str
    fault_kind: str = ""  # dropout | freeze | bias | noise | accel_bias
    axis: str = ""  # n, e, d (velocity) or x, y, z (accelerometer, body)
    duration_s: float | None = None


def cases(quick: bool) -> list[Case]:
    if quick:
        return [
            Case("hover", "hover", duration_s=15.0),
            Case("climbing-turn", "climbing-turn", duration_s=20.0),
            Case("launch", "launch", duration_s=12.0),
            Case("fault-bias-e", "fault-bias", "bias", "e", duration_s=31.0),
            Case("fault-dropout-d", "fault-dropout", "dropout", "d", duration_s=31.0),
        ]
    # nominal flights capped at 60 s (launch: its 20 s); fault flights end 12 s after the
    # fault starts (20 s): enough for the +10 s metric, and the full suite stays ~15 min
    out = [Case(n, n, duration_s=20.0 if n == "launch" else 60.0) for n in NOMINAL]
    out += [
        Case(f"fault-{k}-{a}", f"fault-{k}", k, a, duration_s=32.0)
        for k in VELOCITY_FAULTS
        for a in NED_AXES
    ]
    out += [
        Case(f"fault-accel-bias-{a}", "fault-accel-bias", "accel_bias", a, duration_s=32.0)
        for a in BODY_AXES
    ]
    return out


SENSOR_PROFILES = ("ideal", "autopilot")  # glmav_sitl.scenario.SENSOR_PROFILES


def build_scenario(case: Case, sensor_profile: str = "ideal") -> Any:
    """The shipped scenario with the fault moved to ``case.axis``, flown with the
    simulator's ``sensor_profile`` sensors."""
    from glmav_sitl.scenario import load_scenario

    sc = dataclasses.replace(load_scenario(case.base), sensor_profile=sensor_profile)
    if case.fault_kind:
        (f,) = sc.faults
        if case.fault_kind == "accel_bias":
            mag = max(abs(v) for v in f.vector)
            x, y, z = (mag if a == case.axis else 0.0 for a in BODY_AXES)
            vec = (x, y, z)
            f = dataclasses.replace(f, vector=vec)
        else:
            f = dataclasses.replace(f, axis=case.axis)
        sc = dataclasses.replace(sc, faults=(f,), name=case.label)
    if case.duration_s is not None:
        sc = dataclasses.replace(sc, duration_s=case.duration_s)
    return sc


def evaluate(case: Case, seed: int, sensor_profile: str = "ideal") -> dict[str, Any]:
    """Fly ``case`` with ``seed``; every metric of the run (JSON-able)."""
    from glmav_sitl.runner import run

    sc = build_scenario(case, sensor_profile)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tlog = Path(tmp) / "run.tlog"
        run(sc, speed="max", seed=seed, tlog_path=tlog)
        t_sim = time.perf_counter() - t0
        samples, _ = tlog_samples(tlog)
    t1 = time.perf_counter()
    tr = run_pass(samples, cold=False)
    cold = run_pass(samples, cold=True, until_s=CONV_WINDOW_S)
    t_est = time.perf_counter() - t1
    err = {n: v - tr.v_true_ned_mps for n, v in tr.est.items()}
    per: dict[str, Any] = {}
    for n, e in err.items():
        per[n] = {
            "rmse_ned_mps": np.sqrt(np.mean(e**2, axis=0)).tolist(),
            "max_ned_mps": np.max(np.abs(e), axis=0).tolist(),
            "conv_5pct_s": convergence_time(cold, n),
        }
    out: dict[str, Any] = {
        "case": case.label,
        "seed": seed,
        "duration_s": float(tr.t_s[-1] - tr.t_start_s),
        "per_estimate": per,
        "faults_isolated": tr.faults,
        "switches": tr.switches,
        "wall_sim_s": t_sim,
        "wall_estimation_s": t_est,
        "n_samples": len(samples),
    }
    if case.fault_kind:
        (flt,) = sc.faults
        out["fault"] = {
            "kind": case.fault_kind,
            "axis": case.axis,
            "t_start_s": flt.t_start_s,
            "t_end_s": flt.t_end_s,
        }
        vel_axis = NED_AXES.index(case.axis) if case.axis in NED_AXES else None
        # the right call: the faulty velocity axis, or an accelerometer event (axis
        # "body", it isolates nothing) for an accelerometer fault; either after the onset
        good = [
            ev
            for ev in tr.faults
            if ev["t_detect_s"] >= flt.t_start_s
            and (
                ev["axis"] == case.axis
                if vel_axis is not None
                else ev["axis"] == "body" and ev["kind"] == "accel_bias"
            )
        ][:1]
        out["isolation_delay_s"] = good[0]["t_detect_s"] - flt.t_start_s if good else None
        out["false_isolations"] = len(tr.faults) - (1 if good else 0)
        after: dict[str, dict[str, float]] = {}
        for dt in AFTER_FAULT_S:
            k = int(np.argmin(np.abs(tr.t_s - (flt.t_start_s + dt))))
            row = {}
            for n in ("bank:active", "bank:full", "kf:full", "raw:full", "dr"):
                e = err[n][k]
                row[n] = (
                    abs(float(e[vel_axis])) if vel_axis is not None else float(np.linalg.norm(e))
                )
            after[f"+{dt:g}s"] = row
        out["faulty_axis_error_after_mps"] = after
    else:
        out["false_isolations"] = len(tr.faults)
    return out


# ---------------------------------------------------------------------------- suite


def _task(args: tuple[Case, int, str]) -> dict[str, Any]:
    """One run; a failure is returned as a row with its traceback (reported, not hidden)."""
    try:
        return evaluate(*args)
    except Exception:
        import traceback

        return {"case": args[0].label, "seed": args[1], "error": traceback.format_exc(limit=6)}


def _mean(xs: Sequence[float]) -> float:
    v = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else math.nan


def _rms_over(
    runs: list[dict[str, Any]], name: str, axes: list[int], key: str = "rmse_ned_mps"
) -> float:
    """Mean over seeds of the RMSE (or max) combined over ``axes`` (root mean square)."""
    vals = []
    for r in runs:
        a = np.asarray(r["per_estimate"][name][key])[axes]
        vals.append(float(np.sqrt(np.mean(a**2))) if key == "rmse_ned_mps" else float(np.max(a)))
    return _mean(vals)


def summarise(results: list[dict[str, Any]], case_list: list[Case]) -> dict[str, Any]:
    by: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        by.setdefault(r["case"], []).append(r)
    nominal: list[dict[str, Any]] = []
    verdict: list[dict[str, Any]] = []
    for case in case_list:
        if case.fault_kind:
            continue
        runs = by[case.label]
        for c in CONFIGS:
            meas = measured_axes(c)
            lost = [j for j in range(3) if j not in meas]
            row: dict[str, Any] = {"scenario": case.label, "config": c}
            for est in ("bank", "kf", "raw"):
                row[f"{est} meas RMSE"] = _rms_over(runs, f"{est}:{c}", meas)
            row["dr RMSE"] = _rms_over(runs, "dr", meas)
            row["bank meas max"] = _rms_over(runs, f"bank:{c}", meas, "max_ned_mps")
            row["kf meas max"] = _rms_over(runs, f"kf:{c}", meas, "max_ned_mps")
            row["bank lost RMSE"] = _rms_over(runs, f"bank:{c}", lost) if lost else math.nan
            row["kf lost RMSE"] = _rms_over(runs, f"kf:{c}", lost) if lost else math.nan
            row["bank t5% (s)"] = _mean(
                [r["per_estimate"][f"bank:{c}"]["conv_5pct_s"] for r in runs]
            )
            row["kf t5% (s)"] = _mean([r["per_estimate"][f"kf:{c}"]["conv_5pct_s"] for r in runs])
            ratio = row["bank meas RMSE"] / row["kf meas RMSE"]
            row["bank/kf"] = ratio
            row["verdict"] = (
                "bank better" if ratio < 1 / TIE else ("tie" if ratio <= TIE else "**KF better**")
            )
            nominal.append(row)
            verdict.append({"scenario": case.label, "config": c, "ratio": ratio})
    faults: list[dict[str, Any]] = []
    for case in case_list:
        if not case.fault_kind:
            continue
        runs = by[case.label]
        row = {"scenario": case.label}
        delays = [r["isolation_delay_s"] for r in runs]
        row["isolated"] = f"{sum(d is not None for d in delays)}/{len(runs)}"
        row["delay (s)"] = _mean(delays)
        row["false iso."] = sum(r["false_isolations"] for r in runs)
        row["bank active RMSE"] = _rms_over(runs, "bank:active", [0, 1, 2])
        row["kf RMSE"] = _rms_over(runs, "kf:full", [0, 1, 2])
        for dt in AFTER_FAULT_S:
            key = f"+{dt:g}s"
            row[f"bank {key}"] = _mean(
                [r["faulty_axis_error_after_mps"][key]["bank:active"] for r in runs]
            )
            row[f"kf {key}"] = _mean(
                [r["faulty_axis_error_after_mps"][key]["kf:full"] for r in runs]
            )
        row["dr +10s"] = _mean([r["faulty_axis_error_after_mps"]["+10s"]["dr"] for r in runs])
        row["raw +10s"] = _mean(
            [r["faulty_axis_error_after_mps"]["+10s"]["raw:full"] for r in runs]
        )
        faults.append(row)
    hours = sum(r["duration_s"] for r in results) / 3600.0
    n_false = sum(r["false_isolations"] for r in results)
    no_acc = [r for r in results if r.get("fault", {}).get("kind") != "accel_bias"]
    hours_na = sum(r["duration_s"] for r in no_acc) / 3600.0
    n_false_na = sum(r["false_isolations"] for r in no_acc)
    worse_faults = [
        {"scenario": row["scenario"], "metric": m, "bank": row[f"bank {m}"], "kf": row[f"kf {m}"]}
        for row in faults
        for m in ("+1s", "+5s", "+10s")
        if row[f"bank {m}"] > TIE * row[f"kf {m}"]
    ]
    return {
        "nominal": nominal,
        "faults": faults,
        "verdict": verdict,
        "false_isolations": n_false,
        "flight_hours": hours,
        "false_isolations_per_hour": n_false / hours if hours > 0 else math.nan,
        "false_isolations_no_accel_fault": n_false_na,
        "flight_hours_no_accel_fault": hours_na,
        "false_isolations_per_hour_no_accel_fault": n_false_na / hours_na
        if hours_na > 0
        else math.nan,
        "faults_bank_worse": worse_faults,
    }


def _names(sensor_profile: str) -> tuple[str, Path]:
    """The result name and the doc of a profile (``ideal`` keeps the historical ones)."""
    if sensor_profile == "ideal":
        return "accuracy", DOC
    return f"accuracy-{sensor_profile}", DOC.with_name(f"accuracy-{sensor_profile}.md")


def run(
    quick: bool = False, sensor_profile: str = "ideal", only: Sequence[str] = ()
) -> dict[str, Any]:
    """The suite. ``GLMAV_ACCURACY_BUDGET_S`` (env) bounds the wall time: runs not started
    by then are dropped (seed 0 of every case goes first) and the doc says so.
    ``only``: case labels to run (the doc is then not rewritten)."""
    if sensor_profile not in SENSOR_PROFILES:
        raise ValueError(f"sensor profile {sensor_profile!r} is not one of {SENSOR_PROFILES}")
    seeds = [0] if quick else [0, 1, 2]
    case_list = cases(quick)
    if only:
        unknown = set(only) - {c.label for c in case_list}
        if unknown:
            known = ", ".join(c.label for c in case_list)
            raise ValueError(f"unknown case(s) {', '.join(sorted(unknown))} (known: {known})")
        case_list = [c for c in case_list if c.label in only]
    tasks = [(c, s, sensor_profile) for s in seeds for c in case_list]
    env_budget = os.environ.get("GLMAV_ACCURACY_BUDGET_S")
    budget = float(env_budget) if env_budget else None  # as_completed: None = no limit
    t0 = time.perf_counter()
    workers = max(1, min(len(tasks), os.cpu_count() or 1))
    results: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(_task, t) for t in tasks]
        try:
            for fut in as_completed(futures, timeout=budget):
                results.append(fut.result())
        except TimeoutError:
            for fut in futures:
                fut.cancel()  # the running ones finish; their results are kept below
    for fut in futures:
        if fut.done() and not fut.cancelled() and fut.result() not in results:
            results.append(fut.result())
    skipped = [
        f"{c.label} seed {s}"
        for (c, s, _), fut in zip(tasks, futures, strict=True)
        if fut.cancelled()
    ]
    wall = time.perf_counter() - t0
    failed = [r for r in results if "error" in r]
    results = [r for r in results if "error" not in r]
    result = finish(
        results,
        quick=quick,
        seeds=seeds,
        wall_s=wall,
        workers=workers,
        sensor_profile=sensor_profile,
        only=only,
    )
    result["failed_runs"] = failed
    result["skipped_runs"] = skipped
    if not only:
        doc = _names(sensor_profile)[1]
        doc.parent.mkdir(parents=True, exist_ok=True)
        doc.write_text(to_markdown(result) + "\n", encoding="utf-8")
    return result


def finish(
    results: list[dict[str, Any]],
    *,
    quick: bool,
    seeds: list[int],
    wall_s: float,
    workers: int,
    sensor_profile: str = "ideal",
    only: Sequence[str] = (),
) -> dict[str, Any]:
    """Summary, goals and the result dict from the per-run results."""
    case_list = [c for c in cases(quick) if any(r["case"] == c.label for r in results)]
    summary = summarise(results, case_list)
    ratios = [v["ratio"] for v in summary["verdict"]]
    delays = [r["isolation_delay_s"] for r in results if r.get("isolation_delay_s") is not None]
    vel_runs = [r for r in results if r.get("fault", {}).get("axis") in NED_AXES]
    b10 = [r["faulty_axis_error_after_mps"]["+10s"]["bank:active"] for r in vel_runs]
    k10 = [r["faulty_axis_error_after_mps"]["+10s"]["kf:full"] for r in vel_runs]
    goals = [
        goal("bank/KF measured-axis RMSE, worst (scenario, config)", max(ratios), TIE,
             higher_is_better=False),
        goal("bank/KF measured-axis RMSE, median", float(np.median(ratios)), 1.0,
             higher_is_better=False),
        goal("false isolations per flight hour, all flights", summary["false_isolations_per_hour"],
             1.0, higher_is_better=False),
        goal("false isolations per flight hour, flights without an accelerometer fault",
             summary["false_isolations_per_hour_no_accel_fault"], 1.0, higher_is_better=False),
    ]  # fmt: skip
    if delays:
        goals.append(goal("velocity fault isolation delay, median (s)", float(np.median(delays)),
                          1.0, higher_is_better=False))  # fmt: skip
    if b10:
        goals.append(goal("faulty-axis error +10 s, bank/KF (median over runs)",
                          float(np.median(b10) / max(float(np.median(k10)), 1e-12)), 1.0,
                          higher_is_better=False))  # fmt: skip
    return {
        "name": _names(sensor_profile)[0],
        "sensor_profile": sensor_profile,
        "only": list(only),
        "quick": quick,
        "seeds": seeds,
        "rows": summary["nominal"] + summary["faults"],
        "goals": goals,
        "summary": summary,
        "runs": results,
        "failed_runs": [],
        "skipped_runs": [],
        "wall_s": wall_s,
        "workers": workers,
    }


def rebuild_docs(path: Path | None = None) -> None:
    """Regenerate docs/benchmarks/accuracy.md from ``results/accuracy.json`` (no rerun)."""
    import json

    old = json.loads((path or RESULTS).read_text(encoding="utf-8"))
    prof = old.get("sensor_profile", "ideal")
    res = finish(old["runs"], quick=old["quick"], seeds=old["seeds"], wall_s=old["wall_s"],
                 workers=old["workers"], sensor_profile=prof)  # fmt: skip
    res["failed_runs"] = old.get("failed_runs", [])
    res["skipped_runs"] = old.get("skipped_runs", [])
    write_result(res)
    _names(prof)[1].write_text(to_markdown(res) + "\n", encoding="utf-8")


def main(argv: Sequence[str] | None = None) -> int:
    """``--quick``, ``--sensor-profile ideal|autopilot``, ``--case LABEL`` (repeatable),
    ``--docs-only`` (regenerate the doc of ``--sensor-profile`` from its JSON)."""
    import argparse

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer cases and seeds (smoke run)")
    ap.add_argument("--sensor-profile", choices=SENSOR_PROFILES, default="ideal")
    ap.add_argument("--case", action="append", default=[], metavar="LABEL",
                    help="run only this case (repeatable); nothing is written")  # fmt: skip
    ap.add_argument("--docs-only", action="store_true", help="rebuild the doc from the JSON")
    args = ap.parse_args(argv)
    name, _ = _names(args.sensor_profile)
    if args.docs_only:
        rebuild_docs(RESULTS.with_name(f"{name}.json"))
        return 0
    try:
        result = run(quick=args.quick, sensor_profile=args.sensor_profile, only=args.case)
    except ValueError as e:
        print(f"accuracy: {e}", file=sys.stderr)
        return 2
    print(to_markdown(result))
    if not args.case:
        print(f"\nwrote {write_result(result)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
