"""The estimate goes back to the vehicle: ``serve --mavlink-out`` closes the loop with the SITL.

The simulator streams to ``serve`` (a subprocess) over UDP loopback and listens on a second
link; the service sends its ODOMETRY, STATUSTEXT, NAMED_VALUE_FLOAT and HEARTBEAT there.
The simulator compares each ODOMETRY velocity with its truth at the message's
``time_usec`` and keeps what the other component said.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_observer.commands.demo import scenario_toml
from glmav_sitl.mavlink.links import Link, open_link
from glmav_sitl.runner import RunSummary, run
from glmav_sitl.scenario import load_scenario

CLI = [sys.executable, "-m", "glmav_observer.cli"]


class Tap:
    """The simulator's listening link, also parsing what it reads (ODOMETRY times)."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.name = link.name
        self.parser = mavlink2.MAVLink(None)
        self.odometry_s: list[float] = []
        self._lock = threading.Lock()

    def read(self) -> list[bytes]:
        data = self.link.read()
        for d in data:
            for m in self.parser.parse_buffer(d) or []:
                if m.get_type() == "ODOMETRY":
                    with self._lock:
                        self.odometry_s.append(m.time_usec / 1e6)
        return data

    def write(self, buf: bytes) -> None:
        self.link.write(buf)

    def last_odometry_s(self) -> float:
        with self._lock:
            return self.odometry_s[-1] if self.odometry_s else 0.0

    def close(self) -> None:
        self.link.close()


@pytest.mark.timeout(120)
def test_odometry_statustext_and_health_reach_the_vehicle(
    tmp_path: Path, free_udp_port: Callable[[], int]
) -> None:
    # a climbing turn with a 1 m/s bias on the measured east velocity from 6 s to 9 s
    path = tmp_path / "loop.toml"
    path.write_text(scenario_toml(14.0, "e", "bias", 6.0, 9.0, name="loop"), encoding="utf-8")
    svc_port, sim_port = free_udp_port(), free_udp_port()
    serve = subprocess.Popen(
        [*CLI, "serve", "--link", f"udpin:127.0.0.1:{svc_port}",
         "--mavlink-out", f"udpout:127.0.0.1:{sim_port}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: list[str] = []
    ready = threading.Event()

    def read_stderr() -> None:
        assert serve.stderr is not None
        for line in serve.stderr:
            lines.append(line)
            if "link open" in line:
                ready.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    tap = Tap(open_link(f"udpin:127.0.0.1:{sim_port}"))
    stop = threading.Event()
    result: list[RunSummary] = []
    sim = threading.Thread(
        target=lambda: result.append(
            run(
                load_scenario(path),
                [f"udpout:127.0.0.1:{svc_port}", tap],
                60.0,
                "realtime",
                1,
                stop_event=stop,
            )
        ),
        daemon=True,
    )
    try:
        assert ready.wait(30.0), "serve did not open its link"
        sim.start()
        # the scenario is 14 s; the vehicle keeps flying (and listening) until the service,
        # which may lag on a loaded machine, has sent its estimate for 14 s
        deadline = time.monotonic() + 90.0
        while tap.last_odometry_s() < 14.0 and time.monotonic() < deadline and sim.is_alive():
            time.sleep(0.1)
        stop.set()
        sim.join(timeout=20.0)
        serve.send_signal(signal.SIGINT)
        serve.wait(timeout=30)
        reader.join(timeout=10)
    finally:
        stop.set()
        tap.close()
        if serve.poll() is None:
            serve.kill()
            serve.wait()
    err = "".join(lines)
    assert serve.returncode == 0, err[-3000:]
    (summary,) = result
    got = summary.received_estimates
    assert got is not None
    # ODOMETRY at rate_hz = 30 per vehicle (vehicle time): the first 14 s all arrived
    # (loopback; the estimator starts within 0.1 s of boot), each time once
    stamps = [t for t in tap.odometry_s if t <= 14.0]
    assert len(stamps) == pytest.approx(30 * 14, abs=5)
    assert len(set(stamps)) == len(stamps) and stamps == sorted(stamps)
    assert got.count["ODOMETRY"] == len(tap.odometry_s)
    assert got.sources == {(1, 191)}  # the vehicle's system, MAV_COMP_ID_ONBOARD_COMPUTER
    assert got.estimator_types == {mavlink2.MAV_ESTIMATOR_TYPE_GPS_INS}
    # compared with the truth at each time_usec: the daemon's 0.1 m/s bound (the hand-over
    # keeps the dead-reckoned east axis within it through the 3 s fault)
    assert got.compared >= 0.9 * got.count["ODOMETRY"]
    rmse = got.rmse_ned_mps()
    assert rmse is not None and max(rmse) <= 0.1, rmse
    # the switch to c3 and back: two resets; quality 50 while dead reckoning
    assert got.reset_counters == {0, 1, 2}
    assert got.qualities == {100, 50}
    # the component announced itself as an onboard controller, never as a ground station
    assert got.heartbeats[(1, 191)] == (
        mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink2.MAV_AUTOPILOT_INVALID,
    )
    fault = [t for t in got.texts if t.startswith("glmav 1: fault bias ve at ")]
    assert len(fault) == 1
    assert 6.0 <= float(fault[0].rsplit(" ", 1)[1].rstrip("s")) <= 6.5  # the daemon's 0.5 s
    assert any(t.startswith("glmav 1: full -> c3 at ") for t in got.texts)
    assert any(t.startswith("glmav 1: c3 -> full at ") for t in got.texts)
    # NAMED_VALUE_FLOAT at 1 Hz: GLV_E went faulty (3) and back; GLV_CFG c3 (3) and full (0)
    assert 3.0 in got.named_values["GLV_E"] and got.named_values["GLV_E"][-1] == 1.0
    assert got.named_values["GLV_CFG"][0] == 0.0 and 3.0 in got.named_values["GLV_CFG"]
    assert all(v == 1.0 for v in got.named_values["GLV_N"][3:])  # ok after the warm-up
    assert len(got.named_values["GLV_N"]) == pytest.approx(14, abs=2)


def test_vision_speed_estimate_signed_with_the_service_key(
    free_udp_port: Callable[[], int],
) -> None:
    """The sink alone, records in, a receiver that accepts only frames signed with the key."""
    import socket

    from glmav_observer.config import MavlinkOutSettings
    from glmav_observer.publish.mavlink_out import MavlinkOutSink
    from glmav_observer.records import VelocityRecord

    key = bytes(range(32))
    port = free_udp_port()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.settimeout(2.0)
    settings = MavlinkOutSettings(
        enabled=True,
        link=f"udpout:127.0.0.1:{port}",
        system_id=42,
        component_id=197,
        rate_hz=10.0,
        odometry=False,
        vision_speed_estimate=True,
    )
    sink = MavlinkOutSink(settings, signing_key=key)
    try:
        for k in range(250):  # 1 s at 250 Hz, east lost (dead reckoning) from 0.5 s
            lost = "e" if k >= 125 else None
            sink.write(
                VelocityRecord(
                    3, "active", k * 0.004, (0.0, 0.0, 0.0), (1.0, -2.0, 0.5), lost,
                    "dead_reckoning" if lost else "ok", k, "c3" if lost else "full",
                    0.2 if lost else None,
                )
            )  # fmt: skip
    finally:
        sink.close()
    parser = mavlink2.MAVLink(None)
    parser.signing.secret_key = key
    parser.signing.allow_unsigned_callback = None  # unsigned or badly signed: BAD_DATA
    got = []
    try:
        while True:
            for m in parser.parse_buffer(rx.recv(65535)) or []:
                got.append(m)
    except TimeoutError:
        pass
    finally:
        rx.close()
    assert [m.get_type() for m in got if m.get_type() == "BAD_DATA"] == []
    vse = [m for m in got if m.get_type() == "VISION_SPEED_ESTIMATE"]
    # 10 Hz of vehicle time over 1 s; system 42 (fixed), component 197, all signed
    assert len(vse) == 10
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in got} == {(42, 197)}
    assert all(m.get_signed() for m in got)
    assert [round(m.usec / 4000) for m in vse] == [0, 25, 50, 75, 100, 125, 150, 175, 200, 225]
    assert all((m.x, m.y, m.z) == (1.0, -2.0, 0.5) for m in vse)
    # covariance: 0.05^2 on measured axes; the dead-reckoned east axis 0.2^2 (float32)
    assert vse[0].covariance[0] == pytest.approx(0.0025) and vse[0].covariance[4] == pytest.approx(
        0.0025
    )
    assert vse[-1].covariance[4] == pytest.approx(0.04) and vse[-1].covariance[8] == pytest.approx(
        0.0025
    )
    assert [m.reset_counter for m in vse] == [0] * 5 + [1] * 5
    hb = [m for m in got if m.get_type() == "HEARTBEAT"]
    assert hb and hb[0].type == mavlink2.MAV_TYPE_ONBOARD_CONTROLLER


@pytest.mark.timeout(60)
def test_udpin_output_answers_only_its_first_peer(free_udp_port: Callable[[], int]) -> None:
    """Issue 31 D7: a local process that sends one byte to a ``udpin`` output used to get
    the stream (the last sender won); now the first peer keeps it, the other is refused."""
    import socket

    from glmav_observer.config import MavlinkOutSettings
    from glmav_observer.publish.mavlink_out import HEARTBEAT_PERIOD_S, MavlinkOutSink

    port = free_udp_port()
    sink = MavlinkOutSink(MavlinkOutSettings(enabled=True, link=f"udpin:127.0.0.1:{port}"))
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    parser = mavlink2.MAVLink(None)

    def heartbeats(sock: socket.socket, seconds: float) -> int:
        sock.settimeout(0.1)
        n = 0
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                data = sock.recv(65535)
            except TimeoutError:
                continue
            n += sum(m.get_type() == "HEARTBEAT" for m in parser.parse_buffer(data) or [])
        return n

    try:
        gcs.bind(("127.0.0.1", 0))
        thief.bind(("127.0.0.1", 0))
        gcs.sendto(b"\x00", ("127.0.0.1", port))
        # the first peer is pinned at the next heartbeat turn (1 s), then heard at 1 Hz
        assert heartbeats(gcs, 3 * HEARTBEAT_PERIOD_S + 1.0) >= 1
        thief.sendto(b"\x00", ("127.0.0.1", port))
        # 4 periods: >= 2 heartbeats to the first peer even if the thread is late by one,
        # and none to the thief, whose byte the sink read within the first period
        got_thief = heartbeats(thief, 4 * HEARTBEAT_PERIOD_S)
        got_gcs = heartbeats(gcs, 0.2) + heartbeats(gcs, 2 * HEARTBEAT_PERIOD_S)
        assert got_thief == 0
        assert got_gcs >= 1
        assert sink.stats.foreign_peer_datagrams == 1
    finally:
        sink.close()
        gcs.close()
        thief.close()
