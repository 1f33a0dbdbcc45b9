"""SERVO_OUTPUT_RAW: the commanded rotor speeds and cyclic, decoded from a tlog, against
the simulator's input at each message (glmav_sitl.mavlink.servo)."""

from __future__ import annotations

from pathlib import Path

from pymavlink import mavutil

from glmav_sitl.mavlink.servo import servo_pwm_us
from glmav_sitl.mavlink.vehicle import MavlinkVehicle
from glmav_sitl.scenario import effective_rates, load_scenario
from glmav_sitl.simulator import Simulator
from glmav_testkit.sitl_helpers import MemoryLink


def test_servo_output_raw_decodes_to_the_commanded_input(tmp_path: Path) -> None:
    sim = Simulator(load_scenario("gusts"), seed=3)
    path = tmp_path / "servo.tlog"
    sent: list[tuple[int, tuple[float, ...]]] = []  # (time_usec, u) at each message
    with path.open("wb") as tlog:
        v = MavlinkVehicle(
            sim,
            [MemoryLink()],
            rates_hz=effective_rates(sim.sitl, sim.scenario),
            sysid=1,
            tlog=tlog,
        )
        for _ in range(2000):  # 2 s at dt = 1 ms
            n = v.stats.sent["servo_output_raw"]
            v.poll_streams()
            if v.stats.sent["servo_output_raw"] > n:
                sent.append((sim.t_us, tuple(sim.u)))
            sim.step()
    mav = mavutil.mavlink_connection(str(path), dialect="common")
    got = []
    while (m := mav.recv_match(type="SERVO_OUTPUT_RAW")) is not None:
        got.append(m)
    # 50 Hz (sitl.toml): t = 0, 20, ..., 1980 ms
    assert [m.time_usec for m in got] == [k * 20_000 for k in range(100)]
    assert [t for t, _ in sent] == [m.time_usec for m in got]
    p = sim.params
    omega_lsb, swash_lsb = p.omega_max / 1000.0, p.swash_limit / 500.0
    cyclic_seen = 0.0
    for m, (_, u) in zip(got, sent, strict=True):
        assert (m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw) == servo_pwm_us(u, p)
        assert m.servo5_raw == m.servo8_raw == 0
        # the inverse of the documented linear map, within half a PWM step (rounding);
        # the hover commands stay inside the ranges (no saturation)
        assert abs((m.servo1_raw - 1000) * omega_lsb - u[0]) <= 0.5 * omega_lsb + 1e-9
        assert abs((m.servo2_raw - 1000) * omega_lsb - u[1]) <= 0.5 * omega_lsb + 1e-9
        assert abs((m.servo3_raw - 1500) * swash_lsb - u[2]) <= 0.5 * swash_lsb + 1e-9
        assert abs((m.servo4_raw - 1500) * swash_lsb - u[3]) <= 0.5 * swash_lsb + 1e-9
        cyclic_seen = max(cyclic_seen, abs(u[2]), abs(u[3]))
    # the turbulence makes the controller move the cyclic: the channels carry a signal
    assert cyclic_seen > 10 * swash_lsb


def test_servo_pwm_saturates_at_the_range() -> None:
    p = Simulator(load_scenario("hover"), seed=1).params
    big = (2 * p.omega_max, -1.0, 2 * p.swash_limit, -2 * p.swash_limit)
    assert servo_pwm_us(big, p) == (2000, 1000, 2000, 1000)
    assert servo_pwm_us((p.omega_max / 2, 0.0, 0.0, p.swash_limit / 2), p) == (
        1500,
        1000,
        1500,
        1750,
    )
