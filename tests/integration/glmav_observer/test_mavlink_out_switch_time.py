"""Issue 29.7: a switch's STATUSTEXT gives the switch's own time, not the next health
record's (86.13 s for a switch at 86.043 s on ArduPilot's SITL).

The synthetic flight (exact kinematics) goes through the service as MAVLink frames, its IMU
at 25 Hz: a switch decided at a LOCAL_POSITION_NED sample (30 Hz) reaches the next health
record only at the next IMU sample, up to 40 ms later. The sink sends to a UDP socket on
127.0.0.1; the texts are compared with the service's switch events.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterator

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from glmav_observer.app import Service
from glmav_observer.config import MavlinkOutSettings, ServiceConfig
from glmav_observer.ingest.samples import AttitudeSample, ImuSample, VelocitySample
from glmav_observer.publish.mavlink_out import MavlinkOutSink
from glmav_testkit.synthetic_flight import FAULTS, flight

#: the IMU's period (s): a 25 Hz IMU, as ArduPilot streams RAW_IMU on a slow link
IMU_PERIOD_MS = 40


def _frames(mav: object) -> Iterator[tuple[float, bytes]]:
    """The flight (east velocity dropped out from 5 s to 9 s) as MAVLink 2 frames."""
    dropout = FAULTS["dropout"](1, 5.0)

    def fault(t: float, y: object) -> object:
        return dropout(t, y) if t < 9.0 else y

    for s in flight(14.0, seed=3, fault=fault):
        t_ms = round(s.t_boot_s * 1000)
        if isinstance(s, ImuSample):
            if t_ms % IMU_PERIOD_MS:
                continue
            f, w = s.f_body_mps2, s.omega_body_radps
            msg = mavlink.MAVLink_highres_imu_message(
                t_ms * 1000, *f, *w, 0.0, 0.0, 0.0, 1013.0, 0.0, 0.0, 20.0, 0x3F
            )
        elif isinstance(s, AttitudeSample):
            msg = mavlink.MAVLink_attitude_message(t_ms, *s.euler_rad, 0.0, 0.0, 0.0)
        elif isinstance(s, VelocitySample):
            msg = mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, 0.0, *s.v_ned_mps)
        else:
            continue
        yield s.t_boot_s, bytes(msg.pack(mav))


def test_switch_text_gives_the_switch_time(free_udp_port: Callable[[], int]) -> None:
    port = free_udp_port()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    rx.settimeout(2.0)
    sink = MavlinkOutSink(
        MavlinkOutSettings(enabled=True, link=f"udpout:127.0.0.1:{port}", named_value_float=False)
    )
    svc = Service(ServiceConfig(request_rates=False), [sink])
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    try:
        for t, frame in _frames(mav):
            svc.feed_bytes("flight", frame, t)
    finally:
        svc.close()
    texts: list[str] = []
    parser = mavlink.MAVLink(None)
    rx.settimeout(0.5)
    try:
        while True:
            for m in parser.parse_buffer(rx.recv(65536)) or []:
                if m.get_type() == "STATUSTEXT":
                    texts.append(m.text)
    except TimeoutError:
        pass
    finally:
        rx.close()
    switches = svc.summary().vehicles[1].switches
    assert [(s["from"], s["to"]) for s in switches] == [("full", "c3"), ("c3", "full")]
    said = [t for t in texts if " -> " in t]
    assert said == [
        f"glmav 1: {s['from']} -> {s['to']} at {s['t_boot_s']:.2f}s" for s in switches
    ], (said, switches)
