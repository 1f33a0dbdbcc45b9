"""The simulator core: state, fixed-step RK4, controller, wind and sensors (no I/O).

``Simulator.step()`` advances one physics step ``dt_s``; the controller and the wind
update at the control rate (zero-order hold between ticks). The scenario's
``sensor_profile`` picks the sensors: ``ideal`` (truth plus noise and bias, sampled when
a message is sent, :mod:`glmav_sitl.sensors.models`) or ``autopilot`` (a fast IMU with
vibration, an attitude estimator and a filtered, lagging GPS run inside the step,
:mod:`glmav_sitl.sensors.autopilot`). Time is kept as an
integer number of microseconds (``t_us``) so that stream schedules never drift.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from glmav_sitl.control.controller import Controller
from glmav_sitl.dynamics.frames import euler_from_quat, rotate_body_to_ned
from glmav_sitl.dynamics.model import (
    ModelOptions,
    initial_state,
    make_rhs,
    trim_rotor_speeds,
)
from glmav_sitl.params import VehicleParams, load_vehicle_params
from glmav_sitl.scenario import (
    Scenario,
    SensorConfig,
    SitlConfig,
    effective_sensor_config,
    load_scenario,
    load_sitl_config,
)
from glmav_sitl.sensors.autopilot import (
    AutopilotAttitude,
    AutopilotImu,
    AutopilotPosition,
    AutopilotSensors,
)
from glmav_sitl.sensors.models import AttitudeSensor, ImuModel, PositionVelocitySensor
from glmav_sitl.wind import WindModel

Vec3 = tuple[float, float, float]


class TruthState(NamedTuple):
    """The true state at ``t_s`` (SI; NED earth, FRD body). Immutable; a named tuple
    rather than a frozen dataclass because it is built at every stream tick (~0.5 us
    against ~4 us)."""

    t_s: float
    p_ned_m: Vec3
    v_body_mps: Vec3
    v_ned_mps: Vec3
    q: tuple[float, float, float, float]  # (w, x, y, z) body -> NED
    euler_rad: Vec3  # ZYX (phi, theta, psi)
    omega_body_radps: Vec3
    f_body_mps2: Vec3  # specific force (F - weight)/m, what an ideal accelerometer reads
    wind_ned_mps: Vec3
    rotor_radps: tuple[float, float]
    swash_rad: tuple[float, float]


class Simulator:
    """Fly one scenario. ``seed`` drives every random draw (sensors, turbulence, faults)."""

    def __init__(
        self,
        scenario: Scenario | str,
        *,
        params: VehicleParams | None = None,
        sitl: SitlConfig | None = None,
        seed: int = 0,
        dt_s: float | None = None,
        model_options: ModelOptions | None = None,
    ) -> None:
        self.scenario = load_scenario(scenario) if isinstance(scenario, str) else scenario
        self.params = params or load_vehicle_params()
        self.sitl = sitl or load_sitl_config()
        sc = self.scenario
        dt = dt_s if dt_s is not None else (sc.dt_s if sc.dt_s is not None else self.sitl.dt_s)
        self.dt_us = round(dt * 1e6)
        if self.dt_us < 1:
            raise ValueError(f"dt_s = {dt} s is below 1 us")
        self.dt_s = self.dt_us / 1e6
        ctl_us = round(1e6 / self.sitl.control_rate_hz)
        self.control_every = max(1, round(ctl_us / self.dt_us))  # steps per control tick
        self.model_options = model_options or ModelOptions()
        self._rhs = make_rhs(self.params, self.model_options)
        self._f = self._rhs.f
        self._step = self._rhs.step
        trim = trim_rotor_speeds(self.params, self.model_options)
        self.trim_rotor_radps = trim
        rotor0 = sc.rotor_radps if sc.rotor_radps is not None else trim
        self.x = initial_state(
            sc.position_ned_m,
            sc.velocity_body_mps,
            sc.euler_rad,
            sc.omega_body_radps,
            rotor_radps=rotor0,
            swash_rad=sc.swash_rad,
        )
        ss = np.random.SeedSequence(seed)
        r_imu, r_att, r_pos, r_fault, r_wind = (np.random.default_rng(s) for s in ss.spawn(5))
        self.sensor_config: SensorConfig = effective_sensor_config(self.sitl, sc)
        self.sensor_profile = sc.sensor_profile
        self.autopilot: AutopilotSensors | None = None
        self.imu: ImuModel | AutopilotImu
        self.attitude_sensor: AttitudeSensor | AutopilotAttitude
        self.position_sensor: PositionVelocitySensor | AutopilotPosition
        if sc.sensor_profile == "autopilot":
            # own streams, spawned after the five above (which stay as they are)
            r_ap = tuple(np.random.default_rng(s) for s in ss.spawn(4))
            q0 = (self.x[6], self.x[7], self.x[8], self.x[9])
            ap = AutopilotSensors(
                self.sitl.autopilot,
                self.sensor_config,
                (r_imu, r_ap[0], r_ap[1], r_ap[2], r_fault),
                sc.faults,
                g_mps2=self.params.g,
                dt_us=self.dt_us,
                q0=q0,
                p0_ned_m=(self.x[0], self.x[1], self.x[2]),
                v0_ned_mps=rotate_body_to_ned(q0, (self.x[3], self.x[4], self.x[5])),
                rotor_trim_radps=trim,
            )
            self.autopilot = ap
            self.imu = AutopilotImu(ap)
            self.attitude_sensor = AutopilotAttitude(ap)
            self.position_sensor = AutopilotPosition(ap)
        else:
            self.imu = ImuModel(self.sensor_config, r_imu, sc.faults)
            self.attitude_sensor = AttitudeSensor(self.sensor_config, r_att)
            self.position_sensor = PositionVelocitySensor(
                self.sensor_config, r_pos, r_fault, sc.faults
            )
        self.wind = WindModel(sc.wind, r_wind)
        self.wind_ned: list[float] = list(self.wind.update(0.0))
        self.controller: Controller | None = None
        if sc.control == "closed_loop":
            self.controller = Controller(
                self.params, self.sitl.gains, sc.setpoints, self.control_every * self.dt_s
            )
            self.u = self.controller.update(0.0, self.x)
        else:
            ol = sc.open_loop_rotor_radps if sc.open_loop_rotor_radps is not None else trim
            self.u = [ol[0], ol[1], sc.open_loop_swash_rad[0], sc.open_loop_swash_rad[1]]
        self.n_steps = 0
        self.t_us = 0
        self._truth_cache: TruthState | None = None

    @property
    def t_s(self) -> float:
        return self.t_us / 1e6

    def step(self) -> None:
        """Advance one physics step (RK4, inputs and wind held)."""
        self.x = self._step(self.x, self.u, self.wind_ned, self.dt_s)
        self.n_steps += 1
        self._after_steps()

    def advance(self, n: int) -> None:
        """Advance ``n`` physics steps: the same as ``n`` calls of :meth:`step`, bit for
        bit, in one compiled call per control period when nothing else runs in between
        (the ``autopilot`` profile's sensors run after every step: then step by step)."""
        if self.autopilot is not None or n <= 1:
            for _ in range(n):
                self.step()
            return
        every = self.control_every
        while n > 0:
            k = min(n, every - self.n_steps % every)
            x = list(self.x)  # a new list, as step() makes: a state handed out stays put
            self._rhs.step_into(x, self.u, self.wind_ned, self.dt_s, k)
            self.x = x
            self.n_steps += k
            n -= k
            self._after_steps()

    def _after_steps(self) -> None:
        """The clock, the control tick when due, the autopilot profile's sensors."""
        self.t_us = self.n_steps * self.dt_us
        self._truth_cache = None
        if self.n_steps % self.control_every == 0:
            t = self.t_s
            self.wind_ned = list(self.wind.update(t))
            if self.controller is not None:
                self.u = self.controller.update(t, self.x)
        if self.autopilot is not None:
            self.autopilot.update(self.t_us, self.x)
        if not math.isfinite(self.x[2]):
            raise FloatingPointError(f"state diverged at t = {self.t_s:.4f} s")

    def run_for(self, duration_s: float) -> None:
        self.advance(round(duration_s / self.dt_s))

    def truth(self) -> TruthState:
        """The true state now (cached until the next step)."""
        if self._truth_cache is not None:
            return self._truth_cache
        x = self.x
        x_dot, f_body = self._f(x, self.u, self.wind_ned)
        qw, qx, qy, qz = x[6], x[7], x[8], x[9]
        w = self.wind_ned
        self._truth_cache = TruthState(
            self.t_us / 1e6,
            (x[0], x[1], x[2]),
            (x[3], x[4], x[5]),
            # eq. (1): p_dot = R(q) v, the operations of frames.rotate_body_to_ned
            (x_dot[0], x_dot[1], x_dot[2]),
            (qw, qx, qy, qz),
            euler_from_quat(qw, qx, qy, qz),
            (x[10], x[11], x[12]),
            f_body,
            (w[0], w[1], w[2]),
            (x[13], x[14]),
            (x[15], x[16]),
        )
        return self._truth_cache
