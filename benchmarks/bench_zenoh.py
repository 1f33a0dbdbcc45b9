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

Per-record cost (the CPU time ``write`` takes on the estimator's thread,
``time.thread_time``): each payload encoder that was a
candidate, on the same velocity records, against today's (``to_dict()`` + stdlib JSON)
as the baseline; and the whole ``write`` of the sink against a copy of the ``write`` of
a845e63 (``route()`` per record, the lock, stdlib JSON, ``put``) on the same session,
the sink's embedded loopback peer, first without a subscriber and then with one in a
separate process (a peer the sink connects to). Repeats alternate before/after so that
load hits both alike; medians.
"""

from __future__ import annotations

import json
import math
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.common import format_goals, format_table, goal, main_for, time_per_call_s
from glmav_observer.publish.schema import KINDS
from glmav_observer.publish.zenoh_config import EMBEDDED_DEFAULT_JSON5
from glmav_observer.publish.zenoh_keys import encode_json, encode_payload, payload_encoder, route
from glmav_observer.publish.zenoh_sink import ZenohSink, open_zenoh_sink
from glmav_observer.records import CONFIGS, Record, VelocityRecord

LATENCY_GOAL_RATIO = 1.5
#: the whole write() of one published velocity record (µs)
WRITE_GOAL_US = 2.0
SERVICE_ID = "bench"
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


# ---------------------------------------------------------------------------------------
# Per-record cost: the encoders, and write() before/after
# ---------------------------------------------------------------------------------------


def _stdlib_payload(record: Record, service_id: str = SERVICE_ID) -> bytes:
    """Today's encoder (a845e63's ``encode_payload``): to_dict() + service_id, stdlib JSON."""
    d = record.to_dict()
    d["service_id"] = service_id
    return encode_json(d)


_STDLIB_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def _stdlib_cached(record: Record) -> bytes:
    """The stdlib with one encoder made once (json.dumps with arguments makes one per call)."""
    d = record.to_dict()
    d["service_id"] = SERVICE_ID
    return _STDLIB_ENCODER.encode(d).encode()


_JSON_STR: dict[str | None, str] = {None: "null"}


def _jstr(x: str | None) -> str:
    out = _JSON_STR.get(x)
    if out is None:
        out = _JSON_STR[x] = json.dumps(x)
    return out


def _text_from_fields(record: VelocityRecord) -> bytes:
    """JSON text built straight from the tuple's fields (float repr, cached string
    literals); falls back to the stdlib for a NaN, an infinity or a numpy repr."""
    (sysid, config, t, b, v, lost, health, seq, src, sigma, schema, dr, s_ned) = record
    nums = (
        f'{t!r},"v_body_mps":[{b[0]!r},{b[1]!r},{b[2]!r}],"v_ned_mps":[{v[0]!r},{v[1]!r},{v[2]!r}]'
        f',"lost_axis":{_jstr(lost)},"health":{_jstr(health)},"seq":{seq:d}'
        f',"source_config":{_jstr(src)},"sigma_lost_mps":{"null" if sigma is None else repr(sigma)}'
        f',"dead_reckoned_axes":[{",".join(_jstr(a) for a in dr)}],"sigma_ned_mps":'
        + ("null" if s_ned is None else f"[{s_ned[0]!r},{s_ned[1]!r},{s_ned[2]!r}]")
    )
    if "n" in nums.replace("null", ""):  # nan, inf, np.float64(...)
        return _stdlib_payload(record)
    return (
        f'{{"schema":{_jstr(schema)},"sysid":{sysid:d},"config":{_jstr(config)},"t_boot_s":'
        f'{nums},"service_id":{_jstr(SERVICE_ID)}}}'
    ).encode()


#: The binary layout measured (not offered): sysid u8, config u8, lost_axis u8, health u8,
#: seq u32, t_boot_s, v_body_mps[3], v_ned_mps[3], sigma_lost_mps (NaN = none) as f64,
#: little-endian, 72 bytes; source_config and service_id would need a header of their own.
_STRUCT = struct.Struct("<BBBBI8d")
_CONFIG_IDS = {c: i for i, c in enumerate((*CONFIGS, "aided", "active"))}
_LOST_IDS = {None: 0, "n": 1, "e": 2, "d": 3}
_HEALTH_IDS = {h: i for i, h in enumerate(("ok", "dead_reckoning", "degraded", "aided"))}


def _struct_layout(record: VelocityRecord) -> bytes:
    (sysid, config, t, b, v, lost, health, seq, _src, sigma, _schema, _dr, _s_ned) = record
    return _STRUCT.pack(
        sysid, _CONFIG_IDS[config], _LOST_IDS[lost], _HEALTH_IDS[health], seq, t,
        b[0], b[1], b[2], v[0], v[1], v[2], math.nan if sigma is None else sigma,
    )  # fmt: skip


def _encoder_candidates() -> list[tuple[str, Callable[[Any], bytes], str]]:
    """(name, encoder, status) in the order of the table; the baseline first."""
    out: list[tuple[str, Callable[[Any], bytes], str]] = [
        ("stdlib json.dumps(to_dict()) (a845e63)", _stdlib_payload, "baseline"),
        ("stdlib, one JSONEncoder, to_dict()", _stdlib_cached, "candidate"),
        ("JSON text from the tuple's fields (repr)", _text_from_fields, "candidate"),
    ]
    try:
        import orjson

        def orjson_to_dict(record: Record) -> bytes:
            d = record.to_dict()
            d["service_id"] = SERVICE_ID
            return orjson.dumps(d)

        out.append(("orjson, to_dict()", orjson_to_dict, "candidate"))
    except ImportError:
        pass
    out.append(
        ("orjson from the tuple's fields", payload_encoder("json", SERVICE_ID), "chosen (json)")
    )
    try:
        import msgpack

        def msgpack_to_dict(record: Record) -> bytes:
            d = record.to_dict()
            d["service_id"] = SERVICE_ID
            return bytes(msgpack.packb(d))

        out.append(("msgpack, to_dict()", msgpack_to_dict, "candidate"))
    except ImportError:
        pass
    out.append(
        (
            "ormsgpack from the tuple's fields",
            payload_encoder("msgpack", SERVICE_ID),
            "offered (msgpack)",
        )
    )
    out.append(("struct, fixed 72-byte layout", _struct_layout, "not offered"))
    return out


def _per_call_us(fn: Callable[[Any], Any], items: list[Any]) -> float:
    """CPU time of this thread per call (µs): what the caller's thread spends, without the
    time other processes of a shared machine hold the core (Zenoh's own threads, which
    take the sample from ``put``, are not counted: they do not hold the estimator)."""
    t0 = time.thread_time()
    for item in items:
        fn(item)
    return (time.thread_time() - t0) / len(items) * 1e6


def _encoders(records: list[VelocityRecord], repeats: int) -> list[dict[str, Any]]:
    candidates = _encoder_candidates()
    baseline_fn = candidates[0][1]
    for name, fn, _ in candidates:  # warm-up, and the JSON ones read back the same object
        _per_call_us(fn, records[:100])
        if "json" in name.lower():
            for r in records[:100]:
                if json.loads(fn(r)) != json.loads(baseline_fn(r)):
                    raise AssertionError(f"{name}: not the same JSON object as the baseline")
    samples: dict[str, list[float]] = {name: [] for name, _, _ in candidates}
    for _ in range(repeats):  # interleaved: load hits every candidate alike
        for name, fn, _ in candidates:
            samples[name].append(_per_call_us(fn, records))
    base = statistics.median(samples[candidates[0][0]])
    rows = []
    for name, fn, status in candidates:
        med = statistics.median(samples[name])
        rows.append(
            {
                "encoder": name,
                "status": status,
                "median_us": med,
                "min_us": min(samples[name]),
                "vs_baseline": med / base,
                "bytes": len(fn(records[len(records) // 2])),  # full-precision floats
            }
        )
    return rows


class _WriteOfA845e63:
    """``ZenohSink.write`` as it was at a845e63 (the baseline), on a session of ours:
    ``route()`` builds the key per record, the lock around the shared state and the
    counters, the stdlib JSON of ``to_dict()``, then ``put``. (Its liveliness token is a
    set here: declared once, as the sink's is.)"""

    def __init__(self, session: Any, prefix: str) -> None:
        import zenoh

        self.session = session
        self.prefix = prefix
        self.zenoh = zenoh
        self.lock = threading.Lock()
        self.latest: dict[int, dict[str, Record]] = {}
        self.last_seen: dict[int, float] = {}
        self.tokens: set[int] = set()
        self.write_count: dict[str, int] = {}
        self.publishers: dict[str, Any] = {}
        self.decimation = dict.fromkeys(KINDS, 1)
        self.published = dict.fromkeys(KINDS, 0)
        self.decimated = dict.fromkeys(KINDS, 0)

    def write(self, record: Record) -> None:
        kind, key, slot = route(self.prefix, record)
        sysid = record.sysid
        now = time.monotonic()
        every = self.decimation[kind]
        with self.lock:
            slots = self.latest.get(sysid)
            if slots is None:
                slots = self.latest[sysid] = {}
            slots[slot] = record
            self.last_seen[sysid] = now
            if sysid not in self.tokens:
                self.tokens.add(sysid)
            n = self.write_count.get(key, 0)
            self.write_count[key] = n + 1
            if every == 0 or n % every:
                self.decimated[kind] += 1
                return
            publisher = self.publishers.get(key)
            if publisher is None:
                zenoh = self.zenoh
                publisher = self.publishers[key] = self.session.declare_publisher(
                    key,
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.DROP,
                    priority=zenoh.Priority.DATA,
                )
        publisher.put(_stdlib_payload(record))
        with self.lock:
            self.published[kind] += 1

    def close(self) -> None:
        for publisher in self.publishers.values():
            publisher.undeclare()


_SUBSCRIBER_SCRIPT = """
import json, sys, zenoh
port = sys.argv[1]
session = zenoh.open(zenoh.Config.from_json5(json.dumps({
    "mode": "peer", "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
    "scouting": {"multicast": {"enabled": False}}})))
count = [0]
def on_sample(_sample):
    count[0] += 1
    if count[0] == 1:
        print("got", flush=True)
subs = [session.declare_subscriber(k, on_sample) for k in ("glmav/**", "base/**", "bare/**")]
print("ready", flush=True)
sys.stdin.read()
print(count[0], flush=True)
session.close()
"""


def _write_costs(quick: bool) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """write() per velocity record, before (a845e63's) and after, on the sink's embedded
    loopback peer; without a subscriber, then with one in another process."""
    repeats = 5 if quick else 15
    steps = 400 if quick else 1000
    records = [_record(s, c) for s in range(steps) for c in (*CONFIGS, "active")]
    port = _free_port()
    with tempfile.TemporaryDirectory() as tmp:
        # the embedded default (peer on an ephemeral 127.0.0.1 port, multicast off) with its
        # connect endpoint pointed at the subscriber's port instead of a local router's
        config = Path(tmp) / "peer-local.json5"
        config.write_text(EMBEDDED_DEFAULT_JSON5.replace("7447", str(port)), encoding="utf-8")
        sink = open_zenoh_sink(str(config), service_id=SERVICE_ID, effective_config={})
    before = _WriteOfA845e63(sink.session, "base")
    import zenoh

    # Zenoh's own share: a bare put of a payload encoded beforehand, same publisher options
    bare_pubs = {
        c: sink.session.declare_publisher(
            f"bare/1/velocity/{c}",
            encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        for c in (*CONFIGS, "active")
    }
    bare_items = [(bare_pubs[r.config], encode_payload(r, SERVICE_ID)) for r in records]

    def bare_put(item: tuple[Any, bytes]) -> None:
        item[0].put(item[1])

    rows: list[dict[str, Any]] = []
    raw: dict[str, Any] = {}
    subscriber = None
    try:
        for phase in ("no subscriber", "subscriber in another process"):
            if phase != "no subscriber":
                subscriber = subprocess.Popen(
                    [sys.executable, "-c", _SUBSCRIBER_SCRIPT, str(port)],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                )
                assert subscriber.stdout is not None
                if subscriber.stdout.readline().strip() != "ready":
                    raise RuntimeError("the subscriber process did not start")
                got = threading.Event()
                out = subscriber.stdout
                threading.Thread(
                    target=lambda out=out, got=got: (out.readline(), got.set()), daemon=True
                ).start()
                deadline = time.monotonic() + 20
                while not got.is_set() and time.monotonic() < deadline:  # the peer link is up
                    sink.write(records[0])
                    before.write(records[0])
                    time.sleep(0.01)
                if not got.is_set():
                    raise RuntimeError("no sample reached the subscriber process in 20 s")
                time.sleep(0.5)
            for fn in (sink.write, before.write):  # warm-up: publishers declared
                _per_call_us(fn, records[:500])
            _per_call_us(bare_put, bare_items[:500])
            samples: dict[str, list[float]] = {"before": [], "after": [], "bare": []}
            for i in range(repeats):
                order = (("before", before.write), ("after", sink.write))
                for name, fn in order if i % 2 == 0 else order[::-1]:
                    samples[name].append(_per_call_us(fn, records))
                    time.sleep(0.05)  # let Zenoh's TX thread drain between repeats
                samples["bare"].append(_per_call_us(bare_put, bare_items))
                time.sleep(0.05)
            b, a = statistics.median(samples["before"]), statistics.median(samples["after"])
            rows.append(
                {
                    "write() per velocity record": phase,
                    "before_us (a845e63)": b,
                    "after_us": a,
                    "after_min_us": min(samples["after"]),
                    "before/after": b / a,
                    "bare_put_us": statistics.median(samples["bare"]),
                }
            )
            raw[phase] = samples
        stats = sink.stats()
        raw["sink_stats"] = {k: stats[k] for k in ("published", "decimated", "errors")}
    finally:
        if subscriber is not None:
            subscriber.communicate(timeout=20)
        for pub in bare_pubs.values():
            pub.undeclare()
        before.close()
        sink.close()
    raw["records_per_repeat"] = len(records)
    return rows, raw


def run(quick: bool = False) -> dict[str, Any]:
    import zenoh

    cost_records = [_record(s, c) for s in range(400) for c in (*CONFIGS, "active")]
    encoder_rows = _encoders(cost_records, repeats=5 if quick else 15)
    write_rows, write_raw = _write_costs(quick)

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
    rows.append({"case": "write() call incl. making the record, router topology, no subscriber (median)", "n": 2000,
                 "p50_us": write_t["median_s"] * 1e6, "p99_us": float("nan"),
                 "rate_per_s": 1.0 / write_t["median_s"]})  # fmt: skip
    rows.append({"case": "encode_payload (json: orjson from the fields) (median)", "n": 5000,
                 "p50_us": encode_t["median_s"] * 1e6, "p99_us": float("nan"),
                 "rate_per_s": 1.0 / encode_t["median_s"]})  # fmt: skip
    p50_ratio = statistics.median(lat["sink"]) / statistics.median(lat["bare"])
    after = {r["write() per velocity record"]: r["after_us"] for r in write_rows}
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
        goal(
            "write() per published velocity record, no subscriber (µs)",
            after["no subscriber"],
            WRITE_GOAL_US,
            higher_is_better=False,
        ),
        goal(
            "write() per published velocity record, a subscriber (µs)",
            after["subscriber in another process"],
            WRITE_GOAL_US,
            higher_is_better=False,
        ),
    ]
    return {
        "name": "bench_zenoh",
        "quick": quick,
        "rows": rows,
        "encoder_rows": encoder_rows,
        "write_rows": write_rows,
        "write_samples_us": write_raw,
        "goals": goals,
        "rates": {"paced": rate_paced, "burst_sink": rate_sink, "burst_bare": rate_bare},
        "timings": {"write": write_t, "encode": encode_t},
    }


ENCODER_COLUMNS = ("encoder", "status", "median_us", "min_us", "vs_baseline", "bytes")
WRITE_COLUMNS = (
    "write() per velocity record",
    "before_us (a845e63)",
    "after_us",
    "after_min_us",
    "before/after",
    "bare_put_us",
)


def _ordered(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> list[dict[str, Any]]:
    """The rows with their columns in the table's order (results JSON sorts its keys)."""
    return [{c: r.get(c, "") for c in columns} for r in rows]


def to_markdown(result: dict[str, Any]) -> str:
    return (
        "### Zenoh republishing (bench_zenoh)\n\n"
        "Loopback, router + 2 client sessions in one process; latency from before the call "
        "to the subscriber's callback, one sample in flight, ours and bare alternating.\n\n"
        + format_table(result["rows"])
        + "\n\nPer-record cost of the payload encoders (CPU time of the calling thread per "
        "velocity record with service_id; medians of 15 interleaved repeats over 2000 "
        "records):\n\n"
        + format_table(_ordered(result["encoder_rows"], ENCODER_COLUMNS))
        + "\n\nThe whole `ZenohSink.write` per velocity record (CPU time of the calling "
        "thread; 5 keys of one vehicle, every record published; medians of 15 repeats of "
        "5000 records), before (a845e63's write, stdlib JSON) and after, "
        "alternating, on the sink's embedded loopback peer; `bare_put_us`: Zenoh's own "
        "share, a `publisher.put` of the payload encoded beforehand:\n\n"
        + format_table(_ordered(result["write_rows"], WRITE_COLUMNS))
        + "\n\n"
        + format_goals(result["goals"])
    )


if __name__ == "__main__":
    import sys

    sys.exit(main_for(sys.modules[__name__]))
