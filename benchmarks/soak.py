"""Soak: N simulated vehicles (default 10) into one service for a long time.

Every vehicle is a ``glmav-sitl run`` subprocess in real time on its own UDP link
(HIGHRES_IMU 250 Hz, ATTITUDE 100 Hz, LOCAL_POSITION_NED 30 Hz, SIM_STATE 50 Hz: ~430
datagrams/s each); the service runs in this process with the shipped configuration.
Measured (``glmav_testkit.soakrun``): RSS growth after the warm-up, in = out counters
(samples out of ingest vs into the estimators, frames sent vs decoded + dropped by the
kernel, records produced vs received by the sink), per-datagram processing latency per
window, and each vehicle's RMSE against SIM_STATE.

    python -m benchmarks.soak                  # 10 vehicles, 600 s (the record)
    python -m benchmarks.soak --quick          # 10 vehicles, 60 s
    GLMAV_SOAK_VEHICLES=20 GLMAV_SOAK_SECONDS=1800 python -m benchmarks.soak
    GLMAV_SOAK_TRAFFIC=fleet python -m benchmarks.soak   # one glmav-sitl fleet process

``GLMAV_SOAK_TRAFFIC=fleet`` replaces the N simulator processes by one ``glmav-sitl fleet``
replaying one recorded flight as N vehicles to one port: the simulators no longer compete
with the service for the cores, so the drops measured are the service's own.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, machine, main_for
from glmav_testkit.soakrun import soak

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks" / "soak.md"


def run(quick: bool = False) -> dict[str, Any]:
    n = int(os.environ.get("GLMAV_SOAK_VEHICLES", "10"))
    duration = float(os.environ.get("GLMAV_SOAK_SECONDS", "60" if quick else "600"))
    warmup = min(60.0, duration / 4)
    load_before = os.getloadavg()
    traffic = os.environ.get("GLMAV_SOAK_TRAFFIC", "sitl")
    r = soak(n, duration, warmup, windows=4 if quick else 10, traffic=traffic)
    r["loadavg_before"] = load_before
    r["loadavg_after"] = os.getloadavg()
    w = r["latency_windows"]
    p99_first, p99_last = w[0]["p99_ms"], w[-1]["p99_ms"]
    r["name"] = "soak"
    r["quick"] = quick
    r["rows"] = w
    r["goals"] = [
        goal("RSS growth after warm-up (%)", r["rss_growth_pct"], 5.0, higher_is_better=False),
        goal(
            "samples out of ingest - samples into estimators",
            float(r["ingest_samples"] - r["estimator_samples"]),
            0.0,
            higher_is_better=False,
        ),
        goal(
            "frames sent - (decoded + kernel drops)",
            float(r["sent_frames"] - r["frames_ok"] - r["kernel_drops"]),
            0.0,
            higher_is_better=False,
        ),
        goal(
            "records produced - records at the sink",
            float(r["records"] - r["sink_records"]),
            0.0,
            higher_is_better=False,
        ),
        goal(
            "latency p99, last window / first window",
            p99_last / max(p99_first, 1e-6),
            2.0,
            higher_is_better=False,
        ),
        goal(
            "kernel-dropped datagrams (% of sent)",
            100.0 * r["kernel_drops"] / max(1, r["sent_frames"]),
            1.0,
            higher_is_better=False,
        ),
        goal(
            "|kernel drops the service counted - /proc/net/udp's|",
            float(abs(r["kernel_drops_counted"] - r["kernel_drops"])),
            0.0,
            higher_is_better=False,
        ),
    ]
    return r


def _counted(r: dict[str, Any]) -> str:
    """What the service itself counted of the kernel's drops (a run recorded before it
    counted them has none)."""
    n = r.get("kernel_drops_counted")
    return "" if n is None else f"; the service counted {n:,} itself"


def to_markdown(result: dict[str, Any]) -> str:
    r = result
    m = r.get("machine") or machine()
    rmse = [v for v in r["max_rmse_active_mps"].values() if v is not None]
    during = [v for _, v in r.get("loadavg_1min_series", [])]
    load_during = (
        f"; during the run (every second) min {min(during):.1f}, median "
        f"{statistics.median(during):.1f}, max {max(during):.1f}"
        if during
        else ""
    )
    lines = [
        f"Command: `{'GLMAV_SOAK_TRAFFIC=fleet ' if r.get('traffic') == 'fleet' else ''}"
        f"python -m benchmarks.soak{' --quick' if r['quick'] else ''}` — "
        f"{r['n_vehicles']} vehicles × {r['duration_s']:.0f} s in real time, warm-up "
        f"{r['warmup_s']:.0f} s; {m['cpu']}, {m['cores']} cores; load average "
        f"{r['loadavg_before'][0]:.1f} before, {r['loadavg_after'][0]:.1f} after"
        f"{load_during} (other work on the machine competes for the two cores).",
        "",
        format_goals(r["goals"]),
        "",
        f"- RSS: {r['rss_warm_mb']:.1f} MB after warm-up, {r['rss_end_mb']:.1f} MB at the end "
        f"({r['rss_growth_pct']:+.2f} %).",
        f"- Frames: {r['sent_frames']:,} sent, {r['frames_ok']:,} decoded, "
        f"{r['kernel_drops']:,} dropped by the kernel (receive buffer full: the service fell "
        f"behind{_counted(r)}), "
        f"{r['rejected_frames']} rejected; {r['messages']:,} messages.",
        f"- Samples: {r['ingest_samples']:,} out of ingest, {r['estimator_samples']:,} into the "
        f"estimators; records: {r['records']:,} produced, {r['sink_records']:,} at the sink.",
        f"- Throughput: {r['datagrams_per_s']:,.0f} datagrams/s processed after warm-up.",
        f"- Latency per datagram (arrival to records at the sinks): p50 "
        f"{r['latency_p50_ms']:.3f} ms, p99 {r['latency_p99_ms']:.2f} ms, max "
        f"{r['latency_max_ms']:.1f} ms.",
        f"- Accuracy: max per-axis RMSE of the active estimate over the vehicles "
        f"{max(rmse):.3f} m/s (median {sorted(rmse)[len(rmse) // 2]:.3f})."
        if rmse
        else "- Accuracy: no truth",
        "",
        "Latency, kernel drops and the 1-minute load average by window:",
        "",
        format_table(r["rows"]),
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    code = main_for(sys.modules[__name__])
    res = ROOT / "benchmarks" / "results" / "soak.json"
    if res.exists():
        DOC.parent.mkdir(parents=True, exist_ok=True)
        DOC.write_text("# soak\n\n" + to_markdown(json.loads(res.read_text())), encoding="utf-8")
    sys.exit(code)
