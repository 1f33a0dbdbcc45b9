"""glmav-sitl's own sensor and wind parameters as a lost-axis floor model
(:class:`glmav_observer.estimation.aero.floor.FloorModel`): read from the simulator's
config and scenario loaders, never retyped. Shared by the floor's tests and
``python -m benchmarks.aero`` (the service itself does not import the simulator)."""

from __future__ import annotations

import dataclasses
import math

from glmav_observer.estimation.aero.floor import FloorModel
from glmav_sitl.params import VehicleParams, load_vehicle_params
from glmav_sitl.scenario import (
    Scenario,
    SitlConfig,
    effective_rates,
    effective_sensor_config,
    load_scenario,
    load_sitl_config,
)


def sitl_floor_model(
    scenario: str | Scenario,
    axis: int,
    *,
    sensor_profile: str | None = None,
    sitl: SitlConfig | None = None,
    velocity_rate_hz: float | None = None,
) -> FloorModel:
    """The floor model of NED ``axis`` (0 n, 1 e, 2 d) for a glmav-sitl scenario: the IMU's
    accelerometer noise density and bias random walk (``[imu]`` with the scenario's noise
    and bias switches and scales), the scenario's turbulence σ on that axis and its time
    constant, the LOCAL_POSITION_NED rate (or ``velocity_rate_hz``) and noise."""
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    if sensor_profile is not None:
        sc = dataclasses.replace(sc, sensor_profile=sensor_profile)
    cfg = sitl or load_sitl_config()
    sens = effective_sensor_config(cfg, sc)
    noise = sens.noise_scale if sens.noise else 0.0
    bias = sens.bias_scale if sens.bias else 0.0
    rate = velocity_rate_hz or effective_rates(cfg, sc)["local_position_ned"]
    sigma_v = (
        cfg.autopilot.gps_velocity_sigma_mps
        if sc.sensor_profile == "autopilot"
        else sens.velocity_sigma_mps
    ) * noise
    return FloorModel(
        accel_noise_density=sens.imu.accel_noise_density * noise,
        accel_bias_random_walk=sens.imu.accel_bias_random_walk * bias,
        turbulence_sigma_mps=sc.wind.turbulence_sigma_mps[axis],
        turbulence_time_constant_s=sc.wind.turbulence_time_constant_s,
        velocity_rate_hz=rate,
        velocity_sigma_mps=sigma_v,
    )


def glmav_linear_drag_per_s(params: VehicleParams | None = None) -> tuple[float, float]:
    """The body's linear drag (k_x, k_y) in hover, 1/s, from the vehicle file: equations.md
    eqs. (7)-(8), f_i = ½ρS_iC_i [V_tot]_i ‖V_tot‖ / m, linearised in the horizontal
    airspeed u about the hover, where ‖V_tot‖ ≈ v_dw (the rotor's downwash at the body,
    momentum theory with the download: v_dw = downwash_hover √(T/(mg)), T = mg/(1 − c),
    c = ½ρS_top C_z downwash_hover²/(mg), glmav_sitl/dynamics/model.py):
    k_i = ½ρ S_side C_i v_dw / m. The informed prior of ``DragModelConfig.prior_k``."""
    p = params or load_vehicle_params()
    c = 0.5 * p.rho * p.top_area_m2 * p.cz * p.downwash_hover**2 / (p.m * p.g)
    v_dw = p.downwash_hover * math.sqrt(1.0 / (1.0 - c))
    kx = 0.5 * p.rho * p.side_area_m2 * p.cx * v_dw / p.m
    ky = 0.5 * p.rho * p.side_area_m2 * p.cy * v_dw / p.m
    return kx, ky
