"""Fuzzing the ingest path: a million damaged inputs, zero crashes, every rejection counted.

The input path of the service (framing -> ingest -> one estimator per vehicle) gets the
simulator's valid MAVLink stream (vehicle 1, 6 s of the ``cruise`` scenario, one frame
per datagram as on UDP) with three damaged datagrams after every valid one
(``glmav_testkit.fuzzgen``: random bytes, truncated and spliced frames, wrong CRCs,
bad flags, unknown ids, NaN/inf/extreme values, time jumps, system and component id
storms, MAVLink 1 mixes, slices of the real corrupt ArduSub log). Sessions alternate:

- *vehicle-safe*: no damaged frame that passes the CRC carries the vehicle's ids (or
  its stamps are corrupt far beyond the forward window); the vehicle's velocity records
  must then be **identical** to those of the clean stream;
- *chaos*: anything goes, on the vehicle too; only no crash and full accounting.

Every decoded message must end as a sample, a consumed ``SYSTEM_TIME`` or a rejection
with a counted reason (``unaccounted`` must stay 0); numpy RuntimeWarnings count as
crashes. With ``atheris`` installed, a coverage-guided run (libFuzzer) over the same
path is added (subprocess: ``python -m benchmarks.fuzz_ingest --atheris -runs=N``).

    python -m benchmarks.fuzz_ingest            # 1,000,000 cases (record)
    python -m benchmarks.fuzz_ingest --quick    # 20,000 cases

``--serve`` fuzzes the real command instead (issue 31: "fuzz re-run in the default worker
mode"; ``glmav_testkit.serve_fuzz``): ``glmav-observer serve`` as a subprocess on
``udpin:127.0.0.1:PORT`` with its default outputs (Zenoh on, a service id of its own) and
``--out``, once without ``--workers`` (one worker per usable core) and once with
``--workers 1``; per mode a vehicle-safe session and a chaos session, each the vehicle's
stream (the simulator's ``cruise``, 120 s; 10 s with ``--quick``) sent at the vehicle's
own rate with three damaged datagrams after every valid frame, over UDP. Every datagram
is framed beforehand by the service's own decoder in this process: the service's link
counters (summed over the workers) must equal it reason by reason; no crash (alive after
the traffic, exit 0 after SIGTERM with its summary, no traceback); the sender holds back
while 1 MB is queued on the port, so no datagram is lost unless the service stops
reading; vehicle-safe: the vehicle's records identical to its clean stream's. In the
chaos sessions frames with the vehicle's own ids but another timeline are a second
source on its system id: the service stops estimating it by design (docs/reliability.md,
"Two sources with one system id"); its records are reported, not judged.

    python -m benchmarks.fuzz_ingest --serve            # 2 modes x 2 sessions x 120 s
    python -m benchmarks.fuzz_ingest --serve --quick    # 10 s sessions
"""

from __future__ import annotations

import argparse
import collections
import re
import subprocess
import sys
import time
import traceback
import warnings
from pathlib import Path
from typing import Any

from benchmarks.common import format_table, goal, main_for
from glmav_testkit.fuzzgen import (
    VEHICLE_SYSID,
    CaseMaker,
    ValidStream,
    load_corrupt_log,
    sitl_stream,
)
from glmav_testkit.ingest_harness import Harness, velocity_series

ROOT = Path(__file__).resolve().parents[1]
REAL_TLOGS = ROOT / "tests" / "data" / "real-tlogs"
CASES_PER_FRAME = 3
#: valid frames before the damage starts: the vehicle is admitted first. Without this, a
#: storm of new system ids can fill the vehicle cap before the vehicle's first sample
#: message, which then waits ``evict_idle_s`` (by design: docs/reliability.md).
WARMUP_FRAMES = 50
DOC = ROOT / "docs" / "benchmarks" / "fuzz_ingest.md"


def run_session(
    stream: ValidStream,
    clean_series: list[Any],
    corrupt: bytes,
    seed: int,
    *,
    vehicle_safe: bool,
    datagram: bool = True,
) -> dict[str, Any]:
    """One pass of the valid stream with damaged cases interleaved; what came out."""
    h = Harness(datagram=datagram)
    cm = CaseMaker(stream.frames, corrupt, seed, vehicle_safe=vehicle_safe)
    kinds: collections.Counter[str] = collections.Counter()
    crashes: list[str] = []
    n_crash = 0
    t_host = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for i, frame in enumerate(stream.frames):
            t_host += 0.001
            h.feed(frame, t_host)
            if i < WARMUP_FRAMES:
                continue
            v = h.ingest.vehicles.get(VEHICLE_SYSID)
            if v is not None and v.clock.t_now_s is not None:
                cm.t_ms = int(v.clock.t_now_s * 1000)
            for _ in range(CASES_PER_FRAME):
                kind, data = cm.make()
                kinds[kind] += 1
                try:
                    h.feed(data, t_host)
                except Exception:  # a crash is the finding: count it, keep fuzzing
                    n_crash += 1
                    if len(crashes) < 3:
                        crashes.append(f"{kind} {data.hex()}\n{traceback.format_exc(limit=4)}")
                    h.decoder = type(h.decoder)(datagram=datagram, counters=h.frame_counters)
    same = velocity_series(h.records.get(VEHICLE_SYSID, [])) == clean_series
    return {
        "cases": sum(kinds.values()),
        "kinds": dict(kinds),
        "crashes": n_crash,
        "crash_examples": crashes,
        "outcomes": dict(h.outcomes),
        "counts": h.counts(),
        "same_estimates": same,
        "nonfinite_velocity_records": h.nonfinite_velocity_records,
        "max_vehicles": h.max_vehicles_seen,
        "cap": h.ingest_config.max_vehicles,
    }


def run_atheris(runs: int, timeout_s: float = 600.0) -> dict[str, Any]:
    """The coverage-guided run in a subprocess (libFuzzer exits the process when done)."""
    try:
        import atheris  # noqa: F401
    except ImportError:
        return {"available": False}
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "benchmarks.fuzz_ingest",
                "--atheris",
                f"-runs={runs}",
                "-seed=1",
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
    except subprocess.TimeoutExpired:  # slow machine: say so, it is not a crash
        return {"available": True, "returncode": 0, "runs": 0, "wall_s": timeout_s,
                "coverage_edges": 0, "tail": f"timed out after {timeout_s:.0f} s"}  # fmt: skip
    wall = time.perf_counter() - t0
    m = re.search(r"Done (\d+) runs in (\d+) second", proc.stderr)
    cov = re.findall(r"cov: (\d+)", proc.stderr)
    return {
        "available": True,
        "returncode": proc.returncode,
        "runs": int(m.group(1)) if m else 0,
        "wall_s": wall,
        "coverage_edges": int(cov[-1]) if cov else 0,
        "tail": proc.stderr[-600:] if proc.returncode != 0 else "",
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--serve",
        action="store_true",
        help="fuzz the real `glmav-observer serve` over UDP in the default worker mode and "
        "with one worker, instead of the input path in this process",
    )


#: vehicle seconds of a ``--serve`` session (the vehicle's stream, fuzzed throughout)
SERVE_SESSION_S = 120.0
SERVE_SESSION_S_QUICK = 10.0


def run_serve(quick: bool = False) -> dict[str, Any]:
    """The damage over UDP to ``serve``, default workers and one worker (module docstring)."""
    import os
    import tempfile

    from glmav_testkit.serve_fuzz import clean_series, make_plan, run_session
    from glmav_testkit.serve_process import usable_cores

    vehicle_s = SERVE_SESSION_S_QUICK if quick else SERVE_SESSION_S
    t0 = time.perf_counter()
    stream = sitl_stream("cruise", vehicle_s, seed=1)
    clean = clean_series(stream)
    corrupt = load_corrupt_log(REAL_TLOGS)
    plans = {
        "vehicle-safe": make_plan(stream, vehicle_s, corrupt, 1001, vehicle_safe=True),
        "chaos": make_plan(stream, vehicle_s, corrupt, 1002, vehicle_safe=False),
    }
    prep_s = time.perf_counter() - t0
    load_before = os.getloadavg()
    sessions: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="glmav-fuzz-serve-") as tmp:
        for workers in (None, 1):
            mode = f"default ({usable_cores()} workers)" if workers is None else f"{workers} worker"
            for kind, plan in plans.items():
                sid = f"fuzz-{os.getpid()}-{'default' if workers is None else workers}-{kind}"
                r = run_session(plan, workers, Path(tmp), zenoh=True, service_id=sid)
                sessions.append(_serve_row(mode, kind, r, clean, vehicle_s))
                print(sessions[-1], file=sys.stderr, flush=True)
    goals = []
    for row in sessions:
        label = f"{row['mode']}, {row['session']}"
        goals += [
            goal(f"{label}: crashes (dead, exit code, no summary, traceback)",
                 float(row["crashed"]), 0.0, higher_is_better=False),
            goal(f"{label}: framing counters off the reference decoder (sum)",
                 float(row["framing_diff"]), 0.0, higher_is_better=False),
            goal(f"{label}: datagrams lost (kernel drops)", float(row["kernel_drops"]), 0.0,
                 higher_is_better=False),
        ]  # fmt: skip
        if row["session"] == "vehicle-safe":
            goals.append(goal(f"{label}: vehicle's records identical to the clean run",
                              float(row["vehicle_identical"]), 1.0, higher_is_better=True))  # fmt: skip
    return {
        "name": "fuzz_ingest_serve",
        "quick": quick,
        "vehicle_s": vehicle_s,
        "valid_frames": len(stream.frames),
        "clean_full_records": len(clean),
        "prep_s": prep_s,
        "kinds": {k: dict(sorted(p.kinds.items())) for k, p in plans.items()},
        "expected": {k: p.expected for k, p in plans.items()},
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "sessions": sessions,
        "goals": goals,
    }


def _serve_row(mode: str, kind: str, r: Any, clean: list[Any], vehicle_s: float) -> dict[str, Any]:
    s = r.stopped.summary
    framing = r.framing()
    expected = r.plan.expected
    diff = sum(abs(framing.get(k, 0) - expected.get(k, 0)) for k in set(framing) | set(expected))
    tracebacks = r.stopped.stderr.count("Traceback")
    crashed = (not r.alive_after_traffic or r.stopped.returncode != 0 or not s.present
               or tracebacks > 0)  # fmt: skip
    series = r.vehicle_series
    return {
        "mode": mode,
        "session": kind,
        "cases": r.plan.cases,
        "datagrams": r.sent,
        "wall_s": r.wall_s,
        "datagrams_per_s": r.sent / max(1e-9, r.wall_s),
        "held_s": r.held_s,
        "kernel_drops": r.kernel_drops,
        "alive_after_traffic": r.alive_after_traffic,
        "returncode": r.stopped.returncode,
        "summary_present": s.present,
        "tracebacks": tracebacks,
        "crashed": crashed,
        "stop_s": r.stopped.stop_s,
        "framing": framing,
        "framing_diff": diff,
        "rejected_frames": s.rejected_frames,
        "messages": s.messages,
        "records": s.records,
        "service_counters": s.service,
        "vehicles_in_summary": len(s.vehicles),  # admitted at some time (evicted ones too)
        "workers": s.workers,
        "vehicle_full_records": len(series),
        "vehicle_identical": series == clean,
        "vehicle_last_t_fraction": (series[-1][0] / clean[-1][0]) if series else 0.0,
        "rss_end_mb": {k: v["rss_mb"] for k, v in r.processes.items()},
        "stderr_tail": r.stopped.stderr[-1500:] if crashed else "",
    }


def serve_to_markdown(result: dict[str, Any]) -> str:
    from benchmarks.common import format_goals, machine

    r = result
    m = r.get("machine") or machine()
    cols = ("mode", "session", "cases", "datagrams", "datagrams_per_s", "held_s",
            "kernel_drops", "returncode", "stop_s", "rejected_frames", "messages",
            "vehicles_in_summary", "vehicle_full_records", "vehicle_identical",
            "vehicle_last_t_fraction")  # fmt: skip
    lines = [
        "Command: `python -m benchmarks.fuzz_ingest --serve"
        + (" --quick" if r["quick"] else "")
        + f"` — the real `glmav-observer serve` (default outputs: Zenoh on; `--out`), "
        f"per mode a vehicle-safe and a chaos session of {r['vehicle_s']:.0f} s of the "
        f"vehicle ({r['valid_frames']:,} valid frames, {CASES_PER_FRAME} damaged datagrams "
        f"after each) over UDP loopback; {m['cpu']}, {m['cores']} cores; load average "
        f"{r['loadavg_before'][0]:.1f} before, {r['loadavg_after'][0]:.1f} after"
        + (f" (run at {r['git_head']})" if r.get("git_head") else "")
        + ".",
        "",
        format_goals(r["goals"]),
        "",
        format_table([{k: row[k] for k in cols} for row in r["sessions"]]),
        "",
        "Framing counters (the service's, summed over its workers; equal to the reference "
        "decoder's where the goal above says 0):",
        "",
        format_table([
            {"mode": row["mode"], "session": row["session"], **row["framing"]}
            for row in r["sessions"]
        ]),
        "",
        "Service counters:",
        "",
    ]  # fmt: skip
    for row in r["sessions"]:
        sc = ", ".join(f"{k} {v:,}" for k, v in sorted(row["service_counters"].items()))
        lines.append(f"- {row['mode']}, {row['session']}: {sc}; RSS at the end (MB): "
                     + ", ".join(f"{k} {v:.1f}" for k, v in row["rss_end_mb"].items()))  # fmt: skip
    lines += [
        "",
        "Cases by kind: "
        + "; ".join(
            f"{k}: " + ", ".join(f"{n} {c:,}" for n, c in kinds.items())
            for k, kinds in r["kinds"].items()
        )
        + ".",
    ]
    for row in r["sessions"]:
        if row["stderr_tail"]:
            lines += ["", f"{row['mode']}, {row['session']} stderr:", "", "```",
                      row["stderr_tail"], "```"]  # fmt: skip
    return "\n".join(lines) + "\n"


def write_doc() -> None:
    """docs/benchmarks/fuzz_ingest.md from the recorded results (either or both)."""
    import json

    from benchmarks.common import RESULTS_DIR

    parts = ["# fuzz_ingest", ""]
    served = RESULTS_DIR / "fuzz_ingest_serve.json"
    inproc = RESULTS_DIR / "fuzz_ingest.json"
    if served.exists():
        parts += ["## The real `serve` over UDP, default worker mode and one worker (issue 31)",
                  "", serve_to_markdown(json.loads(served.read_text()))]  # fmt: skip
    if inproc.exists():
        parts += ["## The input path in the benchmark's process", "",
                  to_markdown(json.loads(inproc.read_text()))]  # fmt: skip
    DOC.parent.mkdir(parents=True, exist_ok=True)
    DOC.write_text("\n".join(parts), encoding="utf-8")


def run(quick: bool = False, serve: bool = False) -> dict[str, Any]:
    if serve:
        return run_serve(quick)
    n_target = 20_000 if quick else 1_000_000
    stream = sitl_stream("cruise", 6.0, seed=1)
    clean = Harness()
    clean.feed_all(stream.frames)
    clean_series = velocity_series(clean.records[VEHICLE_SYSID])
    corrupt = load_corrupt_log(REAL_TLOGS)
    totals: collections.Counter[str] = collections.Counter()
    kinds: collections.Counter[str] = collections.Counter()
    outcomes: collections.Counter[str] = collections.Counter()
    sessions = {"safe": 0, "safe_same": 0, "chaos": 0}
    crashes = 0
    examples: list[str] = []
    nonfinite = {"safe": 0, "chaos": 0}
    max_vehicles = 0
    cap = 0
    n = 0
    seed = 0
    t0 = time.perf_counter()
    while n < n_target:
        safe = seed % 2 == 0
        r = run_session(stream, clean_series, corrupt, seed, vehicle_safe=safe)
        seed += 1
        n += r["cases"]
        crashes += r["crashes"]
        examples += r["crash_examples"][: max(0, 3 - len(examples))]
        totals.update(r["counts"])
        kinds.update(r["kinds"])
        outcomes.update(r["outcomes"])
        max_vehicles = max(max_vehicles, r["max_vehicles"])
        cap = r["cap"]
        key = "safe" if safe else "chaos"
        sessions[key] += 1
        nonfinite[key] += r["nonfinite_velocity_records"]
        if safe and r["same_estimates"]:
            sessions["safe_same"] += 1
    wall = time.perf_counter() - t0
    ath = run_atheris(5_000 if quick else 30_000)
    rows = [{"reason": k, "count": v} for k, v in sorted(totals.items())]
    goals = [
        goal("cases run", float(n), float(n_target), higher_is_better=True),
        goal("crashes (exceptions, numpy warnings)", float(crashes), 0.0, higher_is_better=False),
        goal(
            "messages without a counted outcome",
            float(outcomes["unaccounted"]),
            0.0,
            higher_is_better=False,
        ),
        goal(
            "vehicle-safe sessions with estimates identical to the clean run (fraction)",
            sessions["safe_same"] / max(1, sessions["safe"]),
            1.0,
            higher_is_better=True,
        ),
        goal(
            "admitted vehicles at most the cap",
            float(max_vehicles),
            float(cap),
            higher_is_better=False,
        ),
    ]
    if ath.get("available"):
        goals.append(
            goal(
                "atheris: failing exit code",
                float(ath["returncode"] != 0),
                0.0,
                higher_is_better=False,
            )
        )
    return {
        "name": "fuzz_ingest",
        "quick": quick,
        "cases": n,
        "cases_per_s": n / wall,
        "wall_s": wall,
        "sessions": sessions,
        "valid_frames_per_session": len(stream.frames),
        "kinds": dict(sorted(kinds.items())),
        "outcomes": dict(sorted(outcomes.items())),
        "crashes": crashes,
        "crash_examples": examples,
        "nonfinite_velocity_records": nonfinite,
        "max_vehicles": max_vehicles,
        "atheris": ath,
        "rows": rows,
        "goals": goals,
    }


def to_markdown(result: dict[str, Any]) -> str:
    from benchmarks.common import format_goals

    if result.get("name") == "fuzz_ingest_serve":
        return serve_to_markdown(result)
    s = result["sessions"]
    ath = result["atheris"]
    lines = [
        "Command: `python -m benchmarks.fuzz_ingest`"
        + (" --quick" if result["quick"] else "")
        + f" — {result['cases']:,} damaged datagrams in {result['wall_s']:.0f} s "
        f"({result['cases_per_s']:,.0f} cases/s, one core, framing + ingest + estimators).",
        "",
        f"Sessions: {s['safe']} vehicle-safe ({s['safe_same']} with the vehicle's velocity "
        f"records identical to the clean run), {s['chaos']} chaos; "
        f"{result['valid_frames_per_session']} valid frames and "
        f"{CASES_PER_FRAME} damaged cases per valid frame in each.",
        "",
        format_goals(result["goals"]),
        "",
        "Cases by kind: " + ", ".join(f"{k} {v:,}" for k, v in result["kinds"].items()) + ".",
        "",
        "Outcome of every decoded message: "
        + ", ".join(f"{k} {v:,}" for k, v in result["outcomes"].items())
        + ".",
        "",
        "Non-finite velocity records: "
        + ", ".join(f"{k} {v}" for k, v in result["nonfinite_velocity_records"].items())
        + ".",
        "",
        "Rejections and events by reason (framing, ingest-wide, summed over the vehicles"
        " admitted at the end of each session):",
        "",
        format_table(result["rows"]),
        "",
    ]
    if ath.get("available"):
        lines.append(
            f"atheris (libFuzzer, coverage-guided, same path, datagram and stream framing): "
            f"{ath['runs']:,} runs in {ath['wall_s']:.0f} s, exit code {ath['returncode']}, "
            f"{ath['coverage_edges']} coverage edges."
            + (f" ({ath['tail']})" if ath.get("tail") else "")
        )
    else:
        lines.append("atheris: not installed in this environment (hypothesis runs in CI).")
    if result["crash_examples"]:
        lines += ["", "First crashes:", "", "```", *result["crash_examples"], "```"]
    return "\n".join(lines) + "\n"


def _atheris_main(argv: list[str]) -> None:
    import atheris

    atheris.instrument_all()  # the service's modules are loaded already (imports above)
    harnesses = [
        Harness(datagram=True, keep_records=False),
        Harness(datagram=False, keep_records=False),
    ]
    count = [0]

    def one_input(data: bytes) -> None:
        count[0] += 1
        if count[0] % 20_000 == 0:  # bounded state between long runs
            harnesses[:] = [
                Harness(datagram=True, keep_records=False),
                Harness(datagram=False, keep_records=False),
            ]
        for h in harnesses:
            h.feed(data, count[0] * 0.001)

    atheris.Setup([sys.argv[0], *argv], one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    if "--atheris" in sys.argv:
        _atheris_main([a for a in sys.argv[1:] if a != "--atheris"])
    else:
        code = main_for(sys.modules[__name__])
        write_doc()
        sys.exit(code)
