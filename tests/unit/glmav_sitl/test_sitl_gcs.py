"""The simulator as a ground station sees it: parameters, arming, modes, offboard, the ground.

In-memory link, the real runner loop (``run`` at full speed); a script injects the ground
station's messages at given simulated times through the truth callback.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.gcs.autopilot import Mode
from glmav_sitl.gcs.params import VEHICLE_PARAM_NAMES
from glmav_sitl.params import load_vehicle_params
from glmav_sitl.runner import RunSummary, run
from glmav_sitl.simulator import TruthState
from glmav_testkit.sitl_helpers import MemoryLink
from glmav_testkit.sitl_helpers import decode_mavlink as _decode

GCS = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)


def _pack(msg: Any) -> bytes:
    return bytes(msg.pack(GCS))


def _cmd(cmd: int, *params: float) -> bytes:
    p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    return _pack(mavlink2.MAVLink_command_long_message(1, 1, cmd, 0, *p))


def _param_set(name: str, value: float) -> bytes:
    return _pack(
        mavlink2.MAVLink_param_set_message(
            1, 1, name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32
        )
    )


def _velocity_setpoint(vn: float, ve: float, vd: float) -> bytes:
    mask = 0b111 | 0b111000000 | (1 << 11)  # ignore position, acceleration, yaw rate
    return _pack(
        mavlink2.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, mask, 0, 0, 0, vn, ve, vd, 0, 0, 0, 0.0, 0
        )
    )


def _fly(
    script: Callable[[float, MemoryLink], None],
    duration_s: float,
    scenario: str | None = None,
    every_s: float = 0.001,
) -> tuple[RunSummary, list[Any], dict[int, TruthState]]:
    """Run the simulator with ``script(t_s, link)`` called every ``every_s`` of simulated
    time; the truth at those times by millisecond."""
    link = MemoryLink()
    truth: dict[int, TruthState] = {}

    def on_truth(tr: TruthState) -> None:
        truth[round(tr.t_s * 1000)] = tr
        script(tr.t_s, link)

    summary = run(scenario, [link], duration_s, "max", 0, on_truth=on_truth, truth_every_s=every_s)
    return summary, _decode(link.out), truth


def _once(at_s: float, *bufs: bytes) -> Callable[[float, MemoryLink], None]:
    done = [False]

    def step(t: float, link: MemoryLink) -> None:
        if not done[0] and t >= at_s:
            done[0] = True
            link.inbox += bufs

    return step


def test_parameters_list_read_set_and_refusals() -> None:
    veh = load_vehicle_params()
    script = [
        _once(0.1, _pack(mavlink2.MAVLink_param_request_list_message(1, 1))),
        _once(0.2, _param_set("SIM_VEL_SIGMA", 0.0)),
        _once(0.3, _param_set("VEH_M", 3.0)),  # read-only
        _once(0.4, _param_set("MIS_TAKEOFF_ALT", 500.0)),  # out of range
        _once(
            0.5,
            _pack(mavlink2.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1)),
        ),
    ]
    summary, msgs, truth = _fly(lambda t, lk: [s(t, lk) for s in script], 2.0)
    values = [m for m in msgs if m.get_type() == "PARAM_VALUE"]
    n = values[0].param_count
    listed = values[:n]
    assert [v.param_index for v in listed] == list(range(n))
    assert all(v.param_type == mavlink2.MAV_PARAM_TYPE_REAL32 for v in listed)
    by_name = {v.param_id: v.param_value for v in listed}
    for key, name in VEHICLE_PARAM_NAMES.items():  # the vehicle file's values (float32)
        assert by_name[name] == pytest.approx(getattr(veh, key), rel=1e-6)
    assert by_name["SIM_VEL_SIGMA"] == pytest.approx(0.05)  # sitl.toml's value
    answers = [(v.param_id, v.param_value) for v in values[n:]]
    assert answers == [
        ("SIM_VEL_SIGMA", 0.0),
        ("VEH_M", pytest.approx(veh.m)),  # unchanged: the refusal
        ("MIS_TAKEOFF_ALT", 10.0),  # unchanged
        ("MIS_TAKEOFF_ALT", 10.0),  # the read
    ]
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert texts == [
        "VEH_M: read-only (the vehicle file's value)",
        "MIS_TAKEOFF_ALT: 500 outside [1, 100]",
    ]
    # SIM_VEL_SIGMA = 0 from 0.2 s: LOCAL_POSITION_NED velocity is the truth exactly
    # (float32 of the message: 1e-6 m/s), on the ground at rest
    lpn = [m for m in msgs if m.get_type() == "LOCAL_POSITION_NED" and m.time_boot_ms > 250]
    assert len(lpn) >= 50
    for m in lpn:
        tr = truth[m.time_boot_ms]
        assert (m.vx, m.vy, m.vz) == pytest.approx(tr.v_ned_mps, abs=1e-6)
    assert summary.final_truth is not None and summary.final_truth.p_ned_m[2] == 0.0
    # resting on the ground the accelerometer feels the ground's push: -g on body z (the
    # model alone would read free fall, 0); turn-on bias sigma 0.2 m/s^2, 4 sigma
    imu = [m for m in msgs if m.get_type() == "HIGHRES_IMU"]
    zacc = sum(m.zacc for m in imu) / len(imu)
    assert zacc == pytest.approx(-9.81, abs=0.8)


def test_ground_station_flight_arm_takeoff_offboard_timeout_rtl_land() -> None:
    script = [
        _once(0.1, _param_set("MPC_LAND_SPEED", 2.0), _param_set("RTL_RETURN_ALT", 12.0)),
        _once(0.5, _cmd(22, *[math.nan] * 7)),  # takeoff before arming: refused
        _once(1.0, _cmd(400, 1.0)),  # arm
        _once(1.5, _cmd(22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)),  # to 10 m
        _once(7.0, _cmd(400, 0.0)),  # disarm in the air: refused
        _once(8.2, _cmd(176, 1.0, 6.0, 0.0)),  # OFFBOARD
        _once(14.0, _cmd(20)),  # RTL
    ]

    def offboard(t: float, link: MemoryLink) -> None:
        # velocity setpoints 2 m/s north at 10 Hz from 8 s to 12 s, then silence
        if 8.0 <= t < 12.0 and round(t * 1000) % 100 == 0:
            link.inbox.append(_velocity_setpoint(2.0, 0.0, 0.0))

    def all_(t: float, link: MemoryLink) -> None:
        for s in script:
            s(t, link)
        offboard(t, link)

    summary, msgs, truth = _fly(all_, 30.0, every_s=0.01)
    acks = [(m.command, m.result) for m in msgs if m.get_type() == "COMMAND_ACK"]
    assert acks == [
        (22, mavlink2.MAV_RESULT_DENIED),
        (400, mavlink2.MAV_RESULT_ACCEPTED),
        (22, mavlink2.MAV_RESULT_ACCEPTED),
        (400, mavlink2.MAV_RESULT_DENIED),
        (176, mavlink2.MAV_RESULT_ACCEPTED),
        (20, mavlink2.MAV_RESULT_ACCEPTED),
    ]
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert texts == [
        "takeoff refused: arm first",
        "armed",
        "mode TAKEOFF",
        "takeoff to 10.0 m",
        "takeoff complete",
        "mode HOLD",
        "disarming refused: in the air (land first)",
        "mode OFFBOARD",
        "offboard setpoints lost: HOLD",
        "mode HOLD",
        "mode RTL",
        "landed",
        "mode HOLD",
        "disarmed",
    ]
    # resting on the ground until armed: no sinking, no drift
    assert truth[1000].p_ned_m == (0.0, 0.0, 0.0)
    # at 10 m (within TAKEOFF_DONE_M = 0.3 m) in hold before the offboard leg
    assert -truth[8000].p_ned_m[2] == pytest.approx(10.0, abs=0.3)
    # offboard: 2 m/s north after the velocity loop's settling (vel_p = 2/s: 1 s ~ 2 time
    # constants, then within 0.1 m/s), height held within 0.3 m
    for t_ms in range(10_000, 12_000, 100):
        v = truth[t_ms].v_ned_mps
        assert v[0] == pytest.approx(2.0, abs=0.1) and abs(v[1]) < 0.1
    # the setpoints stop at 12 s; COM_OF_LOSS_T = 1 s later HOLD stops the vehicle
    assert math.hypot(*truth[13_900].v_ned_mps[:2]) < 0.5
    # RTL: climbs to RTL_RETURN_ALT = 12 m, back over home (1 m), lands, disarms
    assert max(-tr.p_ned_m[2] for tr in truth.values()) == pytest.approx(12.0, abs=0.5)
    end = summary.final_truth
    assert end is not None and end.p_ned_m[2] == 0.0 and math.hypot(*end.p_ned_m[:2]) < 1.0
    # heartbeats: the mode and arming state as a ground station reads them
    hb = [
        (m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED != 0, m.custom_mode)
        for m in msgs
        if m.get_type() == "HEARTBEAT"
    ]
    assert hb[0] == (False, Mode.HOLD.custom_mode) and hb[-1] == (False, Mode.HOLD.custom_mode)
    modes = {c for _, c in hb}
    assert {Mode.TAKEOFF.custom_mode, Mode.OFFBOARD.custom_mode, Mode.RTL.custom_mode} <= modes
    # EXTENDED_SYS_STATE's landed state walks the whole cycle
    ls = [m.landed_state for m in msgs if m.get_type() == "EXTENDED_SYS_STATE"]
    seq = [s for i, s in enumerate(ls) if i == 0 or s != ls[i - 1]]
    assert seq == [
        mavlink2.MAV_LANDED_STATE_ON_GROUND,
        mavlink2.MAV_LANDED_STATE_TAKEOFF,
        mavlink2.MAV_LANDED_STATE_IN_AIR,
        mavlink2.MAV_LANDED_STATE_LANDING,
        mavlink2.MAV_LANDED_STATE_ON_GROUND,
    ]
    # GLOBAL_POSITION_INT is the truth in its units (mm, cm/s): 10 m relative at 8 s
    gpi = [m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT" and m.time_boot_ms == 8000]
    assert len(gpi) == 1 and gpi[0].relative_alt == round(-truth[8000].p_ned_m[2] * 1000)


def test_velocity_fault_injected_through_parameters() -> None:
    # hover scenario (parameters work in a scenario flight too); noise off to see the bias
    script = [
        _once(0.1, _param_set("SIM_VEL_SIGMA", 0.0)),
        _once(0.2, _param_set("SIM_VFLT_KIND", 1.0), _param_set("SIM_VFLT_MAG", 1.5)),
        _once(
            0.3,
            _param_set("SIM_VFLT_START", 1.0),
            _param_set("SIM_VFLT_LEN", 1.0),
            _param_set("SIM_VFLT_AXIS", 2.0),  # e: armed last, from 1 s to 2 s
        ),
    ]
    _summary, msgs, truth = _fly(lambda t, lk: [s(t, lk) for s in script], 3.0, "hover")
    lpn = [m for m in msgs if m.get_type() == "LOCAL_POSITION_NED" and m.time_boot_ms > 150]
    inside = outside = 0
    for m in lpn:
        tr = truth[m.time_boot_ms]
        bias = 1.5 if 1000 <= m.time_boot_ms < 2000 else 0.0
        inside += bias > 0
        outside += bias == 0
        assert m.vy - tr.v_ned_mps[1] == pytest.approx(bias, abs=1e-5)
        assert m.vx == pytest.approx(tr.v_ned_mps[0], abs=1e-6)
    assert inside >= 29 and outside >= 50  # 30 Hz
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert texts == ["fault bias ve 1.5 t=1.000-2.000s"]
