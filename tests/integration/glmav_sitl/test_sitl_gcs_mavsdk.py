"""MAVSDK flies the simulator as a ground station would: parameters, arm, takeoff, offboard,
land, disarm, with its telemetry checked against the simulator's truth.

``glmav-sitl`` in ground-station flight (no scenario), real time, UDP loopback; MAVSDK's
native v4 binding (its bundled C++ core) is the client.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from glmav_sitl.params import load_vehicle_params
from glmav_sitl.simulator import TruthState
from glmav_testkit.sitl_helpers import background_run


def _wait(pred: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return
        time.sleep(0.05)  # MAVSDK updates its telemetry on its own thread
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.mark.timeout(150)
def test_mavsdk_flies_the_simulator(free_udp_port: Callable[[], int]) -> None:
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.offboard import Offboard, VelocityNedYaw
    from mavsdk.plugins.param import Param
    from mavsdk.plugins.telemetry import FlightMode, Telemetry

    port = free_udp_port()
    latest: list[TruthState] = []
    lock = threading.Lock()

    def on_truth(t: TruthState) -> None:
        with lock:
            latest[:] = [t]

    def truth() -> TruthState:
        with lock:
            return latest[0]

    veh = load_vehicle_params()
    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    plugins: list[Any] = []
    try:
        drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        with background_run(
            scenario=None,
            links=[f"udpout:127.0.0.1:{port}"],
            speed="realtime",
            on_truth=on_truth,
            truth_every_s=0.01,
        ) as (_stop, out):
            system = drone.first_autopilot(timeout_s=10.0)
            assert system is not None, "MAVSDK did not discover the vehicle"
            tel, act, par, off = Telemetry(system), Action(system), Param(system), Offboard(system)
            plugins += [tel, act, par, off]
            _wait(lambda: tel.health().is_armable, 10.0, "health: armable")
            # MAVSDK sets armable from SYS_STATUS and home from HOME_POSITION, two messages
            # handled one after the other: wait for the position flags too (once, in a full run, the
            # home flag was read a moment before its message had been handled)
            _wait(
                lambda: (
                    (h := tel.health()).is_home_position_ok
                    and h.is_global_position_ok
                    and h.is_local_position_ok
                ),
                10.0,
                "health: home, global and local position",
            )
            # the position is another message again, GLOBAL_POSITION_INT (10 Hz): NaN until
            # MAVSDK has handled the first one (CI once read it before, with the flags set)
            _wait(
                lambda: math.isfinite(tel.position().relative_altitude_m),
                5.0,
                "the first GLOBAL_POSITION_INT",
            )
            assert not tel.armed() and not tel.in_air()
            assert tel.flight_mode() == FlightMode.HOLD
            # on the ground at home: GLOBAL_POSITION_INT (1e-7 deg, 1 mm) and HOME_POSITION
            p = tel.position()
            assert p.relative_altitude_m == 0.0 and p.absolute_altitude_m == pytest.approx(260.0)
            assert tel.home().latitude_deg == pytest.approx(47.5867, abs=1e-7)

            # parameters: the vehicle file's values; settable ones take effect
            assert par.get_param_float("VEH_M") == pytest.approx(veh.m, rel=1e-6)
            assert par.get_param_float("VEH_IZZ") == pytest.approx(veh.izz, rel=1e-6)
            par.set_param_float("MPC_LAND_SPEED", 2.0)
            assert par.get_param_float("MPC_LAND_SPEED") == 2.0
            names = {q.name for q in par.get_all_params().float_params}
            assert {"VEH_M", "SIM_VFLT_AXIS", "MIS_TAKEOFF_ALT", "COM_OF_LOSS_T"} <= names

            act.set_takeoff_altitude(10.0)
            act.arm()
            _wait(tel.armed, 5.0, "armed")
            act.takeoff()
            _wait(lambda: tel.position().relative_altitude_m > 9.7, 20.0, "10 m")
            _wait(lambda: tel.flight_mode() == FlightMode.HOLD, 5.0, "HOLD after takeoff")
            assert tel.in_air()
            time.sleep(1.0)  # settle in hold
            # telemetry against the truth: GLOBAL_POSITION_INT is the autopilot's solution
            # (the truth, in 1 mm / 1 cm/s units); MAVSDK's copy lags by the loopback and
            # its polling (< 0.2 s) at < 0.5 m/s in hold -> 0.1 m and 0.1 m/s
            tr = truth()
            p, v = tel.position(), tel.velocity_ned()
            assert p.relative_altitude_m == pytest.approx(-tr.p_ned_m[2], abs=0.1)
            assert p.relative_altitude_m == pytest.approx(10.0, abs=0.3)
            for got, want in zip((v.north_m_s, v.east_m_s, v.down_m_s), tr.v_ned_mps, strict=True):
                assert got == pytest.approx(want, abs=0.1)
            # LOCAL_POSITION_NED (the noisy sensor): 5 sigma of 0.05 m/s plus the same lag
            pv = tel.position_velocity_ned().velocity
            for got, want in zip(
                (pv.north_m_s, pv.east_m_s, pv.down_m_s), tr.v_ned_mps, strict=True
            ):
                assert got == pytest.approx(want, abs=5 * 0.05 + 0.1)

            # offboard velocity: 2 m/s north, 1 m/s east
            off.set_velocity_ned(VelocityNedYaw(2.0, 1.0, 0.0, 0.0))
            off.start()
            _wait(lambda: tel.flight_mode() == FlightMode.OFFBOARD, 5.0, "OFFBOARD")
            time.sleep(3.0)  # the velocity loop settles in ~1 s (vel_p = 2/s)
            tr = truth()
            assert tr.v_ned_mps[0] == pytest.approx(2.0, abs=0.1)
            assert tr.v_ned_mps[1] == pytest.approx(1.0, abs=0.1)
            v = tel.velocity_ned()
            # constant velocity: MAVSDK's copy equals the truth within 1 cm/s units + 0.05
            assert v.north_m_s == pytest.approx(tr.v_ned_mps[0], abs=0.06)
            assert v.east_m_s == pytest.approx(tr.v_ned_mps[1], abs=0.06)
            off.stop()
            _wait(lambda: tel.flight_mode() == FlightMode.HOLD, 5.0, "HOLD after offboard")

            act.land()
            _wait(lambda: not tel.armed(), 20.0, "disarmed after landing")
            assert not tel.in_air()
            tr = truth()
            assert tr.p_ned_m[2] == 0.0 and math.hypot(*tr.v_ned_mps) == 0.0
        summary = out[0]
    finally:
        for pl in plugins:
            pl.destroy()
        drone.destroy()
    # the events a ground station saw, in order (STATUSTEXT)
    want = [
        "armed",
        "takeoff complete",
        "mode OFFBOARD",
        "mode HOLD",
        "mode LAND",
        "landed",
        "disarmed",
    ]
    it = iter(summary.statustexts)
    assert all(w in it for w in want), summary.statustexts
