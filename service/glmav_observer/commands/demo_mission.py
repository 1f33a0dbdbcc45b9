"""The demo's mission, flown through MAVSDK as a ground station flies a vehicle.

Against ``glmav-sitl run`` without a scenario (on the ground, disarmed): set the fault
injection parameters (``SIM_VFLT_*``, a scheduled velocity-sensor fault in vehicle time)
and a brisk takeoff (``MPC_TKO_SPEED`` = 4 m/s), arm, take off towards 10 m, and from 5 m
fly a climbing turn in OFFBOARD with velocity setpoints (3 m/s along a heading that turns
at 0.3 rad/s, climbing 0.5 m/s) until the simulator stops: the vehicle is moving well
before the fault starts, so every fault kind (a freeze too) is observable. The heading follows the vehicle's own clock (the IMU timestamps MAVSDK
receives), so the turn is the same at any simulation speed.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

logger = logging.getLogger(__name__)

#: SIM_VFLT_KIND codes of glmav-sitl (glmav_sitl.gcs.params.FAULT_KIND_CODES)
FAULT_KIND_CODE = {"bias": 1, "freeze": 2, "dropout": 3, "noise": 4}
FAULT_AXIS_CODE = {"n": 1, "e": 2, "d": 3}
TAKEOFF_ALT_M = 10.0
TAKEOFF_SPEED_MPS = 4.0
#: the turn starts above this height (m)
TURN_FROM_M = 5.0
TURN_SPEED_MPS = 3.0
TURN_RATE_RADPS = 0.3
CLIMB_RATE_MPS = 0.5
#: how often the offboard setpoint is updated (host seconds)
SETPOINT_PERIOD_S = 0.05


@dataclass
class MissionLog:
    """What the ground station did, with the vehicle time of each step (s)."""

    steps: list[tuple[str, float]] = field(default_factory=list)
    error: str | None = None

    def step(self, what: str, t_vehicle_s: float) -> None:
        self.steps.append((what, t_vehicle_s))
        logger.info("mavsdk: %s at t = %.2f s", what, t_vehicle_s)

    def summary(self) -> str:
        done = ", ".join(f"{w} (t = {t:.1f} s)" for w, t in self.steps)
        return f"flown by MAVSDK: {done}" + (f"; stopped: {self.error}" if self.error else "")


def fly(
    port: int,
    *,
    fault_axis: str,
    fault_kind: str,
    fault_at_s: float,
    fault_end_s: float,
    magnitude: float,
    stop: threading.Event,
    connected: threading.Event | None = None,
) -> MissionLog:
    """Fly the mission through MAVSDK listening on ``udpin://127.0.0.1:port`` until ``stop``."""
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.offboard import Offboard, VelocityNedYaw
    from mavsdk.plugins.param import Param
    from mavsdk.plugins.telemetry import Telemetry

    log = MissionLog()
    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    plugins: list[Any] = []
    try:
        drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        if connected is not None:
            connected.set()
        system = None
        deadline = time.monotonic() + 30.0
        while system is None and not stop.is_set() and time.monotonic() < deadline:
            system = drone.first_autopilot(timeout_s=0.5)
        if system is None:
            log.error = "no vehicle discovered"
            return log
        tel, act, par, off = Telemetry(system), Action(system), Param(system), Offboard(system)
        plugins += [tel, act, par, off]

        def t_vehicle() -> float:
            return float(tel.imu().timestamp_us) / 1e6

        def wait(pred: Any, timeout_s: float) -> bool:
            deadline = time.monotonic() + timeout_s
            while not stop.is_set() and time.monotonic() < deadline:
                if pred():
                    return True
                stop.wait(0.02)
            return False

        # the fault, scheduled in vehicle time; SIM_VFLT_AXIS last arms it
        par.set_param_float("SIM_VFLT_KIND", float(FAULT_KIND_CODE[fault_kind]))
        par.set_param_float("SIM_VFLT_MAG", magnitude)
        par.set_param_float("SIM_VFLT_START", fault_at_s)
        par.set_param_float("SIM_VFLT_LEN", fault_end_s - fault_at_s)
        par.set_param_float("SIM_VFLT_AXIS", float(FAULT_AXIS_CODE[fault_axis]))
        par.set_param_float("MPC_TKO_SPEED", TAKEOFF_SPEED_MPS)
        log.step(f"fault {fault_kind} on v{fault_axis} set by parameters", t_vehicle())
        if not wait(lambda: tel.health().is_armable, 30.0):
            log.error = "the vehicle never became armable"
            return log
        act.set_takeoff_altitude(TAKEOFF_ALT_M)
        act.arm()
        log.step("armed", t_vehicle())
        act.takeoff()
        log.step(f"takeoff to {TAKEOFF_ALT_M:g} m", t_vehicle())
        if not wait(lambda: tel.position().relative_altitude_m > TURN_FROM_M, 60.0):
            log.error = log.error or f"not above {TURN_FROM_M:g} m"
            return log
        t0 = t_vehicle()
        yaw0 = tel.attitude_euler().yaw_deg
        off.set_velocity_ned(VelocityNedYaw(0.0, 0.0, -CLIMB_RATE_MPS, yaw0))
        off.start()
        log.step(f"offboard climbing turn from {TURN_FROM_M:g} m", t0)
        while not stop.is_set():
            psi = math.radians(yaw0) + TURN_RATE_RADPS * (t_vehicle() - t0)
            off.set_velocity_ned(
                VelocityNedYaw(
                    TURN_SPEED_MPS * math.cos(psi),
                    TURN_SPEED_MPS * math.sin(psi),
                    -CLIMB_RATE_MPS,
                    math.degrees(psi),
                )
            )
            stop.wait(SETPOINT_PERIOD_S)
    except Exception as exc:  # MAVSDK raises its own errors; the demo reports them
        if not stop.is_set():
            log.error = f"{type(exc).__name__}: {exc}"
    finally:
        for p in plugins:
            p.destroy()
        drone.destroy()
    return log
