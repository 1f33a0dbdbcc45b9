"""The simulator's autopilot: arming, flight modes, commands, offboard setpoints, the ground.

Two kinds of flight:

- **ground-station flight** (``glmav-sitl run`` without ``--scenario``): the vehicle starts
  on the ground at home, disarmed, rotors stopped, and flies only what a ground station
  commands. The ground is the plane ``z = 0`` (home altitude): the vehicle rests on it.
- **scenario flight** (``--scenario NAME``): the scenario's setpoints fly the vehicle as
  before; the mode reads MISSION and flight commands are refused (DENIED, with a
  STATUSTEXT saying why). Parameters, telemetry and fault injection work in both.

Modes use PX4's ``custom_mode`` layout (``main_mode << 16 | sub_mode << 24``) and the
HEARTBEAT says MAV_AUTOPILOT_PX4, so MAVSDK, MAVProxy and QGroundControl name them (PX4's
names: HOLD is PX4's LOITER) and set them with DO_SET_MODE:

==========  ====  ===  =========================================================
mode        main  sub  behaviour
==========  ====  ===  =========================================================
HOLD        4     3    hold the position where the mode was entered (default)
TAKEOFF     4     2    climb at ``MPC_TKO_SPEED`` to ``MIS_TAKEOFF_ALT``, then HOLD
LAND        4     6    descend at ``MPC_LAND_SPEED``; disarm 1 s after touchdown
RTL         4     5    climb to ``RTL_RETURN_ALT``, fly over home, LAND
MISSION     4     4    a scenario flight (not selectable)
OFFBOARD    6     0    fly SET_POSITION_TARGET_LOCAL_NED; HOLD after ``COM_OF_LOSS_T``
==========  ====  ===  =========================================================

Commands: COMPONENT_ARM_DISARM (400; on the ground; param2 = 21196 forces a disarm in the
air), NAV_TAKEOFF (22; param7 = altitude AMSL; below home's altitude it is read as the
height above home, as MAVSDK sends it; NaN: ``MIS_TAKEOFF_ALT``), NAV_LAND (21),
NAV_RETURN_TO_LAUNCH (20), NAV_LOITER_UNLIM (17, HOLD), DO_SET_MODE (176; param2 main
mode, param3 sub mode). Every refusal is DENIED (or TEMPORARILY_REJECTED when it could
succeed later) with a STATUSTEXT naming the reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.dynamics.frames import euler_from_quat, quat_from_euler, rotate_body_to_ned
from glmav_sitl.scenario import Fault, Setpoint
from glmav_sitl.simulator import Simulator

from .params import FAULT_AXIS_CODES, FAULT_KIND_CODES, ParamTable

CMD_NAV_LOITER_UNLIM = 17
CMD_NAV_RETURN_TO_LAUNCH = 20
CMD_NAV_LAND = 21
CMD_NAV_TAKEOFF = 22
CMD_DO_SET_MODE = 176
CMD_COMPONENT_ARM_DISARM = 400
FORCE_DISARM_MAGIC = 21196
#: on the ground: within this height of it (m) ...
GROUND_HEIGHT_M = 0.05
#: ... and slower than this (m/s)
GROUND_SPEED_MPS = 0.3
#: takeoff is complete within this of the target altitude (m)
TAKEOFF_DONE_M = 0.3
#: LAND disarms after this long on the ground (s)
LANDED_DISARM_S = 1.0
#: RTL is over home (and lands) within this horizontal distance (m)
RTL_HOME_RADIUS_M = 1.0

# SET_POSITION_TARGET_*.type_mask bits
_IGNORE_POSITION = 0b111
_IGNORE_VELOCITY = 0b111000
_IGNORE_YAW = 1 << 10


class Mode(Enum):
    HOLD = (4, 3)
    TAKEOFF = (4, 2)
    LAND = (4, 6)
    RTL = (4, 5)
    MISSION = (4, 4)
    OFFBOARD = (6, 0)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @classmethod
    def from_main_sub(cls, main: int, sub: int) -> Mode | None:
        for m in cls:
            if m.value == (main, sub):
                return m
        return None


@dataclass
class Event:
    """A STATUSTEXT to send: MAV_SEVERITY and text (50 characters at most per message)."""

    severity: int
    text: str


class Autopilot:
    """Arming, modes, commands and offboard for ``sim``; ``events`` is drained by the vehicle."""

    def __init__(self, sim: Simulator, params: ParamTable, *, ground_station_flight: bool) -> None:
        if sim.controller is None:
            raise ValueError("the autopilot needs a closed-loop scenario (a controller)")
        self.sim = sim
        self.controller = sim.controller
        self.params = params
        self.gcs_flight = ground_station_flight
        self.armed = not ground_station_flight
        self.mode = Mode.HOLD if ground_station_flight else Mode.MISSION
        self.events: list[Event] = []
        self._offboard_sp: Setpoint | None = None
        self._offboard_rx_s = -math.inf
        self._rtl_phase = ""
        self._target_alt_m = 0.0
        self._ground_since_s: float | None = None
        self._takeoff_climbing = False
        self.resting = ground_station_flight  # on the ground at home
        self._scenario_faults = sim.scenario.faults

    # ------------------------------------------------------------------ state
    def _say(self, severity: int, text: str) -> None:
        self.events.append(Event(severity, text))

    def v_ned_mps(self) -> tuple[float, float, float]:
        x = self.sim.x
        return rotate_body_to_ned((x[6], x[7], x[8], x[9]), (x[3], x[4], x[5]))

    def on_ground(self) -> bool:
        if not self.gcs_flight:
            return False
        v = self.v_ned_mps()
        return (
            self.sim.x[2] > -GROUND_HEIGHT_M
            and math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) < GROUND_SPEED_MPS
        )

    def landed_state(self) -> int:
        if self.on_ground() and self.mode is not Mode.TAKEOFF:
            return int(mavlink2.MAV_LANDED_STATE_ON_GROUND)
        if self.mode is Mode.TAKEOFF:
            return int(mavlink2.MAV_LANDED_STATE_TAKEOFF)
        if self.mode is Mode.LAND or (self.mode is Mode.RTL and self._rtl_phase == "land"):
            return int(mavlink2.MAV_LANDED_STATE_LANDING)
        return int(mavlink2.MAV_LANDED_STATE_IN_AIR)

    def _fly(self, sp: Setpoint) -> None:
        self.controller.command(sp, self.sim.t_s, self.sim.x)

    def _hold_here(self) -> None:
        self._fly(Setpoint(0.0, "idle" if not self.armed else "hold"))

    def _set_mode(self, mode: Mode) -> None:
        if mode is not self.mode:
            self.mode = mode
            self._say(mavlink2.MAV_SEVERITY_INFO, f"mode {mode.name}")

    # --------------------------------------------------------------- commands
    def command(self, cmd: int, p: Sequence[float]) -> int | None:
        """A flight command's MAV_RESULT, or None if ``cmd`` is not a flight command."""
        if cmd not in (
            CMD_COMPONENT_ARM_DISARM,
            CMD_NAV_TAKEOFF,
            CMD_NAV_LAND,
            CMD_NAV_RETURN_TO_LAUNCH,
            CMD_NAV_LOITER_UNLIM,
            CMD_DO_SET_MODE,
        ):
            return None
        if not self.gcs_flight:
            return self._deny("scenario flight: commands refused")
        if cmd == CMD_COMPONENT_ARM_DISARM:
            return self.arm() if p[0] == 1.0 else self.disarm(force=p[1] == FORCE_DISARM_MAGIC)
        if cmd == CMD_NAV_TAKEOFF:
            alt = p[6] if math.isfinite(p[6]) else math.nan
            if alt >= self.sim.sitl.home_alt_m:  # AMSL, as the command defines it
                alt -= self.sim.sitl.home_alt_m
            return self.takeoff(alt)
        if cmd == CMD_NAV_LAND:
            return self.land()
        if cmd == CMD_NAV_RETURN_TO_LAUNCH:
            return self.rtl()
        if cmd == CMD_NAV_LOITER_UNLIM:
            return self.hold()
        if not int(p[0]) & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return self._deny("DO_SET_MODE: custom modes only")
        mode = Mode.from_main_sub(int(p[1]), int(p[2]))
        if mode is None:
            return self._deny(f"mode {int(p[1])}/{int(p[2])} not supported")
        return self.select_mode(mode)

    def _deny(self, why: str, result: int = mavlink2.MAV_RESULT_DENIED) -> int:
        self._say(mavlink2.MAV_SEVERITY_WARNING, why)
        return int(result)

    def select_mode(self, mode: Mode) -> int:
        if mode is Mode.HOLD:
            return self.hold()
        if mode is Mode.TAKEOFF:
            return self.takeoff(math.nan)
        if mode is Mode.LAND:
            return self.land()
        if mode is Mode.RTL:
            return self.rtl()
        if mode is Mode.OFFBOARD:
            return self.offboard()
        return self._deny(f"mode {mode.name} is not selectable")

    def arm(self) -> int:
        if self.armed:
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        if not self.on_ground():
            return self._deny("arming refused: not on the ground")
        if self.mode not in (Mode.HOLD, Mode.TAKEOFF):
            self._set_mode(Mode.HOLD)
        self.armed = True
        self._hold_here()
        self._say(mavlink2.MAV_SEVERITY_INFO, "armed")
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def disarm(self, *, force: bool = False) -> int:
        if not self.armed:
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        if not force and not self.on_ground():
            return self._deny("disarming refused: in the air (land first)")
        self.armed = False
        self._set_mode(Mode.HOLD)
        self._fly(Setpoint(0.0, "idle"))
        self._say(
            mavlink2.MAV_SEVERITY_CRITICAL
            if force and not self.on_ground()
            else mavlink2.MAV_SEVERITY_INFO,
            "disarmed (forced in the air)" if force and not self.on_ground() else "disarmed",
        )
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def takeoff(self, alt_m: float) -> int:
        if not self.armed:
            return self._deny("takeoff refused: arm first")
        if not self.on_ground():
            return self._deny("takeoff refused: already in the air")
        if not math.isfinite(alt_m):
            alt_m = self.params.get("MIS_TAKEOFF_ALT")
        if not 1.0 <= alt_m <= 100.0:
            return self._deny(f"takeoff refused: {alt_m:.1f} m outside [1, 100] m")
        self._target_alt_m = alt_m
        self._takeoff_climbing = True
        self._fly(
            Setpoint(
                0.0, "velocity", velocity_ned_mps=(0.0, 0.0, -self.params.get("MPC_TKO_SPEED"))
            )
        )
        self._set_mode(Mode.TAKEOFF)
        self._say(mavlink2.MAV_SEVERITY_INFO, f"takeoff to {alt_m:.1f} m")
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def hold(self) -> int:
        self._set_mode(Mode.HOLD)
        self._hold_here()
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def land(self) -> int:
        if not self.armed or self.on_ground():
            return self._deny("land refused: not flying")
        self._set_mode(Mode.LAND)
        self._ground_since_s = None
        self._fly(
            Setpoint(
                0.0, "velocity", velocity_ned_mps=(0.0, 0.0, self.params.get("MPC_LAND_SPEED"))
            )
        )
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def rtl(self) -> int:
        if not self.armed or self.on_ground():
            return self._deny("RTL refused: not flying")
        self._set_mode(Mode.RTL)
        x = self.sim.x
        alt = max(self.params.get("RTL_RETURN_ALT"), -x[2])
        self._target_alt_m = alt
        self._rtl_phase = "climb"
        self._fly(Setpoint(0.0, "position", position_ned_m=(x[0], x[1], -alt)))
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def offboard(self) -> int:
        if not self.armed:
            return self._deny("offboard refused: arm first")
        if self._offboard_sp is None or (
            self.sim.t_s - self._offboard_rx_s > self.params.get("COM_OF_LOSS_T")
        ):
            return self._deny(
                "offboard refused: no recent setpoint", mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
            )
        self._set_mode(Mode.OFFBOARD)
        self._fly(self._offboard_sp)
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def position_target(
        self, frame: int, type_mask: int, pos: Sequence[float], vel: Sequence[float], yaw: float
    ) -> bool:
        """SET_POSITION_TARGET_LOCAL_NED: store the setpoint (flown in OFFBOARD). False if refused."""
        yaw_sp = None if type_mask & _IGNORE_YAW or not math.isfinite(yaw) else float(yaw)
        if frame == mavlink2.MAV_FRAME_BODY_NED and not type_mask & _IGNORE_VELOCITY:
            # velocity along the heading: rotate by the current yaw
            x = self.sim.x
            psi = euler_from_quat(x[6], x[7], x[8], x[9])[2]
            c, s = math.cos(psi), math.sin(psi)
            vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
            frame = mavlink2.MAV_FRAME_LOCAL_NED
            type_mask |= _IGNORE_POSITION
        if frame != mavlink2.MAV_FRAME_LOCAL_NED:
            return False
        if not type_mask & _IGNORE_POSITION and all(math.isfinite(v) for v in pos):
            sp = Setpoint(0.0, "position", position_ned_m=(pos[0], pos[1], pos[2]), yaw_rad=yaw_sp)
        elif not type_mask & _IGNORE_VELOCITY and all(math.isfinite(v) for v in vel):
            sp = Setpoint(
                0.0, "velocity", velocity_ned_mps=(vel[0], vel[1], vel[2]), yaw_rad=yaw_sp
            )
        else:
            return False
        changed = sp != self._offboard_sp
        self._offboard_sp = sp
        self._offboard_rx_s = self.sim.t_s
        if self.mode is Mode.OFFBOARD and changed:
            self._fly(sp)
        return True

    # ---------------------------------------------------------- fault injection
    def param_changed(self, name: str, value: float) -> None:
        if name == "SIM_VEL_SIGMA":
            self.sim.position_sensor.set_velocity_sigma_mps(value)
        elif name == "MPC_XY_VEL_MAX":
            from dataclasses import replace

            self.controller.k = replace(self.controller.k, max_speed_mps=value)
        elif name.startswith("SIM_VFLT_") and (
            name == "SIM_VFLT_AXIS" or self.params.get("SIM_VFLT_AXIS") != 0
        ):
            self._apply_fault()

    def _apply_fault(self) -> None:
        axis = FAULT_AXIS_CODES.get(round(self.params.get("SIM_VFLT_AXIS")))
        if axis is None:
            self.sim.position_sensor.set_faults(self._scenario_faults)
            self._say(mavlink2.MAV_SEVERITY_NOTICE, "velocity fault cleared")
            return
        kind = FAULT_KIND_CODES[round(self.params.get("SIM_VFLT_KIND"))]
        start = self.params.get("SIM_VFLT_START")
        t0 = self.sim.t_s if start < 0 else start
        length = self.params.get("SIM_VFLT_LEN")
        t1 = t0 + length if length > 0 else math.inf
        mag = self.params.get("SIM_VFLT_MAG")
        fault = Fault("velocity", kind, t0, t1, axis=axis, magnitude=mag)
        self.sim.position_sensor.set_faults((*self._scenario_faults, fault))
        self._say(
            mavlink2.MAV_SEVERITY_NOTICE,
            f"fault {kind} v{axis} {mag:g} t={t0:.3f}-{t1:.3f}s",
        )

    # ------------------------------------------------------------- every tick
    def after_step(self) -> None:
        """The ground (ground-station flight only): the vehicle cannot sink below ``z = 0``.

        Resting on it (``resting``), the accelerometer reads the ground's push (-g on the
        body z axis), not the model's free fall."""
        x = self.sim.x
        if x[2] < 0.0:
            self.resting = False
            return
        self.resting = True
        psi = euler_from_quat(x[6], x[7], x[8], x[9])[2]
        q = quat_from_euler(0.0, 0.0, psi)
        x[2] = 0.0
        x[3] = x[4] = x[5] = 0.0
        x[6], x[7], x[8], x[9] = q
        x[10] = x[11] = x[12] = 0.0

    def tick(self) -> None:
        """Mode transitions, at the control rate."""
        if not self.gcs_flight or not self.armed:
            return
        t = self.sim.t_s
        x = self.sim.x
        if self.mode is Mode.TAKEOFF and self._takeoff_climbing:
            # climb at MPC_TKO_SPEED, then the position loop (its speed pos_p * error equals
            # the climb speed here, so the hand-over is smooth)
            left = self._target_alt_m + x[2]
            if left * self.controller.k.pos_p <= self.params.get("MPC_TKO_SPEED"):
                self._takeoff_climbing = False
                self._fly(
                    Setpoint(0.0, "position", position_ned_m=(x[0], x[1], -self._target_alt_m))
                )
        elif self.mode is Mode.TAKEOFF and abs(-x[2] - self._target_alt_m) < TAKEOFF_DONE_M:
            self._say(mavlink2.MAV_SEVERITY_INFO, "takeoff complete")
            self._set_mode(Mode.HOLD)  # at the takeoff altitude, not where the climb is now
            self._fly(Setpoint(0.0, "position", position_ned_m=(x[0], x[1], -self._target_alt_m)))
        elif self.mode is Mode.OFFBOARD and t - self._offboard_rx_s > self.params.get(
            "COM_OF_LOSS_T"
        ):
            self._say(mavlink2.MAV_SEVERITY_WARNING, "offboard setpoints lost: HOLD")
            self.hold()
        elif self.mode is Mode.RTL:
            if self._rtl_phase == "climb" and abs(-x[2] - self._target_alt_m) < TAKEOFF_DONE_M:
                self._rtl_phase = "return"
                self._fly(Setpoint(0.0, "position", position_ned_m=(0.0, 0.0, -self._target_alt_m)))
            elif self._rtl_phase == "return" and math.hypot(x[0], x[1]) < RTL_HOME_RADIUS_M:
                self._rtl_phase = "land"
                self._ground_since_s = None
                self._fly(
                    Setpoint(
                        0.0,
                        "velocity",
                        velocity_ned_mps=(0.0, 0.0, self.params.get("MPC_LAND_SPEED")),
                    )
                )
        if self.mode is Mode.LAND or (self.mode is Mode.RTL and self._rtl_phase == "land"):
            if self.on_ground():
                if self._ground_since_s is None:
                    self._ground_since_s = t
                elif t - self._ground_since_s >= LANDED_DISARM_S:
                    self._say(mavlink2.MAV_SEVERITY_INFO, "landed")
                    self.disarm()
            else:
                self._ground_since_s = None
