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

``--serve`` soaks the real command instead (issue 31: "soak re-run in the default worker
mode"): ``glmav-observer serve --link udpin:127.0.0.1:PORT`` as a subprocess, on the
shipped configuration with its default outputs (Zenoh on, the embedded loopback peer;
a service id of its own), once without ``--workers`` (serve's default: one worker per
usable core) and once with ``--workers 1``, fed by one ``glmav-sitl fleet`` process
replaying a recorded ``cruise`` flight (with SIM_STATE truth) as N vehicles (default 8,
the shipped ``max_vehicles``; 8 x 381 = 3,050 datagrams/s, below what one worker with
its outputs decoded at most in benchmarks/bench_fleet, 4,584/s) to that port. Measured
from outside every second with psutil: the RSS and open file descriptors of the parent
and of every worker (slope per minute after the warm-up, least squares), the kernel's
drops on the port (/proc/net/udp) and the load average; then frames sent against frames
decoded (serve's summary), SIGTERM to the parent's pid, the time to exit, the exit code
and the summary.

    python -m benchmarks.soak --serve                # 8 vehicles, 600 s per mode
    python -m benchmarks.soak --serve --quick        # 60 s per mode
    GLMAV_SOAK_VEHICLES=10 GLMAV_SOAK_SECONDS=1200 python -m benchmarks.soak --serve
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import RESULTS_DIR, format_goals, format_table, goal, machine, main_for
from glmav_testkit.fleet_helpers import SITL, frames_sent, udp_queue, wait_drained
from glmav_testkit.serve_process import (
    ServeProcess,
    free_udp_port,
    loadavg_1min,
    slope_per_min,
    summarise_processes,
    usable_cores,
)
from glmav_testkit.soakrun import soak

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks" / "soak.md"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--serve",
        action="store_true",
        help="soak the real `glmav-observer serve` (subprocess) in the default worker mode "
        "and with one worker, instead of the service in this process",
    )


def run(quick: bool = False, serve: bool = False) -> dict[str, Any]:
    if serve:
        return run_serve(quick)
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


#: the shipped ``[ingest] max_vehicles``: the soak stays inside the shipped configuration
SERVE_VEHICLES = 8
#: a leak of 0.1 MB/min is 144 MB a day: what a flat process must stay under (the RSS
#: sampled every second moves by ~0.1 MB with the allocator's arenas, fitted over >= 45 min
#: of samples in the 10-minute record)
RSS_SLOPE_MB_PER_MIN = 0.1
#: the stop after SIGTERM: Zenoh sessions closed, rates restored, the summary (the issue's
#: flood test stops within 0.6 s; 5 s leaves room for a loaded machine)
STOP_S = 5.0
_ACTIVE_RMSE = re.compile(r"(?m)^\s+active\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)$")


def run_serve(quick: bool = False) -> dict[str, Any]:
    """The real ``serve`` in the default worker mode, then with one worker."""
    n = int(os.environ.get("GLMAV_SOAK_VEHICLES", str(SERVE_VEHICLES)))
    duration = float(os.environ.get("GLMAV_SOAK_SECONDS", "60" if quick else "600"))
    warmup = min(60.0, duration / 4)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="glmav-soak-serve-") as tmp:
        from glmav_sitl.fleet import record_tlog

        # one flight with SIM_STATE truth, recorded once for both modes
        tlog = record_tlog(Path(tmp) / "cruise.tlog", duration + 2.0, scenario="cruise")
        modes = [
            _serve_mode(tlog, n, duration, warmup, workers=w, tmp=Path(tmp)) for w in (None, 1)
        ]
    goals = []
    for m in modes:
        label = m["mode"]
        goals += [
            goal(f"{label}: exit code after SIGTERM", float(abs(m["returncode"])), 0.0,
                 higher_is_better=False),
            goal(f"{label}: summary printed", float(m["summary_present"]), 1.0,
                 higher_is_better=True),
            goal(f"{label}: time to exit after SIGTERM (s)", m["stop_s"], STOP_S,
                 higher_is_better=False),
            goal(f"{label}: |frames sent - (decoded + kernel drops)|",
                 float(abs(m["sent"] - m["frames_ok"] - m["kernel_drops"])), 0.0,
                 higher_is_better=False),
            goal(f"{label}: dropped datagrams (% of sent)", m["dropped_pct"], 1.0,
                 higher_is_better=False),
            goal(f"{label}: vehicles estimated", float(m["vehicles_seen"]), float(n),
                 higher_is_better=True),
            goal(f"{label}: largest RSS slope of a process after warm-up (MB/min)",
                 max(abs(p["rss_slope_mb_per_min"]) for p in m["processes"].values()),
                 RSS_SLOPE_MB_PER_MIN, higher_is_better=False),
            goal(f"{label}: open fds, most grown in a process after warm-up",
                 float(max(p["fds_end"] - p["fds_warm"] for p in m["processes"].values())),
                 0.0, higher_is_better=False),
        ]  # fmt: skip
    return {
        "name": "soak_serve",
        "quick": quick,
        "n_vehicles": n,
        "duration_s": duration,
        "warmup_s": warmup,
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "modes": modes,
        "goals": goals,
    }


def _serve_mode(
    tlog: Path, n: int, duration_s: float, warmup_s: float, *, workers: int | None, tmp: Path
) -> dict[str, Any]:
    """One soak of ``serve`` (``workers=None``: no ``--workers``, serve's default)."""
    port = free_udp_port()
    label = f"default ({usable_cores()} workers)" if workers is None else f"{workers} worker"
    sid = f"soak-{os.getpid()}-{'default' if workers is None else workers}"
    sp = ServeProcess(port, workers, tmp, zenoh=True, service_id=sid)
    gen_out, gen_err = tmp / f"fleet-{port}.out", tmp / f"fleet-{port}.err"
    gen: subprocess.Popen[str] | None = None
    samples: list[tuple[float, dict[str, dict[str, float]]]] = []
    drops: list[tuple[float, int]] = []
    load: list[tuple[float, float]] = []
    died_at_s: float | None = None
    try:
        sp.wait_ready()
        with gen_out.open("w") as fo, gen_err.open("w") as fe:
            gen = subprocess.Popen(
                [SITL, "fleet", "--tlog", str(tlog), "--vehicles", str(n),
                 "--duration", f"{duration_s:.1f}", "--stagger", "1",
                 "--link", f"udpout:127.0.0.1:{port}"],
                stdout=fo, stderr=fe, text=True,
            )  # fmt: skip
        t0 = time.monotonic()
        k = 0
        while gen.poll() is None:
            t = time.monotonic() - t0
            samples.append((t, sp.sample()))
            drops.append((t, udp_queue(port)[1]))
            load.append((t, loadavg_1min()))
            if not sp.alive():
                died_at_s = t
                break
            if t > duration_s + 120.0:
                raise TimeoutError("the fleet generator did not finish")
            k += 1
            time.sleep(max(0.0, t0 + k - time.monotonic()))  # one sample a second
        gen.wait(60.0)
        if gen.returncode != 0:
            raise RuntimeError(f"glmav-sitl fleet failed: {gen_err.read_text()[-500:]}")
        sent = frames_sent(gen_out.read_text())
        kernel_drops = wait_drained(port, 300.0) if died_at_s is None else udp_queue(port)[1]
        time.sleep(0.5)  # the last datagrams read are being estimated
        samples.append((time.monotonic() - t0, sp.sample()))
        cpu = {}
        for name, p in sp.processes():
            try:
                c = p.cpu_times()
                cpu[name] = c.user + c.system
            except OSError:
                continue
        alive = sp.alive()
        stopped = sp.stop()
    except BaseException:
        sp.kill()
        if gen is not None and gen.poll() is None:
            gen.kill()
        raise
    summ = stopped.summary
    frames_ok = summ.link.get("frames_ok", 0)
    rmse = [max(map(float, g)) for g in _ACTIVE_RMSE.findall(summ.text)]
    total = [(t, sum(v["rss_mb"] for v in s.values())) for t, s in samples if t >= warmup_s]
    procs = summarise_processes(samples, warmup_s)
    minute = []  # the first sample of every minute, and the last
    for i, (t, smp) in enumerate(samples):
        if i == len(samples) - 1 or not minute or t // 60 > minute[-1]["t_s"] // 60:
            minute.append({"t_s": round(t), **{k: round(v["rss_mb"], 2) for k, v in smp.items()}})
    return {
        "mode": label,
        "workers_arg": workers,
        "workers": max(1, len(summ.workers)),
        "port": port,
        "vehicles": n,
        "sent": sent,
        "frames_ok": frames_ok,
        "dropped": sent - frames_ok,
        "dropped_pct": 100.0 * (sent - frames_ok) / max(1, sent),
        "kernel_drops": kernel_drops,
        "kernel_drops_counted": summ.link.get("datagrams_dropped_by_kernel", 0),
        "messages": summ.messages,
        "records": summ.records,
        "rejected_frames": summ.rejected_frames,
        "vehicles_seen": len(summ.vehicles),
        "max_rmse_active_mps": max(rmse) if rmse else None,
        "alive_after_traffic": alive,
        "died_at_s": died_at_s,
        "returncode": stopped.returncode,
        "summary_present": summ.present,
        "stop_s": stopped.stop_s,
        "tracebacks": stopped.stderr.count("Traceback"),
        "stderr_tail": stopped.stderr[-1500:] if stopped.returncode != 0 else "",
        "worker_lines": summ.workers,
        "processes": procs,
        "cpu_s": cpu,
        "rss_total_slope_mb_per_min": slope_per_min(total),
        "rss_by_minute_mb": minute,
        "kernel_drops_series": [(round(t, 1), d) for t, d in drops],
        "loadavg_1min_series": [(round(t, 1), round(v, 2)) for t, v in load],
    }


def serve_to_markdown(result: dict[str, Any]) -> str:
    r = result
    m = r.get("machine") or machine()
    lines = [
        f"Command: `python -m benchmarks.soak --serve{' --quick' if r['quick'] else ''}` — "
        f"the real `glmav-observer serve` (subprocess, shipped configuration, default outputs: "
        f"Zenoh on) fed by `glmav-sitl fleet` with {r['n_vehicles']} vehicles × "
        f"{r['duration_s']:.0f} s per mode over UDP loopback, warm-up {r['warmup_s']:.0f} s; "
        f"{m['cpu']}, {m['cores']} cores; load average {r['loadavg_before'][0]:.1f} before, "
        f"{r['loadavg_after'][0]:.1f} after"
        + (f" (run at {r['git_head']})" if r.get("git_head") else "")
        + ".",
        "",
        format_goals(r["goals"]),
        "",
    ]
    for md in r["modes"]:
        during = [v for _, v in md["loadavg_1min_series"]]
        rmse = md["max_rmse_active_mps"]
        lines += [
            f"### {md['mode']}",
            "",
            f"- Frames: {md['sent']:,} sent, {md['frames_ok']:,} decoded, "
            f"{md['kernel_drops']:,} dropped by the kernel (the service counted "
            f"{md['kernel_drops_counted']:,}), {md['rejected_frames']} rejected; "
            f"{md['messages']:,} messages, {md['records']:,} records, "
            f"{md['vehicles_seen']} vehicles"
            + (f", max active RMSE {rmse:.3f} m/s" if rmse is not None else "")
            + ".",
            f"- Stop: SIGTERM to the parent, exit code {md['returncode']} after "
            f"{md['stop_s']:.2f} s, summary {'printed' if md['summary_present'] else 'MISSING'}"
            f", {md['tracebacks']} tracebacks in the log"
            + ("; " + "; ".join(md["worker_lines"]) if md["worker_lines"] else "")
            + ".",
            f"- Load average during the run: min {min(during):.1f}, max {max(during):.1f}; "
            f"RSS of all the service's processes together: "
            f"{md['rss_total_slope_mb_per_min']:+.4f} MB/min.",
            "",
            format_table([
                {"process": name, **p, "cpu_s": md["cpu_s"].get(name, float("nan"))}
                for name, p in md["processes"].items()
            ]),
            "",
            "RSS (MB) by minute:",
            "",
            format_table(md["rss_by_minute_mb"]),
            "",
        ]  # fmt: skip
    return "\n".join(lines)


def write_doc() -> None:
    """docs/benchmarks/soak.md from the recorded results (either or both)."""
    parts = ["# soak", ""]
    one = RESULTS_DIR / "soak.json"
    two = RESULTS_DIR / "soak_serve.json"
    if two.exists():
        parts += [
            "## The real `serve`, default worker mode and one worker (issue 31)",
            "",
            serve_to_markdown(json.loads(two.read_text())),
        ]
    if one.exists():
        parts += [
            "## The service in the benchmark's process",
            "",
            to_markdown(json.loads(one.read_text())),
        ]
    DOC.parent.mkdir(parents=True, exist_ok=True)
    DOC.write_text("\n".join(parts), encoding="utf-8")


def _counted(r: dict[str, Any]) -> str:
    """What the service itself counted of the kernel's drops (a run recorded before it
    counted them has none)."""
    n = r.get("kernel_drops_counted")
    return "" if n is None else f"; the service counted {n:,} itself"


def to_markdown(result: dict[str, Any]) -> str:
    if result.get("name") == "soak_serve":
        return serve_to_markdown(result)
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
    write_doc()
    sys.exit(code)
