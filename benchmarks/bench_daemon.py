"""The daemon end to end: UDP in -> estimates out, against raw mavutil UDP receive.

Stream: the SITL's own MAVLink stream (``cruise`` scenario, default rates: HIGHRES_IMU,
SCALED_IMU, RAW_IMU 250 Hz each, ATTITUDE 100 Hz, LOCAL_POSITION_NED 30 Hz, SIM_STATE
50 Hz, one frame per datagram), taken from a ``--tlog`` of ``glmav-sitl run``.

1. Throughput. Batches of datagrams are sent over UDP loopback into a socket's receive
   buffer, then drained and timed: (a) the service (``Service.feed_bytes``: framing,
   ingest, the observer bank, FDI, records) and (b) the baseline, pymavlink's
   ``mavutil`` ``udpin`` connection ``recv_msg()`` (receive and parse only), on the same
   datagrams in the same run. Messages per second = datagrams / drain time (median of
   the batches), and the service's CPU time per datagram over the drain. Goal: service
   >= 0.8x baseline (issue 16; it was 0.5x).
2. Latency at default rates. A subprocess replays the stream in real time; the service
   reads with kernel receive time stamps (``SO_TIMESTAMPNS``) and the latency of a
   datagram is the time from its arrival in the kernel to the return of ``feed_bytes``
   (its records handed to the sinks). Goal: p99 <= 2 ms.
"""

from __future__ import annotations

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

BATCH = 2000  # datagrams per batch: fits the default 4 MB receive buffer
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)


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


def _throughput(frames: list[bytes], n_batches: int) -> dict[str, Any]:
    from pymavlink import mavutil

    from glmav_observer.app import Service
    from glmav_observer.config import load_config

    service = Service(load_config(None), [])
    rx, tx, port = _udp_pair()
    rx.setblocking(False)
    base = mavutil.mavlink_connection(f"udpin:127.0.0.1:{0}", source_system=255)
    base.port.close()
    base.port = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    base.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    base.port.bind(("127.0.0.1", 0))
    base.port.setblocking(False)
    base_port = base.port.getsockname()[1]
    svc_rates, raw_rates, svc_cpu_us = [], [], []
    lost = 0
    for b in range(n_batches):
        i0 = (b * BATCH) % max(1, len(frames) - BATCH)
        batch = frames[i0 : i0 + BATCH]
        # service
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
        svc_rates.append(n / dt)
        svc_cpu_us.append((time.process_time() - c0) / max(n, 1) * 1e6)
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
        "service_msgs_per_s": statistics.median(svc_rates),
        "service_cpu_us_per_datagram": statistics.median(svc_cpu_us),
        "mavutil_msgs_per_s": statistics.median(raw_rates),
        "datagrams_lost": lost,
        "records": service.records,
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


def _latency(frames: list[bytes], times: list[float], seconds: float) -> dict[str, Any]:
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
        service = Service(load_config(None), [])
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


def run(quick: bool = False) -> dict[str, Any]:
    frames, times = _frames(6.0 if quick else 20.0)
    tp = _throughput(frames, 3 if quick else 9)
    lat = _latency(frames, times, 3.0 if quick else 15.0)
    ratio = tp["service_msgs_per_s"] / tp["mavutil_msgs_per_s"]
    rows = [
        {"measure": "service msgs/s (UDP in -> records out)", "value": tp["service_msgs_per_s"]},
        {"measure": "mavutil recv_msg msgs/s (baseline)", "value": tp["mavutil_msgs_per_s"]},
        {
            "measure": "service CPU µs per datagram (receive, decode, estimation, records)",
            "value": tp["service_cpu_us_per_datagram"],
        },
        {"measure": "ratio service / baseline", "value": ratio},
        {"measure": "datagrams lost in throughput batches", "value": tp["datagrams_lost"]},
        {"measure": "latency p50 kernel arrival -> records (ms)", "value": lat["p50_ms"]},
        {"measure": "latency p99 kernel arrival -> records (ms)", "value": lat["p99_ms"]},
        {"measure": "latency max (ms)", "value": lat["max_ms"]},
        {"measure": "processing p50 recv -> records (ms)", "value": lat["processing_p50_ms"]},
        {"measure": "processing p99 recv -> records (ms)", "value": lat["processing_p99_ms"]},
        {"measure": "latency sample (datagrams)", "value": lat["datagrams"]},
    ]
    goals = [
        goal("end-to-end throughput >= 0.8x raw mavutil receive (issue 16)", ratio, 0.8,
             higher_is_better=True),
        goal("arrival-to-record latency p99 <= 2 ms at default rates", lat["p99_ms"], 2.0,
             higher_is_better=False),
    ]  # fmt: skip
    return {"name": "bench_daemon", "machine": machine(), "quick": quick, "rows": rows,
            "goals": goals}  # fmt: skip


def to_markdown(result: dict[str, Any]) -> str:
    return "\n\n".join(
        [
            "## bench_daemon: end-to-end daemon throughput and latency",
            format_table(result["rows"]),
            format_goals(result["goals"]),
        ]
    )


if __name__ == "__main__":
    from benchmarks.common import main_for

    sys.exit(main_for(sys.modules[__name__]))
