"""The soak: N simulated vehicles into one service over UDP loopback for a while.

Each vehicle is a ``glmav-sitl run`` subprocess (real time, its own system id and seed,
alternating scenarios), or, with ``traffic="fleet"``, all vehicles come from one
``glmav-sitl fleet`` process replaying one recorded simulator flight (with SIM_STATE
truth) as N system ids to one port, so that the machine's cores go to the service
rather than to N simulators. Either way they send to one service in this process (``Service.run`` on
``udpin:127.0.0.1:PORT`` in a thread, the shipped ``configs/service.toml`` with the cap
raised to N). Measured:

- RSS of this process (psutil) every second; growth = median of the last 5 samples over
  the median of the 5 samples right after the warm-up;
- in = out: samples emitted by ingest vs samples consumed by the estimators; frames the
  simulators sent vs frames decoded + datagrams the kernel dropped (``/proc/net/udp``);
  records produced vs records the sink received;
- processing latency per datagram (arrival to its records handed to the sinks), p50/p99
  per window of the run, to show it does not drift.
"""

from __future__ import annotations

import bisect
import math
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import psutil

from glmav_observer.app import Service
from glmav_observer.config import load_config
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.ingest.links import KERNEL_DROPS_COUNTER, Link
from glmav_observer.ingest.samples import AttitudeSample, ImuSample, TruthSample, VelocitySample
from glmav_observer.records import Record
from glmav_testkit import REPO_ROOT

REPO = REPO_ROOT
SITL = str(Path(sys.executable).with_name("glmav-sitl"))
SCENARIOS = ("cruise", "hover", "climbing-turn", "gusts")
_SAMPLE_TYPES = (AttitudeSample, ImuSample, TruthSample, VelocitySample)


class CountingSink:
    """Counts records (keeps none: the soak must measure the service, not its test sink)."""

    def __init__(self) -> None:
        self.n = 0
        self.closed = False

    def write(self, record: Record) -> None:
        self.n += 1

    def close(self) -> None:
        self.closed = True


def _udp_drops(ports: list[int]) -> int:
    want = {f"0100007F:{p:04X}" for p in ports}
    total = 0
    with open("/proc/net/udp", encoding="ascii") as f:
        for line in f.readlines()[1:]:
            cols = line.split()
            if cols[1] in want:
                total += int(cols[-1])
    return total


#: upper edges of the latency histogram bins: 1 µs to 100 s, 50 bins per decade (±2.3 %)
_EDGES_S = [10 ** (-6 + i / 50) for i in range(8 * 50 + 1)]


def _hq(counts: list[int], q: float) -> float:
    """The ``q`` quantile of a histogram over ``_EDGES_S`` (upper bin edge)."""
    n = sum(counts)
    if n == 0:
        return float("nan")
    target = max(1, math.ceil(q * n))
    acc = 0
    for i, c in enumerate(counts):
        acc += c
        if acc >= target:
            return _EDGES_S[i]
    return _EDGES_S[-1]


def _at(series: list[tuple[float, int]], t: float) -> int:
    """The last value of a (time, cumulative count) series at or before ``t`` (0 before)."""
    i = bisect.bisect_right([x for x, _ in series], t)
    return series[i - 1][1] if i else 0


def _median_in(series: list[tuple[float, float]], a: float, b: float) -> float:
    vals = [v for t, v in series if a <= t < b]
    return statistics.median(vals) if vals else float("nan")


def soak(
    n_vehicles: int = 10,
    duration_s: float = 60.0,
    warmup_s: float = 15.0,
    windows: int = 4,
    traffic: str = "sitl",
) -> dict[str, Any]:
    """Run the soak; returns the measurements (see the module docstring).

    One UDP link per vehicle (as one radio per vehicle on a ground station), so that the
    service's SET_MESSAGE_INTERVAL requests reach each vehicle."""
    links: dict[str, Link] = {}
    ports: list[int] = []
    # the design's streams (HIGHRES_IMU 250 Hz, ATTITUDE 100, LOCAL_POSITION_NED 30,
    # SIM_STATE 50) without RAW_IMU/SCALED_IMU, which the service would ask to stop anyway
    from glmav_sitl.config import data_path

    sitl_toml = data_path("sitl.toml")
    text = re.sub(r"(?m)^(raw_imu|scaled_imu) = .*$", r"\1 = 0.0", sitl_toml.read_text())
    tmp = tempfile.TemporaryDirectory(prefix="glmav-soak-")
    sitl_cfg = Path(tmp.name) / "sitl.toml"
    sitl_cfg.write_text(text, encoding="utf-8")
    if traffic not in ("sitl", "fleet"):
        raise ValueError(f"traffic {traffic!r}: 'sitl' or 'fleet'")
    tlog: Path | None = None
    if traffic == "fleet":
        from glmav_sitl.fleet import record_tlog

        # one flight with SIM_STATE truth, recorded once (about 0.2 s of CPU per second)
        tlog = record_tlog(Path(tmp.name) / "cruise.tlog", duration_s + 2.0, scenario="cruise")
    cfg = load_config(REPO / "configs" / "service.toml")
    rates = dict(cfg.ingest.rates_hz)
    rates.update({"RAW_IMU": -1.0, "SCALED_IMU": -1.0})  # HIGHRES_IMU is the one used
    # no rate requests: the simulators are configured with the wanted streams, and the
    # COMMAND_ACKs they would send back are not in their "N messages" (in = out exact)
    cfg = replace(
        cfg,
        request_rates=False,
        ingest=replace(cfg.ingest, rates_hz=rates, max_vehicles=n_vehicles),
    )
    sink = CountingSink()
    svc = Service(cfg, [sink])

    # instrumentation: samples out of ingest, samples into the estimators, latency
    counts = {"ingest_samples": 0, "estimator_samples": 0}
    orig_on_message = svc.ingest.on_message

    def on_message(msg: Any, t: float) -> list[Any]:
        ev = orig_on_message(msg, t)
        counts["ingest_samples"] += sum(isinstance(e, _SAMPLE_TYPES) for e in ev)
        return ev

    svc.ingest.on_message = on_message  # type: ignore[method-assign]
    orig_on_sample = VehicleEstimator.on_sample

    def on_sample(self: VehicleEstimator, s: Any) -> list[Record]:
        counts["estimator_samples"] += 1
        return orig_on_sample(self, s)

    # latency histograms per window, allocated up front (a list of samples would itself
    # grow by ~100 B per datagram and show up as RSS growth)
    span = max(1e-9, duration_s - warmup_s)
    hist = [[0] * len(_EDGES_S) for _ in range(windows)]
    orig_feed = svc.feed_bytes
    t_start = time.monotonic()

    def feed_bytes(link_id: str, data: bytes, t: float, *, datagram: bool = True) -> int:
        t0 = time.perf_counter()
        n = orig_feed(link_id, data, t, datagram=datagram)
        dt = time.perf_counter() - t0
        k = math.floor((t0 - t_start_pc - warmup_s) * windows / span)  # not int(): -0.5 -> 0
        if 0 <= k < windows:
            hist[k][min(len(_EDGES_S) - 1, bisect.bisect_left(_EDGES_S, dt))] += 1
        return n

    t_start_pc = time.perf_counter()
    svc.feed_bytes = feed_bytes  # type: ignore[method-assign]
    VehicleEstimator.on_sample = on_sample  # type: ignore[method-assign]

    for _ in range(n_vehicles if traffic == "sitl" else 1):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            ports.append(int(s.getsockname()[1]))
        links[f"udp{len(ports)}"] = Link(
            f"udpin:127.0.0.1:{ports[-1]}", udp_receive_buffer_bytes=cfg.udp_receive_buffer_bytes
        )
    stop = threading.Event()
    th = threading.Thread(target=svc.run, args=(links, stop), name="service", daemon=True)
    proc_self = psutil.Process()
    rss: list[tuple[float, int]] = []
    # kernel drops so far and the 1-minute load average, each second: where the drops
    # fall against the load of the shared machine
    drops_series: list[tuple[float, int]] = []
    load_series: list[tuple[float, float]] = []
    procs: list[subprocess.Popen[str]] = []
    sent = 0
    try:
        th.start()
        if tlog is not None:
            cmd = [SITL, "fleet", "--tlog", str(tlog),
                   "--vehicles", str(n_vehicles), "--duration", f"{duration_s:.1f}",
                   "--link", f"udpout:127.0.0.1:{ports[0]}"]  # fmt: skip
            procs.append(
                subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            )
        for i in range(n_vehicles if tlog is None else 0):
            cmd = [SITL, "run", "--scenario", SCENARIOS[i % len(SCENARIOS)],
                   "--duration", f"{duration_s:.1f}", "--speed", "realtime",
                   "--seed", str(100 + i), "--sysid", str(i + 1), "--config", str(sitl_cfg),
                   "--link", f"udpout:127.0.0.1:{ports[i]}"]  # fmt: skip
            procs.append(
                subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            )
        t_start = time.monotonic()
        while any(p.poll() is None for p in procs):
            t_now = time.monotonic() - t_start
            rss.append((t_now, proc_self.memory_info().rss))
            drops_series.append((t_now, _udp_drops(ports)))
            load_series.append((t_now, os.getloadavg()[0]))
            time.sleep(1.0)  # the sampling period of RSS (the flights run meanwhile)
            if time.monotonic() - t_start > duration_s + 120.0:
                raise TimeoutError("simulators did not finish")
        for p in procs:
            out, err = p.communicate(timeout=30)
            if p.returncode != 0:
                raise RuntimeError(f"glmav-sitl failed: {err[-500:]}")
            m = re.search(r"(\d+) messages" if tlog is None else r"(\d+) frames sent", out)
            if m is None:
                raise RuntimeError(f"no summary line: {out[-300:]}")
            sent += int(m.group(1))
        # drain: everything sent is either decoded or dropped by the kernel (up to 120 s:
        # on a loaded machine the backlog outlasts 30 s, and a stop no longer drains the
        # socket without bound, issue 18.6)
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            got = sum(d.counters.counts["frames_ok"] for d in svc.decoders.values())
            if got + _udp_drops(ports) >= sent:
                break
            time.sleep(0.05)
        drops = _udp_drops(ports)
    finally:
        stop.set()
        th.join(10.0)
        for lk in links.values():
            lk.close()
        VehicleEstimator.on_sample = orig_on_sample  # type: ignore[method-assign]
        for p in procs:
            if p.poll() is None:
                p.kill()
        svc.close()
        tmp.cleanup()
    summary = svc.summary()
    frames_ok = sum(c.get("frames_ok", 0) for c in summary.link_counters.values())
    after = [r for t, r in rss if t >= warmup_s]
    if len(after) < 10:
        raise ValueError("run longer than warm-up + 10 s to measure RSS growth")
    rss_warm = statistics.median(after[:5])
    rss_end = statistics.median(after[-5:])
    win: list[dict[str, float]] = []
    for k in range(windows):
        a, b = warmup_s + k * span / windows, warmup_s + (k + 1) * span / windows
        win.append({
            "from_s": a, "to_s": b, "datagrams": float(sum(hist[k])),
            "p50_ms": _hq(hist[k], 0.5) * 1e3, "p99_ms": _hq(hist[k], 0.99) * 1e3,
            "max_ms": _hq(hist[k], 1.0) * 1e3,
            "kernel_drops": float(_at(drops_series, b) - _at(drops_series, a)),
            "load_1min": _median_in(load_series, a, b),
        })  # fmt: skip
    total = [sum(col) for col in zip(*hist, strict=True)]
    rmse = {
        sysid: (max(v.rmse_ned_mps["active"]) if v.rmse_ned_mps.get("active") else None)
        for sysid, v in summary.vehicles.items()
    }
    return {
        "traffic": traffic,
        "n_vehicles": n_vehicles,
        "duration_s": duration_s,
        "warmup_s": warmup_s,
        "rss_warm_mb": rss_warm / 2**20,
        "rss_end_mb": rss_end / 2**20,
        "rss_growth_pct": 100.0 * (rss_end - rss_warm) / rss_warm,
        "rss_series_mb": [(round(t, 1), round(r / 2**20, 2)) for t, r in rss],
        "kernel_drops_series": [(round(t, 1), d) for t, d in drops_series],
        "loadavg_1min_series": [(round(t, 1), round(v, 2)) for t, v in load_series],
        "sent_frames": sent,
        "frames_ok": frames_ok,
        "rejected_frames": summary.rejected_frames,
        "kernel_drops": drops,
        # what the service itself counted (SO_MEMINFO on its sockets): equal to /proc's
        "kernel_drops_counted": sum(
            c.get(KERNEL_DROPS_COUNTER, 0) for c in summary.link_counters.values()
        ),
        "messages": summary.messages,
        "ingest_samples": counts["ingest_samples"],
        "estimator_samples": counts["estimator_samples"],
        "records": summary.records,
        "sink_records": sink.n,
        "vehicles": sorted(summary.vehicles),
        "max_rmse_active_mps": rmse,
        "latency_p50_ms": _hq(total, 0.5) * 1e3,
        "latency_p99_ms": _hq(total, 0.99) * 1e3,
        "latency_max_ms": _hq(total, 1.0) * 1e3,
        "latency_windows": win,
        "datagrams_per_s": sum(total) / span,
    }
