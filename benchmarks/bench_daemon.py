"""The daemon end to end: UDP in -> estimates out, against raw mavutil UDP receive.

Stream: the SITL's own MAVLink stream (``cruise`` scenario, default rates: HIGHRES_IMU,
SCALED_IMU, RAW_IMU 250 Hz each, ATTITUDE 100 Hz, LOCAL_POSITION_NED 30 Hz, SIM_STATE
50 Hz, one frame per datagram), taken from a ``--tlog`` of ``glmav-sitl run``; measured
twice: without SIM_STATE (what a real vehicle sends: the headline) and with it (a
simulator's stream: once a vehicle sends truth the service scores every estimate at
every IMU sample for its summary, which a real vehicle never pays for).

1. Throughput. Batches of datagrams are sent over UDP loopback into a socket's receive
   buffer, then drained and timed: (a) the service (``Service.feed_bytes``: framing,
   ingest, the observer bank, FDI, records) and (b) the baseline, pymavlink's
   ``mavutil`` ``udpin`` connection ``recv_msg()`` (receive and parse only), on the same
   datagrams in the same run. Messages per second = datagrams / drain time (median of
   the batches), and the service's CPU time per datagram over the drain. Goal: service
   >= 2x baseline (issue 30's, for the compiled core; issue 16's was 0.8x).
2. Latency at default rates. A subprocess replays the stream in real time; the service
   reads with kernel receive time stamps (``SO_TIMESTAMPNS``) and the latency of a
   datagram is the time from its arrival in the kernel to the return of ``feed_bytes``
   (its records handed to the sinks). Goal: p99 <= 1 ms (issue 30; issue 16's was 2 ms).

The headline is the service with its default outputs on: the sinks ``serve`` opens with
Zenoh on (:func:`benchmarks.outputs.default_output_sinks`, the product's ``open_sinks``)
and one real subscriber on ``glmav/**`` in another process; the service without sinks is
the baseline beside it in the same run (throughput: the same batches, in turn; and the
outputs without a subscriber there too).
"""

from __future__ import annotations

import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, machine
from benchmarks.outputs import Outputs, default_outputs, sinks_summary, with_unique_id

BATCH = 2000  # datagrams per batch: fits the default 4 MB receive buffer
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
#: the services compared, each with its own sinks
NO_OUTPUTS = "no outputs (baseline)"
OUTPUTS = "default outputs, subscribed"
OUTPUTS_UNSUBSCRIBED = "default outputs, no subscriber"


def _frames(duration_s: float) -> tuple[list[bytes], list[float]]:
    """The SITL's frames and their stream times (s) from a tlog of ``cruise``."""
    from glmav_observer.ingest.framing import iter_tlog

    with tempfile.TemporaryDirectory() as d:
        tlog = Path(d) / "cruise.tlog"
        sitl = str(Path(sys.executable).with_name("glmav-sitl"))
        subprocess.run(
            [sitl, "run", "--scenario", "cruise", "--duration", str(duration_s),
             "--speed", "max", "--seed", "1", "--tlog", str(tlog)],
            check=True, capture_output=True,
        )  # fmt: skip
        data = tlog.read_bytes()
    frames, times = [], []
    for rec in iter_tlog(data):
        frames.append(bytes(rec.msg.get_msgbuf()))
        times.append(rec.t_host_us * 1e-6)
    t0 = times[0]
    return frames, [t - t0 for t in times]


def _udp_pair(rcvbuf: int = 4 * 1024 * 1024) -> tuple[socket.socket, socket.socket, int]:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    return rx, tx, rx.getsockname()[1]


def _throughput(frames: list[bytes], n_batches: int, sinks: dict[str, list[Any]]) -> dict[str, Any]:
    """Per batch, the same datagrams drained by a service per entry of ``sinks`` (its
    outputs; in turn, the order rotating) and by mavutil."""
    from pymavlink import mavutil

    from glmav_observer.app import Service
    from glmav_observer.config import load_config

    config = load_config(None)
    services = {name: Service(config, s) for name, s in sinks.items()}
    rx, tx, port = _udp_pair()
    rx.setblocking(False)
    base = mavutil.mavlink_connection(f"udpin:127.0.0.1:{0}", source_system=255)
    base.port.close()
    base.port = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    base.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    base.port.bind(("127.0.0.1", 0))
    base.port.setblocking(False)
    base_port = base.port.getsockname()[1]
    svc_rates: dict[str, list[float]] = {name: [] for name in services}
    svc_cpu_us: dict[str, list[float]] = {name: [] for name in services}
    raw_rates = []
    lost = 0
    names = list(services)
    for b in range(n_batches):
        i0 = (b * BATCH) % max(1, len(frames) - BATCH)
        batch = frames[i0 : i0 + BATCH]
        for name in names[b % len(names) :] + names[: b % len(names)]:
            service = services[name]
            for f in batch:
                tx.sendto(f, ("127.0.0.1", port))
            n = 0
            t0 = time.perf_counter()
            c0 = time.process_time()
            while True:
                try:
                    data = rx.recv(65535)
                except BlockingIOError:
                    break
                service.feed_bytes("udp", data, time.monotonic())
                n += 1
            dt = time.perf_counter() - t0
            svc_rates[name].append(n / dt)
            svc_cpu_us[name].append((time.process_time() - c0) / max(n, 1) * 1e6)
            lost += len(batch) - n
        # baseline: mavutil receive + parse of the same datagrams
        for f in batch:
            tx.sendto(f, ("127.0.0.1", base_port))
        m = 0
        t0 = time.perf_counter()
        while True:
            msg = base.recv_msg()
            if msg is None:
                break
            m += 1
        dt = time.perf_counter() - t0
        raw_rates.append(m / dt)
    rx.close()
    tx.close()
    base.close()
    return {
        "service_msgs_per_s": {k: statistics.median(v) for k, v in svc_rates.items()},
        "service_cpu_us_per_datagram": {k: statistics.median(v) for k, v in svc_cpu_us.items()},
        "mavutil_msgs_per_s": statistics.median(raw_rates),
        "datagrams_lost": lost,
        "records": {k: svc.records for k, svc in services.items()},
    }


_SENDER = r"""
import socket, sys, time, struct
port = int(sys.argv[1]); path = sys.argv[2]
data = open(path, "rb").read()
frames, times = [], []
p = 0
while p < len(data):
    (t,), n = struct.unpack_from(">d", data, p), struct.unpack_from(">I", data, p + 8)[0]
    frames.append(data[p + 12 : p + 12 + n]); times.append(t); p += 12 + n
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
t0 = time.perf_counter() + 0.2
for f, t in zip(frames, times):
    d = t0 + t - time.perf_counter()
    if d > 0:
        time.sleep(d)
    s.sendto(f, ("127.0.0.1", port))
"""


def _latency(
    frames: list[bytes], times: list[float], seconds: float, sinks: list[Any]
) -> dict[str, Any]:
    from glmav_observer.app import Service
    from glmav_observer.config import load_config

    n = sum(1 for t in times if t <= seconds)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "stream.bin"
        path.write_bytes(
            b"".join(
                struct.pack(">dI", t, len(f)) + f
                for f, t in zip(frames[:n], times[:n], strict=True)
            )
        )
        rx, _tx, port = _udp_pair()
        rx.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        rx.settimeout(5.0)
        service = Service(load_config(None), sinks)
        sender = subprocess.Popen([sys.executable, "-c", _SENDER, str(port), str(path)])
        lat_kernel, lat_user = [], []
        try:
            for _ in range(n):
                data, anc, _flags, _addr = rx.recvmsg(65535, 1024)
                t_user = time.time_ns()
                service.feed_bytes("udp", data, time.monotonic())
                t_out = time.time_ns()
                for level, kind, payload in anc:
                    if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                        sec, nsec = struct.unpack("qq", payload[:16])
                        lat_kernel.append((t_out - (sec * 1_000_000_000 + nsec)) * 1e-9)
                lat_user.append((t_out - t_user) * 1e-9)
        finally:
            sender.wait(timeout=seconds + 30)
            rx.close()
    q = statistics.quantiles(lat_kernel, n=100)
    qu = statistics.quantiles(lat_user, n=100)
    return {
        "datagrams": len(lat_kernel),
        "p50_ms": q[49] * 1e3,
        "p99_ms": q[98] * 1e3,
        "max_ms": max(lat_kernel) * 1e3,
        "processing_p50_ms": qu[49] * 1e3,
        "processing_p99_ms": qu[98] * 1e3,
    }


def _config(tag: str) -> Any:
    from glmav_observer.config import load_config

    return with_unique_id(load_config(None), tag)


#: SIM_STATE's message id: the simulator's truth, which no real vehicle sends
SIM_STATE_MSGID = 108
#: the two streams measured: what a real vehicle sends (the headline), and the simulator's
#: own with its truth (for a vehicle that sends truth the estimator scores every estimate
#: at every IMU sample, ``VehicleEstimator.scorer``: a simulator pays for its summary's
#: RMSE)
REAL = "a real vehicle's stream (no SIM_STATE)"
SIMULATOR = "the simulator's stream with SIM_STATE (every estimate scored)"


def msgid_of(frame: bytes) -> int:
    """The message id of one MAVLink v1 or v2 frame."""
    if frame[0] == 0xFD:
        return frame[7] | frame[8] << 8 | frame[9] << 16
    return frame[5]


def _without_truth(frames: list[bytes], times: list[float]) -> tuple[list[bytes], list[float]]:
    kept = [(f, t) for f, t in zip(frames, times, strict=True) if msgid_of(f) != SIM_STATE_MSGID]
    return [f for f, _ in kept], [t for _, t in kept]


def run(quick: bool = False) -> dict[str, Any]:
    sim_frames, sim_times = _frames(6.0 if quick else 20.0)
    streams = {REAL: _without_truth(sim_frames, sim_times), SIMULATOR: (sim_frames, sim_times)}
    load_before = os.getloadavg()
    seconds = 3.0 if quick else 15.0
    outputs: dict[str, Outputs] = {}
    tp: dict[str, dict[str, Any]] = {}
    lat: dict[str, dict[str, dict[str, Any]]] = {}
    with (
        default_outputs(_config("daemon"), subscriber=True) as subscribed,
        default_outputs(_config("daemon-nosub")) as unsubscribed,
    ):
        outputs = {OUTPUTS: subscribed, OUTPUTS_UNSUBSCRIBED: unsubscribed}
        for stream, (frames, _) in streams.items():
            tp[stream] = _throughput(
                frames,
                3 if quick else 9,
                {
                    NO_OUTPUTS: [],
                    OUTPUTS: subscribed.sinks,
                    OUTPUTS_UNSUBSCRIBED: unsubscribed.sinks,
                },
            )
        load_mid = os.getloadavg()
        for stream, (frames, times) in streams.items():
            lat[stream] = {
                OUTPUTS: _latency(frames, times, seconds, subscribed.sinks),
                NO_OUTPUTS: _latency(frames, times, seconds, []),
            }
        opened = sinks_summary(subscribed.sinks)
    load_after = os.getloadavg()
    rows: list[dict[str, Any]] = []
    goals = []
    for stream in streams:
        t = tp[stream]
        rates = t["service_msgs_per_s"]
        cpu = t["service_cpu_us_per_datagram"]
        ratio = {k: v / t["mavutil_msgs_per_s"] for k, v in rates.items()}
        for name in (OUTPUTS, OUTPUTS_UNSUBSCRIBED, NO_OUTPUTS):
            rows += [
                {"stream": stream, "measure": f"service msgs/s (UDP in -> records out), {name}",
                 "value": rates[name]},
                {"stream": stream, "measure": f"service CPU µs per datagram, {name}",
                 "value": cpu[name]},
                {"stream": stream, "measure": f"ratio service / mavutil, {name}",
                 "value": ratio[name]},
            ]  # fmt: skip
        rows += [
            {"stream": stream, "measure": "mavutil recv_msg msgs/s (baseline)",
             "value": t["mavutil_msgs_per_s"]},
            {"stream": stream, "measure": "datagrams lost in throughput batches",
             "value": t["datagrams_lost"]},
        ]  # fmt: skip
        for name in (OUTPUTS, NO_OUTPUTS):
            la = lat[stream][name]
            rows += [
                {"stream": stream, "measure": f"latency {k} (ms), {name}", "value": la[key]}
                for k, key in (
                    ("p50 kernel arrival -> records", "p50_ms"),
                    ("p99 kernel arrival -> records", "p99_ms"),
                    ("max", "max_ms"),
                    ("processing p50 recv -> records", "processing_p50_ms"),
                    ("processing p99 recv -> records", "processing_p99_ms"),
                )
            ] + [{"stream": stream, "measure": f"latency sample (datagrams), {name}",
                  "value": la["datagrams"]}]  # fmt: skip
        goals += [
            goal(f"end-to-end throughput >= 2x raw mavutil receive (issue 30), {stream}, "
                 "default outputs on", ratio[OUTPUTS], 2.0, higher_is_better=True),
            goal(f"arrival-to-record latency p99 <= 1 ms at default rates (issue 30), {stream}, "
                 "default outputs on", lat[stream][OUTPUTS]["p99_ms"], 1.0,
                 higher_is_better=False),
            goal(f"end-to-end throughput >= 2x raw mavutil receive, {stream}, no outputs "
                 "(baseline)", ratio[NO_OUTPUTS], 2.0, higher_is_better=True),
            goal(f"arrival-to-record latency p99 <= 1 ms at default rates, {stream}, no outputs "
                 "(baseline)", lat[stream][NO_OUTPUTS]["p99_ms"], 1.0, higher_is_better=False),
        ]  # fmt: skip
    out_stats = {
        name: {
            "subscriber": o.stats.get("subscriber"),
            "sinks": {k: v for k, v in o.stats.items() if k != "subscriber"},
        }
        for name, o in outputs.items()
    }
    return {"name": "bench_daemon", "machine": machine(), "quick": quick, "rows": rows,
            "goals": goals, "sinks": opened, "outputs": out_stats,
            "records": {k: v["records"] for k, v in tp.items()},
            "loadavg_before": load_before, "loadavg_mid": load_mid,
            "loadavg_after": load_after}  # fmt: skip


def to_markdown(result: dict[str, Any]) -> str:
    parts = ["## bench_daemon: end-to-end daemon throughput and latency"]
    if result.get("label"):
        parts.append(f"Label: {result['label']}.")
    if result.get("sinks") is not None:
        lb, la = result["loadavg_before"], result["loadavg_after"]
        sub = (result.get("outputs", {}).get(OUTPUTS) or {}).get("subscriber") or {}
        parts.append(
            f"Headline: the service with its default outputs on ({', '.join(result['sinks'])} "
            "from `open_sinks(config, zenoh_enabled=True)`, one subscriber on `glmav/**` in "
            f"another process: {sub.get('samples', 0):,} samples received); the service "
            f"without sinks beside it, same run. Load average {lb[0]:.2f} before, "
            f"{la[0]:.2f} after."
        )
    parts += [format_table(result["rows"]), format_goals(result["goals"])]
    return "\n\n".join(parts)


if __name__ == "__main__":
    from benchmarks.common import main_for

    sys.exit(main_for(sys.modules[__name__]))
