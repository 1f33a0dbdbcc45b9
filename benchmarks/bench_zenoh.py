"""Zenoh republishing: publish-to-receive latency and sustained rate through ``ZenohSink``
against a bare ``session.put`` of the same payload, in the same run.

Topology (loopback only, multicast scouting off): a router session on tcp/127.0.0.1, the
sink's session and a subscriber session as its clients, all in this process so that send
and receive times come from one clock (``time.perf_counter_ns``; the router is Rust and
holds no GIL). Latency: one sample in flight at a time, ours and bare alternating so that
drift and load hit both alike; the time runs from just before ``sink.write(record)`` (or
``session.put(key, payload)``, payload pre-encoded) to the subscriber's callback. Rate:
records (5 configurations of one vehicle per step) offered at 25k/s (paced in 1 ms bursts)
for 3 s, then delivered records per second of wall time and the delivered fraction; and,
for information, bursts as fast as possible through the sink and through bare puts of the
pre-encoded payloads (congestion control DROP drops what the link cannot take).
"""

from __future__ import annotations

import json
import math
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for, time_per_call_s
from glmav_observer.publish.zenoh_keys import encode_payload
from glmav_observer.publish.zenoh_sink import ZenohSink, open_zenoh_sink
from glmav_observer.records import CONFIGS, VelocityRecord

LATENCY_GOAL_RATIO = 1.5
RATE_GOAL_PER_S = 20_000.0
#: offered rate of the sustained test: 25 % above the goal (~19 vehicles at 250 Hz x 5 keys)
PACED_RATE_PER_S = 25_000.0


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _record(step: int, config: str = "full") -> VelocityRecord:
    t = 0.004 * step
    return VelocityRecord(
        sysid=1,
        config=config,
        t_boot_s=t,
        v_body_mps=(1.0 + math.sin(t), -0.5 + math.cos(t), 0.1 * math.sin(3 * t)),
        v_ned_mps=(0.9 + math.cos(t), 1.2 * math.sin(t), -0.05),
        lost_axis=None,
        health="ok",
        seq=step,
        source_config="full" if config == "active" else None,
    )


def _client(port: int) -> Any:
    import zenoh

    return zenoh.open(
        zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "client",
                    "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
                    "scouting": {"multicast": {"enabled": False}},
                }
            )
        )
    )


class _Receiver:
    """Arrival time (perf_counter_ns) of each sample, and an event for the one awaited."""

    def __init__(self) -> None:
        self.count = 0
        self.t_ns = 0
        self.event = threading.Event()

    def __call__(self, _sample: Any) -> None:
        self.t_ns = time.perf_counter_ns()
        self.count += 1
        self.event.set()


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def _latency(sink: ZenohSink, receiver: _Receiver, n: int) -> dict[str, list[float]]:
    import zenoh

    session = sink.session
    bare_key = "bench/1/velocity/full"
    out: dict[str, list[float]] = {"sink": [], "bare": []}
    records = [_record(i) for i in range(n)]
    payloads = [encode_payload(r) for r in records]
    json_enc = zenoh.Encoding.APPLICATION_JSON
    for i in range(n):
        for case in ("sink", "bare") if i % 2 == 0 else ("bare", "sink"):
            receiver.event.clear()
            t0 = time.perf_counter_ns()
            if case == "sink":
                sink.write(records[i])
            else:
                session.put(bare_key, payloads[i], encoding=json_enc)
            if not receiver.event.wait(2.0):
                raise RuntimeError(f"{case} sample {i} not received in 2 s")
            out[case].append((receiver.t_ns - t0) / 1e3)
    return out


def _rate(send: Any, items: list[Any], receiver: _Receiver) -> dict[str, float]:
    start_count = receiver.count
    t0_ns = time.perf_counter_ns()
    for item in items:
        send(item)
    t_written = (time.perf_counter_ns() - t0_ns) / 1e9
    deadline = time.monotonic() + 10.0
    last, last_change = -1, time.monotonic()
    while time.monotonic() < deadline:  # until all arrived, or nothing new for 0.5 s
        got = receiver.count - start_count
        if got >= len(items):
            break
        if got != last:
            last, last_change = got, time.monotonic()
        elif time.monotonic() - last_change > 0.5:
            break
        time.sleep(0.002)
    t_last_arrival = (receiver.t_ns - t0_ns) / 1e9
    delivered = receiver.count - start_count
    elapsed = max(t_written, t_last_arrival)
    return {
        "records": float(len(items)),
        "write_rate_per_s": len(items) / t_written,
        "delivered": float(delivered),
        "delivered_rate_per_s": delivered / elapsed,
        "delivered_fraction": delivered / len(items),
    }


def _paced(send: Any, rate_per_s: float) -> Any:
    """A sender for :func:`_rate` that offers ``items`` at ``rate_per_s`` (bursts of 1 ms)."""
    t0 = [0.0]
    sent = [0]

    def send_paced(item: Any) -> None:
        if sent[0] == 0:
            t0[0] = time.perf_counter()
        send(item)
        sent[0] += 1
        if sent[0] % max(1, int(rate_per_s / 1000)) == 0:
            delay = t0[0] + sent[0] / rate_per_s - time.perf_counter()
            if delay > 0:
                time.sleep(delay)

    return send_paced


def run(quick: bool = False) -> dict[str, Any]:
    import zenoh

    n_latency = 300 if quick else 3000
    n_rate_steps = 2000 if quick else 10000
    port = _free_port()
    router = zenoh.open(
        zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "router",
                    "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
                    "scouting": {"multicast": {"enabled": False}},
                }
            )
        )
    )
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "client.json5"
        config.write_text(
            json.dumps(
                {
                    "mode": "client",
                    "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
                    "scouting": {"multicast": {"enabled": False}},
                }
            ),
            encoding="utf-8",
        )
        sink = open_zenoh_sink(str(config), service_id="bench", effective_config={})
    subscriber = _client(port)
    receiver = _Receiver()
    sub_sink = subscriber.declare_subscriber("glmav/**", receiver)
    sub_bare = subscriber.declare_subscriber("bench/**", receiver)
    try:
        # warm-up: routes established, publishers declared, caches hot
        deadline = time.monotonic() + 10
        while receiver.count < 50 and time.monotonic() < deadline:
            sink.write(_record(0))
            sink.session.put("bench/1/velocity/full", encode_payload(_record(0)))
            time.sleep(0.002)
        lat = _latency(sink, receiver, n_latency)

        records = [_record(s, c) for s in range(n_rate_steps) for c in (*CONFIGS, "active")]
        payloads = [(f"bench/1/velocity/{r.config}", encode_payload(r)) for r in records]
        enc = zenoh.Encoding.APPLICATION_JSON
        bare_pubs = {
            k: sink.session.declare_publisher(
                k, encoding=enc, congestion_control=zenoh.CongestionControl.DROP
            )
            for k in {k for k, _ in payloads}
        }
        rate_sink = _rate(sink.write, records, receiver)
        n_paced = int(PACED_RATE_PER_S * (1.0 if quick else 3.0))
        paced = [_record(s, c) for s in range(n_paced // 5) for c in (*CONFIGS, "active")]
        rate_paced = _rate(_paced(sink.write, PACED_RATE_PER_S), paced, receiver)
        rate_bare = _rate(lambda kp: bare_pubs[kp[0]].put(kp[1]), payloads, receiver)

        # the time write() holds the estimator, with nobody subscribed to that vehicle
        sub_sink.undeclare()
        it = iter(range(10**12))
        write_t = time_per_call_s(
            lambda: sink.write(_record(next(it) % 1000, "c1")), number=2000, repeats=5
        )
        encode_t = time_per_call_s(lambda: encode_payload(records[0]), number=5000, repeats=5)
        for pub in bare_pubs.values():
            pub.undeclare()
    finally:
        sub_bare.undeclare()
        subscriber.close()
        sink.close()
        router.close()

    rows: list[dict[str, Any]] = []
    for case, values in lat.items():
        rows.append(
            {
                "case": f"latency, {'ZenohSink.write' if case == 'sink' else 'bare session.put'}",
                "n": len(values),
                "p50_us": statistics.median(values),
                "p99_us": _percentile(values, 0.99),
                "rate_per_s": float("nan"),
            }
        )
    for case, r in (
        (f"sustained, ZenohSink.write offered at {PACED_RATE_PER_S:.0f}/s", rate_paced),
        ("burst, ZenohSink.write as fast as possible", rate_sink),
        ("burst, bare publisher.put as fast as possible", rate_bare),
    ):
        rows.append(
            {
                "case": f"{case} (delivered {r['delivered_fraction']:.1%})",
                "n": int(r["records"]),
                "p50_us": float("nan"),
                "p99_us": float("nan"),
                "rate_per_s": r["delivered_rate_per_s"],
            }
        )
    rows.append({"case": "write() call, no subscriber (median)", "n": 2000,
                 "p50_us": write_t["median_s"] * 1e6, "p99_us": float("nan"),
                 "rate_per_s": 1.0 / write_t["median_s"]})  # fmt: skip
    rows.append({"case": "encode_payload (to_dict + json) (median)", "n": 5000,
                 "p50_us": encode_t["median_s"] * 1e6, "p99_us": float("nan"),
                 "rate_per_s": 1.0 / encode_t["median_s"]})  # fmt: skip
    p50_ratio = statistics.median(lat["sink"]) / statistics.median(lat["bare"])
    p99_ratio = _percentile(lat["sink"], 0.99) / _percentile(lat["bare"], 0.99)
    goals = [
        goal("p50 latency, sink / bare put", p50_ratio, LATENCY_GOAL_RATIO, higher_is_better=False),
        goal("p99 latency, sink / bare put", p99_ratio, LATENCY_GOAL_RATIO, higher_is_better=False),
        goal(
            f"records/s delivered through the sink, offered {PACED_RATE_PER_S:.0f}/s",
            rate_paced["delivered_rate_per_s"],
            RATE_GOAL_PER_S,
            higher_is_better=True,
        ),
    ]
    return {
        "name": "bench_zenoh",
        "quick": quick,
        "rows": rows,
        "goals": goals,
        "rates": {"paced": rate_paced, "burst_sink": rate_sink, "burst_bare": rate_bare},
        "timings": {"write": write_t, "encode": encode_t},
    }


def to_markdown(result: dict[str, Any]) -> str:
    return (
        "### Zenoh republishing (bench_zenoh)\n\n"
        "Loopback, router + 2 client sessions in one process; latency from before the call "
        "to the subscriber's callback, one sample in flight, ours and bare alternating.\n\n"
        + format_table(result["rows"])
        + "\n\n"
        + format_goals(result["goals"])
    )


if __name__ == "__main__":
    import sys

    sys.exit(main_for(sys.modules[__name__]))
