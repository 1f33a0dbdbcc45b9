"""``serve --workers 2`` against the fleet generator on loopback: vehicles are split by
system id (a UDP port by the kernel), each stays on one worker, the merged file holds exactly what one process
estimates from the same frames, and a TCP stream is cut into frames without loss."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from glmav_observer.fleet.routing import worker_of_sysid
from glmav_testkit.fleet_helpers import (
    OBS,
    SITL,
    frames_sent,
    record_tlog,
    wait_bound_udp,
    wait_drained,
    wait_drained_tcp,
    wait_listening_tcp,
)

VEHICLES = 4


def _velocity_rows(path: Path) -> dict[int, list[tuple[Any, ...]]]:
    by_vehicle: dict[int, list[tuple[Any, ...]]] = defaultdict(list)
    with path.open() as f:
        for line in f:
            r = json.loads(line)
            if r["schema"] == "glmav.velocity/1":
                by_vehicle[r["sysid"]].append(
                    (r["config"], r["seq"], r["t_boot_s"], r["v_ned_mps_n"], r["v_ned_mps_e"])
                )
    return by_vehicle


def _serve_udp(tlog: Path, port: int, out: Path, workers: int) -> tuple[str, int, int]:
    """(serve's stdout, frames the generator sent, kernel drops)."""
    serve = subprocess.Popen(
        [OBS, "serve", "--workers", str(workers), "--link", f"udpin:127.0.0.1:{port}",
         "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_bound_udp(port, serve)
        fleet = subprocess.run(
            [SITL, "fleet", "--tlog", str(tlog), "--vehicles", str(VEHICLES),
             "--link", f"udpout:127.0.0.1:{port}", "--stagger", "0.5"],
            check=True, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        drops = wait_drained(port)
    finally:
        serve.send_signal(signal.SIGINT)
        stdout, stderr = serve.communicate(timeout=60)
    assert serve.returncode == 0, stderr
    return stdout, frames_sent(fleet.stdout), drops


@pytest.mark.timeout(240)
def test_two_workers_estimate_what_one_process_estimates(
    tmp_path: Path, free_udp_port: Callable[[], int]
) -> None:
    tlog = record_tlog(tmp_path, 3.0)
    out2, out1 = tmp_path / "w2.jsonl", tmp_path / "w1.jsonl"
    port2 = free_udp_port()
    stdout2, sent2, drops2 = _serve_udp(tlog, port2, out2, 2)
    stdout1, sent1, drops1 = _serve_udp(tlog, free_udp_port(), out1, 1)
    assert sent1 == sent2 > 0
    # everything sent was decoded (loopback; 4 x 430 = 1.7k datagrams/s: the single process
    # held 1.8k/s without a drop at load average 9.7 on 2 cores, benchmarks/bench_fleet)
    assert (drops1, drops2) == (0, 0)
    for stdout in (stdout1, stdout2):
        assert f"frames_ok={sent1}" in stdout
    # the port is routed by the kernel, each vehicle to its worker by the rule on its id
    # (ids 1-4 on 2 workers: 2 and 2)
    assert f"link udpin:127.0.0.1:{port2}: routed by the kernel" in stdout2
    loads = re.findall(r"worker (\d): (\d+) vehicles \[([\d, ]+)\]", stdout2)
    want = {w: [s for s in range(1, VEHICLES + 1) if worker_of_sysid(s, 2) == w] for w in (0, 1)}
    assert loads == [(str(w), str(len(v)), ", ".join(map(str, v))) for w, v in want.items()]
    assert [len(v) for v in want.values()] == [2, 2]
    rows2, rows1 = _velocity_rows(out2), _velocity_rows(out1)
    assert sorted(rows2) == list(range(1, VEHICLES + 1))
    for sysid in rows1:
        # the estimator runs on the vehicle's clock: the same frames give the same records,
        # whichever process estimated them; seq per configuration never goes back (one
        # worker per vehicle, the merged file keeps each vehicle's order)
        assert rows2[sysid] == rows1[sysid]
        assert len(rows1[sysid]) > 3 * 250 * 5 * 0.9  # ~3 s of 250 Hz IMU, 5 estimates each


@pytest.mark.timeout(180)
def test_a_tcp_stream_is_split_into_frames_for_the_workers(
    tmp_path: Path, free_tcp_port: Callable[[], int]
) -> None:
    tlog = record_tlog(tmp_path, 3.0)
    port = free_tcp_port()
    out = tmp_path / "tcp.csv"
    serve = subprocess.Popen(
        [OBS, "serve", "--workers", "2", "--link", f"tcpin:127.0.0.1:{port}", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_listening_tcp(port, serve)
        fleet = subprocess.run(
            [SITL, "fleet", "--tlog", str(tlog), "--vehicles", "4",
             "--link", f"tcp:127.0.0.1:{port}", "--stagger", "0.2"],
            check=True, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        wait_drained_tcp(port)
    finally:
        serve.send_signal(signal.SIGINT)
        stdout, stderr = serve.communicate(timeout=60)
    assert serve.returncode == 0, stderr
    sent = frames_sent(fleet.stdout)
    assert "0 failed sends" in fleet.stdout
    # one stream, cut at frame boundaries in the router: every frame decoded, none rejected
    assert f"frames_ok={sent}" in stdout and "rejected frames 0" in stdout
    assert "garbage_bytes" not in stdout
    header, *rows = out.read_text().splitlines()
    assert header.startswith("schema,sysid")
    assert {int(r.split(",")[1]) for r in rows} == {1, 2, 3, 4}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--rerun", "serve"], "glmav-observer serve: --rerun serve: with several workers"),
        (["--out", "records.txt"], "glmav-observer serve: records.txt: output must end in"),
        (["--workers", "0"], "argument --workers: 0 workers: must be 1..256"),
        (["--claim", "--no-zenoh", "--workers", "1"], "glmav-observer serve: --claim needs Zenoh"),
        (["--claim", "--no-zenoh"], "glmav-observer serve: --claim needs Zenoh"),
        # every worker opened it; the second said "already taken by another process"
        (
            ["--mavlink-out", "udpin:127.0.0.1:14557"],
            "--mavlink-out udpin:127.0.0.1:14557: one sender per link needs one process",
        ),
    ],
)
def test_bad_worker_options_exit_2_with_the_reason(
    args: list[str], message: str, tmp_path: Path, free_udp_port: Callable[[], int]
) -> None:
    cmd = [OBS, "serve", "--link", f"udpin:127.0.0.1:{free_udp_port()}", *args]
    if "--workers" not in args:
        cmd += ["--workers", "2"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=tmp_path, check=False)
    assert r.returncode == 2
    assert message in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.timeout(180)
def test_a_datagram_the_kernel_sends_to_the_wrong_worker_reaches_its_owner(
    tmp_path: Path, free_udp_port: Callable[[], int]
) -> None:
    """The kernel's program reads the header at byte 0: a datagram with bytes before its
    header goes to worker 0, which hands it to the vehicle's worker through the parent."""
    import threading
    import time

    from pymavlink.dialects.v20 import ardupilotmega as mav2

    from glmav_observer.config import ServiceConfig
    from glmav_observer.fleet.routing import worker_of_sysid
    from glmav_observer.fleet.workers import ShardedServer, worker_specs
    from glmav_observer.ingest.framing import FrameCounters, iter_tlog

    tlog = record_tlog(tmp_path, 1.5)
    messages = [r.msg for r in iter_tlog(tlog.read_bytes(), FrameCounters())]
    sysids = (1, 2, 3, 4)
    owner = {s: worker_of_sysid(s, 2) for s in sysids}
    assert sorted(owner.values()) == [0, 0, 1, 1]
    encoders = {s: mav2.MAVLink(None, srcSystem=s, srcComponent=1) for s in sysids}
    datagrams: list[bytes] = []
    prefixed = {0: 0, 1: 0}
    for i, msg in enumerate(messages):
        for s in sysids:
            d = bytes(msg.pack(encoders[s]))
            if i % 10 == 3:  # every 10th frame of each vehicle after two stray bytes
                d = b"\x00\x00" + d
                prefixed[owner[s]] += 1
            datagrams.append(d)
    port = free_udp_port()
    conn = f"udpin:127.0.0.1:{port}"
    cfg = ServiceConfig(request_rates=False)
    server = ShardedServer(worker_specs(cfg, 2), udp_links=[conn])
    assert server.kernel_routed == [conn]
    stop = threading.Event()
    th = threading.Thread(target=server.run, args=({}, stop), daemon=True)
    th.start()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for k, d in enumerate(datagrams):
                tx.sendto(d, ("127.0.0.1", port))
                if k % 50 == 49:
                    time.sleep(0.002)  # ~25k datagrams/s: well within the receive buffer
        drops = wait_drained(port)
        time.sleep(0.5)  # the forwarded ones go through the parent's batch (≤ 1 ms)
    finally:
        stop.set()
        th.join(30.0)
        result = server.close()
    assert drops == 0
    s = result.summary
    # every frame decoded exactly once: the stray bytes counted as garbage, 2 a datagram
    assert s.messages == len(datagrams)
    n_prefixed = prefixed[0] + prefixed[1]
    assert s.link_counters[conn]["garbage_bytes"] == 2 * n_prefixed
    # those of worker 1's vehicles were read by worker 0 and handed over; worker 0's own
    # stayed with it
    assert s.service_counters["datagrams_rerouted"] == prefixed[1] > 0
    # each vehicle on its owner only: had worker 0 estimated a stray one, it would be there too
    for w, vehicles in result.vehicles_per_worker.items():
        assert vehicles == [v for v in sysids if owner[v] == w]
