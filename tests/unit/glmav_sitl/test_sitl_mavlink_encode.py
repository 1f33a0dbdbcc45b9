"""Encoding, RAW_IMU scaling and command handling of the vehicle (in-memory link)."""

from __future__ import annotations

from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.mavlink.vehicle import MavlinkVehicle
from glmav_sitl.scenario import effective_rates, load_scenario
from glmav_sitl.simulator import Simulator
from glmav_testkit.sitl_helpers import MemoryLink
from glmav_testkit.sitl_helpers import decode_mavlink as _decode


def _vehicle(scenario: str = "hover", **kw: Any) -> tuple[Simulator, MavlinkVehicle, MemoryLink]:
    sim = Simulator(load_scenario(scenario), seed=3)
    link = MemoryLink()
    v = MavlinkVehicle(sim, [link], rates_hz=effective_rates(sim.sitl, sim.scenario), sysid=7, **kw)
    return sim, v, link


def _gcs_command(cmd: int, *params: float, target: int = 7) -> bytes:
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    return bytes(mavlink2.MAVLink_command_long_message(target, 1, cmd, 0, *p).pack(gcs))


def test_raw_imu_scaling_round_trips_within_half_an_lsb() -> None:
    sim, v, link = _vehicle()
    v.poll_streams()
    for _ in range(40):
        sim.step()
        v.poll_streams()
    msgs = _decode(link.out)
    raw = [m for m in msgs if m.get_type() == "RAW_IMU"]
    hi = [m for m in msgs if m.get_type() == "HIGHRES_IMU"]
    sc = [m for m in msgs if m.get_type() == "SCALED_IMU"]
    assert len(raw) == len(hi) == len(sc) == 11  # t = 0, 4, ..., 40 ms at 250 Hz
    c = sim.sensor_config.imu
    # independent noise per message: compare raw units of the truth-level signal:
    # (0, 0, -g) is -1000.35 mG -> -1000 LSB, within the noise of 63 mG * 4 sigma
    for m in raw:
        assert m.zacc * c.raw_accel_lsb_mps2 == pytest.approx(-9.81, abs=0.3 + 0.2 * 4)
    # exact round trip of the quantiser: decode(encode(x)) within half an LSB
    from glmav_sitl.mavlink.frame import i16 as _i16

    for x in (-9.81, 0.01234, 3.3, -0.0004):
        q = _i16(x / c.raw_accel_lsb_mps2) * c.raw_accel_lsb_mps2
        assert abs(q - x) <= 0.5 * c.raw_accel_lsb_mps2
        g = _i16(x / c.raw_gyro_lsb_radps) * c.raw_gyro_lsb_radps
        assert abs(g - x) <= 0.5 * c.raw_gyro_lsb_radps
    assert _i16(1e9) == 32767 and _i16(-1e9) == -32767 and _i16(float("nan")) == 0
    # HIGHRES_IMU carries SI floats and the vehicle's clock in microseconds
    assert [m.time_usec for m in hi] == [k * 4000 for k in range(11)]
    assert all(m.get_srcSystem() == 7 for m in msgs)


def test_set_message_interval_is_acknowledged_and_changes_the_rate() -> None:
    sim, v, link = _vehicle()
    link.inbox.append(_gcs_command(511, 30.0, 50_000.0))  # ATTITUDE every 50 ms
    v.poll_inputs()
    acks = [m for m in _decode(link.out) if m.get_type() == "COMMAND_ACK"]
    assert [(a.command, a.result, a.target_system, a.target_component) for a in acks] == [
        (511, mavlink2.MAV_RESULT_ACCEPTED, 255, 190)
    ]
    link.out.clear()
    v.poll_streams()
    for _ in range(999):
        sim.step()
        v.poll_streams()
    names = [m.get_type() for m in _decode(link.out)]
    assert names.count("ATTITUDE") == 20  # t = 0, 50, ..., 950 ms: 1 s at 20 Hz
    assert names.count("LOCAL_POSITION_NED") == 30  # others untouched
    # -1 disables, 0 restores the default
    link.inbox.append(_gcs_command(511, 30.0, -1.0))
    v.poll_inputs()
    assert v.interval_us["attitude"] == 0
    link.inbox.append(_gcs_command(511, 30.0, 0.0))
    v.poll_inputs()
    assert v.interval_us["attitude"] == 10_000


def test_commands_answered_unsupported_or_ignored() -> None:
    sim, v, link = _vehicle()
    link.inbox += [
        _gcs_command(512, 148.0),  # REQUEST_MESSAGE AUTOPILOT_VERSION
        _gcs_command(400, 1.0),  # ARM during a scenario flight: denied, with a STATUSTEXT
        _gcs_command(183, 1.0, 1500.0),  # DO_SET_SERVO: not supported by the simulator
        _gcs_command(511, 9999.0, 1000.0),  # a message we do not stream
        _gcs_command(510, 105.0),  # GET_MESSAGE_INTERVAL HIGHRES_IMU
        _gcs_command(400, 1.0, target=9),  # another vehicle's: ignored, no ACK
        b"\xfd\x09garbage\x00\x01\x02" * 5,  # malformed bytes
        b"\x00" * 300,
    ]
    v.poll_inputs()
    msgs = _decode(link.out)
    acks = [(m.command, m.result) for m in msgs if m.get_type() == "COMMAND_ACK"]
    assert acks == [
        (512, mavlink2.MAV_RESULT_ACCEPTED),
        (400, mavlink2.MAV_RESULT_DENIED),
        (183, mavlink2.MAV_RESULT_UNSUPPORTED),
        (511, mavlink2.MAV_RESULT_UNSUPPORTED),
        (510, mavlink2.MAV_RESULT_ACCEPTED),
    ]
    (av,) = [m for m in msgs if m.get_type() == "AUTOPILOT_VERSION"]
    assert av.capabilities & mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    (mi,) = [m for m in msgs if m.get_type() == "MESSAGE_INTERVAL"]
    assert (mi.message_id, mi.interval_us) == (105, 4000)
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert texts == ["scenario flight: commands refused"]
    assert v.stats.bad_input > 0 and v.stats.commands == 5
    # and the vehicle still streams afterwards
    link.out.clear()
    sim.step()
    v.poll_streams()
    for _ in range(10):
        sim.step()
        v.poll_streams()
    assert any(m.get_type() == "RAW_IMU" for m in _decode(link.out))


def test_heartbeat_is_coaxial_and_mavlink2() -> None:
    _sim, v, link = _vehicle()
    v.poll_streams()
    hb = next(m for m in _decode(link.out) if m.get_type() == "HEARTBEAT")
    assert hb.type == mavlink2.MAV_TYPE_COAXIAL
    assert hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED  # rotors turning at trim
    assert link.out[0][0] == 0xFD  # MAVLink 2 magic


def test_sim_state_carries_truth() -> None:
    sim, v, link = _vehicle("cruise")
    for _ in range(5000):
        sim.step()
        v.poll_streams()
    tr = sim.truth()
    st = [m for m in _decode(link.out) if m.get_type() == "SIM_STATE"][-1]
    # last SIM_STATE at t = 5.0 s, same step as the truth (float32 rounding)
    assert (st.vn, st.ve, st.vd) == pytest.approx(tr.v_ned_mps, abs=1e-5)
    assert (st.q1, st.q2, st.q3, st.q4) == pytest.approx(tr.q, abs=1e-6)
    assert (st.xacc, st.yacc, st.zacc) == pytest.approx(tr.f_body_mps2, abs=1e-5)
    assert st.alt == pytest.approx(260.0 - tr.p_ned_m[2], abs=1e-3)


def test_signed_stream_verifies_with_the_key() -> None:
    key = bytes(range(32))
    sim, v, link = _vehicle(signing_key=key)
    for _ in range(10):
        sim.step()
        v.poll_streams()
    rx = mavlink2.MAVLink(None)
    rx.signing.secret_key = key
    rx.signing.allow_unsigned_callback = None
    msgs: list[Any] = []
    for b in link.out:
        assert b[2] & 0x01  # incompat flag: signed
        msgs += rx.parse_buffer(b) or []
    assert len(msgs) == len(link.out) and rx.signing.goodsig_count == len(link.out)


def test_signed_vehicle_answers_only_signed_commands() -> None:
    key = bytes(range(1, 33))
    _sim, v, link = _vehicle(signing_key=key)
    link.inbox.append(_gcs_command(512, 148.0))  # unsigned: rejected, no answer
    v.poll_inputs()
    assert not link.out and v.stats.bad_input == 1
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    gcs.signing.secret_key = key
    gcs.signing.sign_outgoing = True
    gcs.signing.timestamp = 10**12
    msg = mavlink2.MAVLink_command_long_message(7, 1, 512, 0, 148.0, 0, 0, 0, 0, 0, 0)
    link.inbox.append(bytes(msg.pack(gcs)))
    v.poll_inputs()
    acks = [m for m in _decode(link.out) if m.get_type() == "COMMAND_ACK"]
    assert [(a.command, a.result) for a in acks] == [(512, mavlink2.MAV_RESULT_ACCEPTED)]
    gcs.signing.secret_key = bytes(32)  # wrong key: rejected
    link.out.clear()
    link.inbox.append(bytes(msg.pack(gcs)))
    v.poll_inputs()
    assert not link.out and v.stats.bad_input == 2
