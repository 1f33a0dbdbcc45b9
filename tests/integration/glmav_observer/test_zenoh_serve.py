"""End to end: the SITL streams MAVLink over UDP to ``glmav-observer serve``, which
publishes on Zenoh as a client of a ``glmav-observer router`` subprocess; a client-mode
subscriber in this process checks every key, the schemas, the values (against the records
the service itself wrote with ``--out``), the queryables and the liveliness tokens.
Loopback only, multicast scouting off."""

from __future__ import annotations

import itertools
import json
import math
import signal
import subprocess
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from glmav_observer.publish.schema import validate
from glmav_observer.reads import next_due_s
from glmav_observer.records import CONFIGS
from glmav_testkit.zenoh_helpers import RouterProcess, client_config, client_session, wait_until

pytestmark = pytest.mark.timeout(120)

REPO = Path(__file__).resolve().parents[3]
SITL = str(Path(sys.executable).with_name("glmav-sitl"))
CLI = [sys.executable, "-m", "glmav_observer.cli"]
DECIMATION = {"velocity": 5, "active": 1, "health": 1}


def _service_toml(tmp: Path) -> Path:
    """The shipped service.toml with this test's id and decimation."""
    text = (REPO / "configs" / "service.toml").read_text(encoding="utf-8")
    text = text.replace('id = "glmav-observer"', 'id = "e2e-svc"', 1)
    head, sep, tail = text.partition("[zenoh.decimation]")
    assert sep and tail.count("velocity = 1\n") == 1
    text = head + sep + tail.replace("velocity = 1\n", f"velocity = {DECIMATION['velocity']}\n")
    path = tmp / "service.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _due(rows: list[dict[str, Any]], rate_hz: float) -> list[dict[str, Any]]:
    """The rows a sink reading one stream at ``rate_hz`` is handed (the service's rule:
    the first at or after each multiple of the period, glmav_observer.reads)."""
    out, due = [], -math.inf
    for row in rows:
        if row["t_boot_s"] >= due:
            out.append(row)
            due = next_due_s(row["t_boot_s"], rate_hz)
    return out


def _row_of(value: dict[str, Any]) -> dict[str, Any]:
    """The velocity payload as the file sink's flat row (records.flatten's names; the
    Zenoh-only ``service_id`` left out)."""
    row = {k: v for k, v in value.items() if not isinstance(v, list) and k != "service_id"}
    for name, axes in (("v_body_mps", "uvw"), ("v_ned_mps", "ned"), ("sigma_ned_mps", "ned")):
        row.pop(name, None)  # (sigma_ned_mps: null when nothing is dead-reckoned)
        for axis, x in zip(axes, value[name] or (None, None, None), strict=True):
            row[f"{name}_{axis}"] = x
    return row


@pytest.fixture
def router(free_tcp_port: Callable[[], int]) -> Iterator[RouterProcess]:
    router = RouterProcess(free_tcp_port())
    router.start()
    yield router
    router.stop()


def test_serve_publishes_what_it_estimates_from_the_sitl(
    tmp_path: Path, router: RouterProcess, free_udp_port: Callable[[], int]
) -> None:
    viewer = client_session(router.port)
    samples: list[tuple[str, str, dict[str, Any]]] = []
    viewer.declare_subscriber(
        "glmav/**",
        lambda s: samples.append(
            (str(s.key_expr), str(s.encoding), json.loads(s.payload.to_bytes()))
        ),
    )
    alive: list[tuple[str, str]] = []
    viewer.liveliness().declare_subscriber(
        "glmav/@alive/**",
        lambda s: alive.append((str(s.key_expr), "+" if s.kind == zenoh.SampleKind.PUT else "-")),
        history=True,
    )
    udp = free_udp_port()
    out = tmp_path / "records.jsonl"
    zenoh_config = client_config(tmp_path / "client.json5", router.port)
    serve = subprocess.Popen(
        [
            *CLI,
            "serve",
            "--config",
            str(_service_toml(tmp_path)),
            "--zenoh",
            str(zenoh_config),
            "--link",
            f"udpin:127.0.0.1:{udp}",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_until(lambda: ("glmav/@alive/e2e-svc", "+") in alive, 30), serve.poll()
        sitl = subprocess.run(
            [
                SITL,
                "run",
                "--scenario",
                "cruise",
                "--duration",
                "8",
                "--speed",
                "4",
                "--link",
                f"udpout:127.0.0.1:{udp}",
                "--sysid",
                "7",
            ],
            check=False,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert sitl.returncode == 0, sitl.stderr
        assert ("glmav/@alive/e2e-svc/7", "+") in alive

        def query(selector: str) -> dict[str, Any]:
            replies = {}
            for reply in viewer.get(selector, timeout=5.0):
                assert reply.ok is not None
                replies[str(reply.ok.key_expr)] = json.loads(reply.ok.payload.to_bytes())
            return replies

        # the last estimate has arrived when the subscriber holds the state's latest seq
        # and that seq has stopped moving (3 polls, 0.6 s: the service has worked off
        # its socket backlog; a stop no longer drains it without bound, issue 18.6)
        seen: list[int | None] = []

        def caught_up() -> bool:
            state = query("glmav/7/state").get("glmav/7/state")
            last = state["velocity"]["active"]["seq"] if state else None
            seen.append(last)
            got = [v["seq"] for k, _, v in samples if k == "glmav/7/velocity/active"]
            stable = len(seen) >= 3 and seen[-3] == seen[-2] == last
            return last is not None and stable and bool(got) and got[-1] == last

        assert wait_until(caught_up, 20, period_s=0.2)
        state = query("glmav/*/state")["glmav/7/state"]
        config = query("glmav/@config/e2e-svc")["glmav/@config/e2e-svc"]
        serve.send_signal(signal.SIGINT)
        stdout, stderr = serve.communicate(timeout=30)
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.communicate()
    assert serve.returncode == 0, stderr
    # withdrawn by the clean close, well before the 10 s lease would expire
    assert wait_until(lambda: ("glmav/@alive/e2e-svc", "-") in alive, 5)
    assert ("glmav/@alive/e2e-svc/7", "-") in alive
    viewer.close()

    # every key, valid, as application/json
    keys = Counter(key for key, _, _ in samples)
    want = {f"glmav/7/velocity/{c}" for c in (*CONFIGS, "active")}
    want |= {"glmav/7/health", "glmav/7/measurement", "glmav/7/truth"}
    assert set(keys) == want
    for key, encoding, value in samples:
        assert encoding == "application/json"
        assert validate(value) == [], (key, validate(value))
        assert value["service_id"] == "e2e-svc", key  # in every payload
    assert validate(state) == [] and validate(config) == []
    assert config["decimation"]["velocity"] == DECIMATION["velocity"]
    assert config["config"]["service_id"] == "e2e-svc"

    # values: what arrived is what the service computed (its own --out file)
    rows = [json.loads(line) for line in out.read_text(encoding="utf-8").splitlines()]
    written: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        if row["schema"] == "glmav.velocity/1":
            written[row["config"]].append(row)
    assert len(written["active"]) > 0.9 * 8 * 250  # 8 s of sim at ~250 Hz (the IMU rate)
    rates = config["rates_hz"]  # what the sink reads: [zenoh.rates], the live defaults
    assert rates["active"] == 50.0 and rates["full"] == 10.0 and rates["health"] == 5.0
    for config_name in (*CONFIGS, "active"):
        every = DECIMATION["active" if config_name == "active" else "velocity"]
        # the records due at the key's rate (the file has every one), then the 1st, N+1st,
        # ... of those (the decimation applies to what the sink reads)
        expected = _due(written[config_name], rates[config_name])[::every]
        got = [_row_of(v) for k, _, v in samples if k == f"glmav/7/velocity/{config_name}"]
        # TCP loopback at ~1.5k records/s: nothing dropped, nothing reordered
        assert len(got) == len(expected), config_name
        for g, e in zip(got, expected, strict=True):
            assert g == {k: e[k] for k in g}, config_name
            assert all(math.isfinite(x) for x in (g["v_ned_mps_n"], g["v_ned_mps_e"]))
    health_rows = [r for r in rows if r["schema"] == "glmav.health/1"]
    assert keys["glmav/7/health"] == len(_due(health_rows, rates["health"])) > 0
    # the state queryable held the very last estimate
    assert _row_of(state["velocity"]["active"]) == {
        k: written["active"][-1][k] for k in _row_of(state["velocity"]["active"])
    }
    # the daemon's own count of the records it gave its sinks
    assert f"records {len(rows)}," in stdout
    assert "vehicle 7: active=" in stdout


def test_serve_survives_a_router_restart_and_resumes_publishing(
    tmp_path: Path, router: RouterProcess, free_udp_port: Callable[[], int]
) -> None:
    udp = free_udp_port()
    out = tmp_path / "records.jsonl"
    serve = subprocess.Popen(
        [
            *CLI,
            "serve",
            "--config",
            str(_service_toml(tmp_path)),
            "--zenoh",
            str(client_config(tmp_path / "client.json5", router.port)),
            "--link",
            f"udpin:127.0.0.1:{udp}",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    viewer = client_session(router.port)
    t_active: list[float] = []
    viewer.declare_subscriber(
        "glmav/*/velocity/active",
        lambda s: t_active.append(json.loads(s.payload.to_bytes())["t_boot_s"]),
    )
    sitl = None
    try:
        # the service is up when its config queryable answers
        assert wait_until(lambda: bool(list(viewer.get("glmav/@config/*", timeout=1.0))), 30)
        sitl = subprocess.Popen(
            [
                SITL,
                "run",
                "--scenario",
                "hover",
                "--duration",
                "14",
                "--speed",
                "1.5",
                "--link",
                f"udpout:127.0.0.1:{udp}",
                "--sysid",
                "3",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert wait_until(lambda: len(t_active) > 50, 20)
        router.kill()
        t_at_kill = t_active[-1]
        time.sleep(1.0)  # the outage itself lasts 1 s (a duration, not an event to await)
        assert serve.poll() is None  # the service is still running
        router.start()  # same port
        # the service's client session reconnects by itself (Zenoh retries its endpoint,
        # backing off from 1 s; the viewer reconnects likewise): estimates resume
        assert wait_until(lambda: bool(t_active) and t_active[-1] > t_at_kill + 1.0, 30)
        _sitl_out, sitl_err = sitl.communicate(timeout=60)
        assert sitl.returncode == 0, sitl_err
        serve.send_signal(signal.SIGINT)
        _, stderr = serve.communicate(timeout=30)
    finally:
        for proc in (sitl, serve):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.communicate()
        viewer.close()
    assert serve.returncode == 0, stderr
    assert "Traceback" not in stderr
    # it kept estimating through the outage: no hole in the vehicle-time series it wrote
    t_written = [
        row["t_boot_s"]
        for row in map(json.loads, out.read_text(encoding="utf-8").splitlines())
        if row["schema"] == "glmav.velocity/1" and row["config"] == "active"
    ]
    assert t_written[0] < t_at_kill < t_written[-1]
    gaps = [b - a for a, b in itertools.pairwise(t_written)]
    # 250 Hz IMU steps (4 ms); allow the SITL's timing grid some slack, not a second's hole
    assert max(gaps) < 0.05
    # and what was published before the kill and after the restart is part of it
    assert set(t_active) <= set(t_written)


def test_two_services_on_one_router_are_told_apart_and_a_namesake_refuses(
    tmp_path: Path, router: RouterProcess, free_udp_port: Callable[[], int]
) -> None:
    viewer = client_session(router.port)
    samples: list[dict[str, Any]] = []
    viewer.declare_subscriber(
        "glmav/*/velocity/active", lambda s: samples.append(json.loads(s.payload.to_bytes()))
    )
    alive: list[str] = []
    viewer.liveliness().declare_subscriber(
        "glmav/@alive/*", lambda s: alive.append(str(s.key_expr)), history=True
    )
    zenoh_config = client_config(tmp_path / "client.json5", router.port)
    ports = {"svc-a": free_udp_port(), "svc-b": free_udp_port()}
    # svc-a in 2 worker processes sharing its id (only worker 0 checks it is free: the
    # second used to refuse on the first's token), svc-b in one
    workers = {"svc-a": "2", "svc-b": "1"}
    services = {
        sid: subprocess.Popen(
            [
                *CLI,
                "serve",
                "--workers",
                workers[sid],
                "--zenoh",
                str(zenoh_config),
                "--service-id",
                sid,
                "--link",
                f"udpin:127.0.0.1:{port}",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for sid, port in ports.items()
    }
    try:
        assert wait_until(lambda: {"glmav/@alive/svc-a", "glmav/@alive/svc-b"} <= set(alive), 30)
        # a third service with svc-a's id: refused with the reason, exit 2, nothing published
        dup = subprocess.run(
            [*CLI, "serve", "--zenoh", str(zenoh_config), "--service-id", "svc-a",
             "--link", f"udpin:127.0.0.1:{free_udp_port()}"],
            capture_output=True, text=True, timeout=60, check=False,
        )  # fmt: skip
        assert dup.returncode == 2, dup.stderr
        assert "another service with id 'svc-a' is already on this Zenoh network" in dup.stderr
        assert "Traceback" not in dup.stderr
        # one simulator, the same vehicle (sysid 1) streamed to both services
        sitl = subprocess.run(
            [SITL, "run", "--scenario", "hover", "--duration", "4", "--speed", "4",
             "--link", f"udpout:127.0.0.1:{ports['svc-a']}",
             "--link", f"udpout:127.0.0.1:{ports['svc-b']}"],
            check=False, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert sitl.returncode == 0, sitl.stderr
        # both streams arrive on glmav/1/velocity/active (~4 s x 50 Hz each: the active
        # estimate's default rate, [zenoh.rates])
        assert wait_until(
            lambda: (
                min(sum(1 for v in samples if v["service_id"] == sid) for sid in ports)
                > 0.9 * 4 * 50
            ),
            20,
            period_s=0.2,
        )
        for proc in services.values():
            proc.send_signal(signal.SIGINT)
        for proc in services.values():
            proc.communicate(timeout=30)
    finally:
        for proc in services.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    viewer.close()
    assert all(p.returncode == 0 for p in services.values())
    # on one key, interleaved; separated by service_id each stream is complete and in order
    assert {v["service_id"] for v in samples} == set(ports)
    for sid in ports:
        seqs = [v["seq"] for v in samples if v["service_id"] == sid]
        # in order, none twice (the simulator sends truth, so every estimate is built for
        # the summary's RMSE and the sink gets its 50 Hz of them: seq may skip)
        assert seqs == sorted(set(seqs)), sid
