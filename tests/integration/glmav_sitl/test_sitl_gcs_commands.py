"""Every command the simulator receives is acknowledged, and its modes are PX4's by name
(issue 31 D13, D14), over real UDP loopback against ``glmav-sitl run`` without a scenario.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from glmav_testkit.sitl_helpers import UdpGroundStation, background_run

ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
DENIED = mavlink2.MAV_RESULT_DENIED
UNSUPPORTED = mavlink2.MAV_RESULT_UNSUPPORTED


@pytest.mark.timeout(60)
def test_every_command_gets_an_ack_even_with_nan_parameters(
    free_udp_port: Callable[[], int],
) -> None:
    port = free_udp_port()
    gs = UdpGroundStation(port)
    nan, inf = math.nan, math.inf
    # (command, params, expected MAV_RESULT): NaN where a mode or a message id is needed
    # used to raise in the simulator and end its command handling (no ACK ever after,
    # the two takeoffs of D13 included)
    sequence = [
        (176, (nan, 4.0, 6.0), DENIED),  # DO_SET_MODE, base mode NaN
        (511, (nan, 1000.0), DENIED),  # SET_MESSAGE_INTERVAL of message NaN
        (512, (inf,), DENIED),  # REQUEST_MESSAGE of message inf
        (31000, (), UNSUPPORTED),  # a command it does not know
        (400, (1.0,), ACCEPTED),  # arm
        (22, (0, 0, 0, 0, 0, 0, 5.0), ACCEPTED),  # takeoff to 5 m
        (22, (0, 0, 0, 0, 0, 0, 5.0), None),  # again: accepted on the ground, else denied
    ]
    try:
        with background_run(
            scenario=None, links=[f"udpout:127.0.0.1:{port}"], duration_s=50.0, speed="realtime"
        ):
            gs.wait_for("HEARTBEAT", 5.0)
            for cmd, params, expected in sequence:
                gs.command_long(1, cmd, *params)
                # an ACK is one datagram after the command's: 5 s is far beyond a loaded
                # machine's scheduling delay
                ack = gs.wait_for("COMMAND_ACK", 5.0, lambda m, c=cmd: m.command == c)
                if expected is not None:
                    assert ack.result == expected, (cmd, ack.result)
                else:
                    assert ack.result in (ACCEPTED, DENIED), (cmd, ack.result)
            # two takeoffs in one datagram: two ACKs
            buf = b"".join(
                bytes(
                    mavlink2.MAVLink_command_long_message(
                        1, 1, 22, conf, 0, 0, 0, 0, 0, 0, 5.0
                    ).pack(gs.gcs)
                )
                for conf in (0, 1)
            )
            assert gs.peer is not None
            start = len(gs.received)
            gs.sock.sendto(buf, gs.peer)
            deadline = time.monotonic() + 5.0
            acks: list[int] = []
            while len(acks) < 2 and time.monotonic() < deadline:
                gs.poll()
                acks = [
                    m.result
                    for _, m in gs.received[start:]
                    if m.get_type() == "COMMAND_ACK" and m.command == 22
                ]
            assert len(acks) == 2
    finally:
        gs.close()


#: how long an answer may take on a loaded machine (s; the test's timeout bounds the sum)
ACK_WAIT_S = 15.0


@pytest.mark.timeout(120)
def test_pymavlink_names_and_sets_the_modes(free_udp_port: Callable[[], int]) -> None:
    """pymavlink (what MAVProxy and many scripts use) reads the modes by name and sets
    one by name: the HEARTBEAT says MAV_AUTOPILOT_PX4, whose layout custom_mode uses."""
    port = free_udp_port()
    master = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    try:
        with background_run(
            scenario=None, links=[f"udpout:127.0.0.1:{port}"], duration_s=50.0, speed="realtime"
        ):
            hb = master.wait_heartbeat(timeout=5.0)
            assert hb is not None
            assert hb.autopilot == mavlink2.MAV_AUTOPILOT_PX4
            assert master.flightmode == "LOITER"  # the simulator's HOLD (4/3)
            master.set_mode("TAKEOFF")  # by name: DO_SET_MODE (base, 4, 2)
            # (the answers come within milliseconds; the waits are long for a loaded
            # machine, where the simulator may get a tenth of a core: seen 5 s missed at
            # a load average of 10 on 2 cores)
            ack = master.recv_match(type="COMMAND_ACK", blocking=True, timeout=ACK_WAIT_S)
            assert ack is not None and ack.command == 176
            # disarmed: a takeoff mode is refused, and said so
            assert ack.result == DENIED
            master.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            ack = master.recv_match(type="COMMAND_ACK", blocking=True, timeout=ACK_WAIT_S)
            assert ack is not None and (ack.command, ack.result) == (400, ACCEPTED)
            for name in ("TAKEOFF", "LOITER"):  # armed: take off, then hold, by name
                master.set_mode(name)
                ack = master.recv_match(type="COMMAND_ACK", blocking=True, timeout=ACK_WAIT_S)
                assert ack is not None and (ack.command, ack.result) == (176, ACCEPTED), name
                deadline = time.monotonic() + ACK_WAIT_S  # the next 1 Hz HEARTBEAT shows it
                while master.flightmode != name and time.monotonic() < deadline:
                    master.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
                assert master.flightmode == name
    finally:
        master.close()
