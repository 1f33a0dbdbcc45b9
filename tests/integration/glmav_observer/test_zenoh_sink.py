"""The Zenoh sink over real sessions on loopback: a router subprocess, the sink and the
subscribers in client mode (multicast scouting off, explicit tcp/127.0.0.1 endpoints)."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import zenoh

from glmav_observer import __version__
from glmav_observer.publish.schema import SCHEMAS, validate
from glmav_observer.publish.zenoh_config import ZenohConfigError
from glmav_observer.publish.zenoh_keys import decode_payload, route
from glmav_observer.publish.zenoh_sink import ZenohSink, open_zenoh_sink
from glmav_observer.records import CONFIGS, HealthRecord, Record, VelocityRecord
from glmav_testkit.zenoh_helpers import (
    RouterProcess,
    client_config,
    client_session,
    health,
    vehicle_stream,
    velocity,
    wait_until,
)

pytestmark = pytest.mark.timeout(60)

DECIMATION = {"velocity": 2, "active": 1, "health": 1, "measurement": 3, "truth": 1}
EFFECTIVE = {"link": ["udpin:127.0.0.1:14550"], "zenoh": {"prefix": "glmav"}, "gamma": [90, 70]}
WARMUP_SYSID = 99


def _published(record: Record, service_id: str) -> dict[str, Any]:
    """A record as a service publishes it: its dict, the service's id, and on a health
    sample the service's release."""
    extra = {"service_version": __version__} if isinstance(record, HealthRecord) else {}
    return {**record.to_dict(), "service_id": service_id, **extra}


@pytest.fixture
def router(free_tcp_port: Callable[[], int]) -> Iterator[RouterProcess]:
    router = RouterProcess(free_tcp_port())
    router.start()
    yield router
    router.stop()


@pytest.fixture
def sink(router: RouterProcess, tmp_path: Path) -> Iterator[ZenohSink]:
    config = client_config(tmp_path / "client.json5", router.port)
    sink = open_zenoh_sink(
        str(config),
        decimation=DECIMATION,
        service_id="test-svc",
        effective_config=EFFECTIVE,
        vehicle_timeout_s=0.3,
    )
    yield sink
    sink.close()


@pytest.fixture
def viewer(router: RouterProcess) -> Iterator[Any]:
    session = client_session(router.port)
    yield session
    session.close()


class Collector:
    """A subscriber's samples: (key, encoding, decoded JSON), warm-up samples left out."""

    def __init__(self, session: Any, keyexpr: str) -> None:
        self.samples: list[tuple[str, str, Any]] = []
        self.warm = False
        self.sub = session.declare_subscriber(keyexpr, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        value = json.loads(sample.payload.to_bytes())
        if value.get("sysid") == WARMUP_SYSID:
            self.warm = True
            return
        self.samples.append((str(sample.key_expr), str(sample.encoding), value))

    def wait_routed(self, sink: ZenohSink) -> None:
        """Publish warm-up records until one arrives: the route sink -> router -> us is up."""
        assert wait_until(lambda: (sink.write(velocity(WARMUP_SYSID, "full", 0)), self.warm)[1], 10)


def expected_published(records: list[Record], prefix: str = "glmav") -> list[tuple[str, Record]]:
    """What the decimation lets through: per key, records number 0, N, 2N, ..."""
    count: dict[str, int] = defaultdict(int)
    out = []
    for record in records:
        kind, key, _ = route(prefix, record)
        if count[key] % DECIMATION[kind] == 0:
            out.append((key, record))
        count[key] += 1
    return out


def test_every_key_arrives_valid_and_equal_to_the_records(sink: ZenohSink, viewer: Any) -> None:
    collector = Collector(viewer, "glmav/**")
    collector.wait_routed(sink)
    published0, decimated0 = sink.published["velocity"], sink.decimated["velocity"]
    streams = [vehicle_stream(1, 300), vehicle_stream(2, 300)]
    records = [r for pair in zip(*streams, strict=True) for r in pair]
    # At the daemon's pace (here twice real time: one estimator step of both vehicles every
    # 2 ms, ~3 kB), the TX queue (2 batches of 64 kB) holds ~80 ms of data: nothing is
    # dropped unless Zenoh's TX thread is starved that long. A burst far faster than that
    # can be dropped by congestion control DROP (by design), see bench_zenoh.py.
    t0 = time.monotonic()
    for record in records:
        sink.write(record)
        if isinstance(record, VelocityRecord) and record.config == "active" and record.sysid == 2:
            delay = t0 + 0.002 * (record.seq + 1) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    expected = expected_published(records)
    assert wait_until(lambda: len(collector.samples) >= len(expected), 15)
    assert len(collector.samples) == len(expected)

    keys = {key for key, _, _ in collector.samples}
    for sysid in (1, 2):
        want = {f"glmav/{sysid}/velocity/{c}" for c in (*CONFIGS, "active")}
        want |= {f"glmav/{sysid}/{k}" for k in ("health", "measurement", "truth")}
        assert want <= keys
    assert len(keys) == 2 * 8

    validators = {sid: jsonschema.Draft202012Validator(s) for sid, s in SCHEMAS.items()}
    by_key: dict[str, list[Any]] = defaultdict(list)
    for key, encoding, value in collector.samples:
        assert encoding == "application/json"
        assert validate(value) == [], (key, validate(value))
        validators[value["schema"]].validate(value)
        by_key[key].append(value)
    want_by_key: dict[str, list[Any]] = defaultdict(list)
    for key, record in expected:
        want_by_key[key].append(_published(record, "test-svc"))
    # per key, in order, the exact values the sink was given (JSON round-trips floats exactly)
    assert by_key == want_by_key
    assert sink.stats()["errors"] == 0
    n_velocity = sum(1 for k, _ in expected if "/velocity/" in k and not k.endswith("active"))
    assert sink.published["velocity"] - published0 == n_velocity == 2 * 4 * 300 // 2
    assert sink.decimated["velocity"] - decimated0 == 2 * 4 * 300 - n_velocity


def test_state_and_config_queryables(sink: ZenohSink, viewer: Any) -> None:
    for record in vehicle_stream(1, 60) + vehicle_stream(2, 30):
        sink.write(record)

    def query(selector: str) -> dict[str, Any]:
        replies = {}
        for reply in viewer.get(selector, timeout=5.0):
            assert reply.ok is not None, reply.err.payload.to_string()
            assert str(reply.ok.encoding) == "application/json"
            replies[str(reply.ok.key_expr)] = json.loads(reply.ok.payload.to_bytes())
        return replies

    states = query("glmav/*/state")
    assert sorted(states) == ["glmav/1/state", "glmav/2/state"]
    for key, state in states.items():
        assert validate(state) == []
        jsonschema.validate(state, SCHEMAS["glmav.state/1"])
        sysid, last_step = (1, 59) if key == "glmav/1/state" else (2, 29)
        assert state["sysid"] == sysid and state["service_id"] == "test-svc"
        # the latest record of each kind, decimated or not
        for config in (*CONFIGS, "active"):
            assert state["velocity"][config] == velocity(sysid, config, last_step).to_dict()
        assert state["health"] == health(sysid, last_step // 25).to_dict()
        assert state["measurement"]["seq"] == last_step // 8
        assert state["truth"]["seq"] == last_step // 5
    assert sorted(query("glmav/2/state")) == ["glmav/2/state"]
    assert query("glmav/7/state") == {}

    configs = query("glmav/@config/*")
    assert list(configs) == ["glmav/@config/test-svc"]
    config = configs["glmav/@config/test-svc"]
    assert validate(config) == []
    assert config["config"] == EFFECTIVE
    assert config["decimation"] == DECIMATION
    assert config["zenoh_config"].endswith("client.json5")
    assert config["version"] == __version__  # the release a fleet operator can check


def test_liveliness_tokens_follow_service_and_vehicles(
    router: RouterProcess, tmp_path: Path, viewer: Any
) -> None:
    events: list[tuple[str, str]] = []
    listener = viewer.liveliness().declare_subscriber(
        "glmav/@alive/**",
        lambda s: events.append((str(s.key_expr), "+" if s.kind == zenoh.SampleKind.PUT else "-")),
        history=True,
    )
    sink = open_zenoh_sink(
        str(client_config(tmp_path / "c.json5", router.port)),
        service_id="live-svc",
        effective_config={},
        vehicle_timeout_s=0.3,
    )
    try:
        assert wait_until(lambda: ("glmav/@alive/live-svc", "+") in events, 5)
        sink.write(velocity(4, "full", 0))
        assert wait_until(lambda: ("glmav/@alive/live-svc/4", "+") in events, 5)
        assert sink.alive_vehicles() == [4]
        # silent for vehicle_timeout_s (0.3 s) -> withdrawn by the watchdog (period 0.075 s)
        assert wait_until(lambda: ("glmav/@alive/live-svc/4", "-") in events, 5)
        assert sink.alive_vehicles() == []
        sink.write(velocity(4, "full", 1))  # back: declared again
        assert wait_until(lambda: events.count(("glmav/@alive/live-svc/4", "+")) == 2, 5)
    finally:
        sink.close()
    assert wait_until(lambda: ("glmav/@alive/live-svc", "-") in events, 5)
    assert wait_until(lambda: events.count(("glmav/@alive/live-svc/4", "-")) == 2, 5)
    listener.undeclare()
    sink.write(velocity(4, "full", 2))  # after close: counted, harmless
    assert sink.after_close == 1


def test_client_without_router_is_a_clear_config_error(
    tmp_path: Path, free_tcp_port: Callable[[], int]
) -> None:
    port = free_tcp_port()  # nothing listens there
    path = client_config(tmp_path / "norouter.json5", port)
    with pytest.raises(ZenohConfigError) as info:
        open_zenoh_sink(str(path), service_id="x", effective_config={})
    message = str(info.value)
    assert message.startswith(f"{path}: cannot open the Zenoh session (mode client")
    assert f"tcp/127.0.0.1:{port}" in message
    assert "/root/.cargo" not in message  # no Rust source locations


#: The reader docs/zenoh.md shows ("Reading the records"): zenoh and the stdlib only.
THREE_LINE_READER = """\
import json, zenoh
session = zenoh.open(zenoh.Config.from_json5('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:7447"]}}'))
for sample in (subscriber := session.declare_subscriber("glmav/**")): print(sample.key_expr, json.loads(sample.payload.to_bytes()), flush=True)
"""


def test_the_three_line_reader_of_the_docs_decodes_a_published_record(
    sink: ZenohSink, router: RouterProcess
) -> None:
    docs = (Path(__file__).resolve().parents[3] / "docs" / "zenoh.md").read_text(encoding="utf-8")
    assert THREE_LINE_READER in docs  # the script tested is the one shown
    script = THREE_LINE_READER.replace("7447", str(router.port))
    reader = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        lines: list[str] = []
        threading.Thread(target=lambda: lines.extend(reader.stdout or ()), daemon=True).start()
        step = 0
        while not lines and reader.poll() is None and step < 4000:  # until it is subscribed
            sink.write(velocity(5, "active", step))
            step += 1
            time.sleep(0.005)
        assert lines, reader.stderr.read() if reader.stderr and reader.poll() is not None else ""
        key, _, value = lines[0].partition(" ")
        assert key == "glmav/5/velocity/active"
        got = ast.literal_eval(value.strip())  # the dict json.loads gave, as print shows it
        assert got == {**velocity(5, "active", got["seq"]).to_dict(), "service_id": "test-svc"}
        assert validate(got) == []
    finally:
        reader.kill()
        reader.wait()


def test_msgpack_sink_publishes_the_same_objects_with_its_encoding(
    router: RouterProcess, viewer: Any, tmp_path: Path
) -> None:
    sink = open_zenoh_sink(
        str(client_config(tmp_path / "mp.json5", router.port)),
        service_id="mp-svc",
        effective_config=EFFECTIVE,
        encoding="msgpack",
    )
    got: list[tuple[str, str, Any]] = []
    warm: list[int] = []

    def on_sample(s: zenoh.Sample) -> None:
        value = decode_payload(s.payload.to_bytes(), str(s.encoding))
        if value["sysid"] == WARMUP_SYSID:
            warm.append(1)
        else:
            got.append((str(s.key_expr), str(s.encoding), value))

    sub = viewer.declare_subscriber("glmav/**", on_sample)
    try:
        records = vehicle_stream(6, 40)
        assert wait_until(lambda: (sink.write(velocity(WARMUP_SYSID, "full", 0)), warm)[1], 10)
        for record in records:
            sink.write(record)
            time.sleep(0.001)
        assert wait_until(lambda: len(got) >= len(records), 10)
    finally:
        sub.undeclare()
        sink.close()
    assert len(got) == len(records)
    by_key: dict[str, list[Any]] = defaultdict(list)
    for key, encoding, value in got:
        assert encoding == "application/msgpack"
        assert validate(value) == []
        by_key[key].append(value)
    want: dict[str, list[Any]] = defaultdict(list)
    for record in records:  # per key in order (keys of other priorities may overtake)
        want[route("glmav", record)[1]].append(_published(record, "mp-svc"))
    assert by_key == want


def test_counters_stay_exact_with_writers_on_two_threads() -> None:
    """write() takes no lock on its path: each key numbers its records with an
    itertools.count, so two link threads writing the same keys lose no count."""
    sink = open_zenoh_sink(
        None,
        service_id="threads-svc",
        effective_config={},
        decimation={"velocity": 3, "active": 0},
        check_unique=False,
    )
    n = 3000
    try:

        def writer() -> None:
            for step in range(n):
                for config in ("full", "c1", "active"):
                    sink.write(velocity(4, config, step))

        threads = [threading.Thread(target=writer) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        stats = sink.stats()
    finally:
        sink.close()
    per_key = 2 * n  # records written per velocity key
    assert stats["published"]["velocity"] == 2 * -(-per_key // 3)
    assert stats["decimated"]["velocity"] == 2 * per_key - 2 * -(-per_key // 3)
    assert stats["published"]["active"] == 0
    assert stats["decimated"]["active"] == per_key
    assert stats["errors"] == 0
    assert stats["publishers"] == 2  # none for a kind decimated to 0
    assert stats["vehicles_alive"] == [4]
