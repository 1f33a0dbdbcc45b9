"""ArduPilot SITL's drag law, wind and sensors as a lost-axis floor model
(:class:`glmav_observer.estimation.aero.floor.FloorModel`), for the ArduPilot flights of
``tests/data/ardupilot_sitl`` (tuning) and ``tests/data/ardupilot_sitl_heldout`` (held out).

The drag law is ArduPilot's own SITL frame model (ArduPilot 2598e9d4, GPLv3; read, not
copied: the formulas below are restated from it with their source files):

- **multicopters** (quad, hexa, octa; ``libraries/SITL/SIM_Frame.cpp``, ``SIM_Motor.cpp``,
  the default frame model: mass 3 kg, refSpd 15.08 m/s at refAngle 45° and refAlt 593 m,
  disc_area 0.385 m², mdrag_coef 0.2). Per body axis j ∈ {x, y}, with u the body airspeed,
  T the total thrust and ρ the air density::

      m f_j = −mdrag ·√(ρ A T) · u_j − ½ ρ areaCd · u_j|u_j|                      (P1)

  (each motor's momentum drag is mdrag·√(ρA/N)·u·√(T/N); the N motors sum to
  mdrag·√(ρAT), whatever N). areaCd is what makes the total drag at refSpd balance
  mg·tan(refAngle): areaCd = (mg tan 45° − D_m)/(½ρ_ref refSpd²), D_m the momentum drag
  there, cos 45°·mdrag·refSpd cos 45°·√(ρ_ref A mg/cos 45°). In hover (T = mg) at 500 m:
  k = 0.242 1/s, q = ½ρ areaCd/m = 0.034 1/m.
- **coax** (``SIM_SingleCopter.cpp``): linear isotropic, f = −(g/v_term) u/eas2tas with
  v_term = 40 m/s: k = 0.24 1/s.
- **heli** (``SIM_Helicopter.cpp``, conventional frame): f_x = −g·a1s + X_u u_x,
  f_y = g·b1s + Y_v u_y + tail thrust, X_u = −0.125, Y_v = −0.375 1/s. The rotor's
  flapping angles are not logged: the oracle is granted them.

**Wind** (``SIM_Aircraft.cpp`` ``update_wind``, ``AP_HAL_SITL/SITL_State.cpp``): the mean
wind SIM_WIND_SPD from SIM_WIND_DIR, scaled by √(h/60 m) below 60 m (SIM_WIND_T's default
profile), known to the oracle; turbulence SIM_WIND_TURB: a horizontal speed, an IIR
(coefficient 0.98 per physics step at 1200 Hz, input 10·TURB·N(0, 1)) of stationary σ_h =
10·TURB·0.02/√(1 − 0.98²) = 1.005·TURB m/s, along an azimuth redrawn at random every step.
Its direction is thus new at every step: on one earth axis it is white at 1200 Hz, with
variance σ_h²/2 and low-frequency PSD r = σ_h²/(2·1200) m²/s, 4.2e-4 at TURB 1; averaged
over one velocity interval Δt it is white noise of variance r/Δt on the airspeed the
drag measures (F2's ε_u). No turbulence is left for the oracle to carry as a state.

**Sensors.** SITL's accelerometer has no noise or bias drift by default (SIM_ACC1_RND 0);
what reaches the service is RAW_IMU in milli-g: quantised, σ = 1 mg/√12 per sample. The
healthy velocity (LOCAL_POSITION_NED, the EKF's) has the error against SIM_STATE that the
flight shows (its RMS, per axis). With the true attitude and no bias random walk the
oracle knows the bias (P_bb = 0 at the hand-over) and its own dead reckoning drifts only
with the quantisation (4 mm/s after 60 s). The estimator's earth-frame acceleration is
rotated by the EKF's attitude, whose error drifts: ``input_bias_random_walk`` gives the
oracle that input instead (the benchmark measures it on each flight against SIM_STATE).

**d.** The oracle does not see the thrust (no actuator outputs in these logs), so the body
z row gives it nothing; the horizontal rows see d only through the tilt. Its floor on d is
taken as its own dead reckoning: an upper bound of the true floor there.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from glmav_observer.estimation.aero.floor import FloorModel, steady_state

FloatArray = NDArray[np.float64]

G_MPS2 = 9.80665
#: ArduPilot SITL's physics rate, Hz (SIM_Aircraft.h ``rate_hz``)
PHYSICS_RATE_HZ = 1200.0
#: SIM_Aircraft.cpp update_wind: the turbulence's IIR coefficient per physics step and the
#: scale of its input (10 × SIM_WIND_TURB)
TURB_IIR = 0.98
TURB_SCALE = 10.0
#: SIM_WIND_T's default profile (WIND_TYPE_SQRT) and SIM_WIND_T_ALT's default, m
WIND_PROFILE_ALT_M = 60.0
#: RAW_IMU's resolution: 1 milli-g, m/s²
RAW_IMU_LSB_MPS2 = 1e-3 * G_MPS2
#: the ArduPilot flights' home altitude, m AMSL (sidecar ``home``), and the take-off
#: altitude above it, m
HOME_ALT_M = 488.0


def air_density_kgpm3(alt_amsl_m: float) -> float:
    """ISA troposphere density (what AP_Baro::get_air_density_for_alt_amsl computes)."""
    t_k = 288.15 - 0.0065 * alt_amsl_m
    p_pa = 101325.0 * (t_k / 288.15) ** 5.25588
    return p_pa / (287.26 * t_k)


@dataclass(frozen=True)
class FrameDrag:
    """A frame's horizontal drag in hover (P1): f_j = −k_j u_j − q u_j|u_j|, 1/s and 1/m."""

    frame: str
    k_x_per_s: float
    k_y_per_s: float
    q_per_m: float


def frame_drag(frame: str, alt_amsl_m: float = HOME_ALT_M + 10.0) -> FrameDrag:
    """The drag law of ArduPilot SITL's ``--model`` (module docstring), in hover."""
    rho = air_density_kgpm3(alt_amsl_m)
    if frame.startswith(("quad", "hexa", "octa", "+", "x")):
        mass, ref_spd, ref_angle, ref_alt = 3.0, 15.08, math.radians(45.0), 593.0
        disc_area, mdrag = 0.385, 0.2
        rho_ref = air_density_kgpm3(ref_alt)
        cos_t = math.cos(ref_angle)
        drag_force = mass * G_MPS2 * math.tan(ref_angle)
        momentum = (
            cos_t * mdrag * ref_spd * cos_t * math.sqrt(mass * G_MPS2 / cos_t * rho_ref * disc_area)
        )
        area_cd = (drag_force - momentum) / (0.5 * rho_ref * ref_spd**2)
        k = mdrag * math.sqrt(rho * disc_area * mass * G_MPS2) / mass
        return FrameDrag(frame, k, k, 0.5 * rho * area_cd / mass)
    if frame.startswith("coax"):
        eas2tas = math.sqrt(1.225 / rho)
        k = G_MPS2 / 40.0 / eas2tas
        return FrameDrag(frame, k, k, 0.0)
    if frame.startswith("heli"):
        return FrameDrag(frame, 0.125, 0.375, 0.0)
    raise ValueError(f"no drag law for ArduPilot SITL frame {frame!r}")


def sidecar(path: Path) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return out


def sitl_frame(meta: dict[str, Any]) -> str:
    m = re.search(r"--model (\S+)", str(meta.get("sitl_command", "")))
    if m is None:
        raise ValueError(f"{meta.get('name')}: no --model in sitl_command")
    return m.group(1)


def wind_params_at(meta: dict[str, Any], t_boot_s: float) -> dict[str, float]:
    """SIM_WIND_* in force at ``t_boot_s``: the baseline, the environment set before arming
    (held-out set) and any fault window that changed them (tuning set's a_quad_wind)."""
    p: dict[str, float] = {"SIM_WIND_SPD": 0.0, "SIM_WIND_DIR": 180.0, "SIM_WIND_TURB": 0.0}
    p.update({k: float(v) for k, v in meta.get("baseline_params", {}).items()})
    for e in meta.get("environment_params") or []:
        p[str(e["name"])] = float(e["acked_value"])
    for f in meta.get("faults", []):
        on = float(f["start_time_boot_ms"]) * 1e-3
        off = float(f.get("end_time_boot_ms", math.inf)) * 1e-3
        if on <= t_boot_s < off:
            p.update({k: float(v) for k, v in f["params"].items()})
    return p


def turbulence_sigma_h_mps(turb: float) -> float:
    """σ_h of the turbulence's horizontal speed (module docstring), m/s."""
    return TURB_SCALE * turb * (1.0 - TURB_IIR) / math.sqrt(1.0 - TURB_IIR**2)


def turbulence_psd_m2ps(turb: float) -> float:
    """r of one earth axis' white turbulence (module docstring), m²/s."""
    return turbulence_sigma_h_mps(turb) ** 2 / 2.0 / PHYSICS_RATE_HZ


def mean_wind_ne_mps(params: dict[str, float], height_m: float) -> tuple[float, float]:
    """The mean wind's (n, e) velocity at ``height_m`` above ground: SITL's direction is
    where the wind comes from (SIM_Aircraft.cpp negates the vector), √ profile below 60 m."""
    spd = params.get("SIM_WIND_SPD", 0.0) * math.sqrt(
        min(max(height_m, 0.0) / WIND_PROFILE_ALT_M, 1.0)
    )
    d = math.radians(params.get("SIM_WIND_DIR", 0.0))
    return -spd * math.cos(d), -spd * math.sin(d)


def ardupilot_floor_model(
    meta: dict[str, Any],
    t_loss_s: float,
    horizon_s: float,
    *,
    velocity_rate_hz: float,
    imu_rate_hz: float,
    velocity_sigma_mps: float,
    input_bias_random_walk: float = 0.0,
) -> FloorModel:
    """The floor model of one lost horizontal axis of an ArduPilot flight from ``t_loss_s``
    for ``horizon_s``: the largest turbulence in force over the window, the frame's hover
    drag (the smallest slope of (P1): the largest airspeed noise from the accelerometer's
    quantisation), RAW_IMU's quantisation as the accelerometer's only noise.

    ``input_bias_random_walk`` (m/s³/√Hz): the random walk of the earth-frame
    acceleration's error that the estimator's inputs carry (0: the oracle's own, exact
    attitude; the benchmark measures the service's, whose attitude is the EKF's ATTITUDE,
    against SIM_STATE)."""
    turb = max(
        wind_params_at(meta, t)["SIM_WIND_TURB"]
        for t in np.linspace(t_loss_s, t_loss_s + horizon_s, 61)
    )
    drag = frame_drag(sitl_frame(meta))
    k = min(drag.k_x_per_s, drag.k_y_per_s)
    sigma_q = RAW_IMU_LSB_MPS2 / math.sqrt(12.0)
    dt_v = 1.0 / velocity_rate_hz
    n_imu = max(imu_rate_hz * dt_v, 1.0)
    var_u = (sigma_q / k) ** 2 / n_imu + turbulence_psd_m2ps(turb) / dt_v
    return FloorModel(
        accel_noise_density=sigma_q / math.sqrt(imu_rate_hz),
        accel_bias_random_walk=input_bias_random_walk,
        turbulence_sigma_mps=0.0,
        turbulence_time_constant_s=1.0,
        velocity_rate_hz=velocity_rate_hz,
        velocity_sigma_mps=velocity_sigma_mps,
        drag_sigma_mps=math.sqrt(var_u),
    )


# --- the as-flown floor (issue 32): the oracle without the gift of a perfect drag law ---
#
# The oracle above is granted the drag law exactly: its only airspeed noise is RAW_IMU's
# quantisation and SITL's white turbulence, which it averages down to a few mm/s. On the
# flights the law does not hold that well: the thrust varies (momentum drag ∝ √T), the
# heli's rotor flaps, the attitude the service has is the EKF's, and each of these leaves a
# misfit that is *correlated over seconds* and so is not averaged away. The as-flown floor
# grants the oracle the best constant law of the form (P1) (k, q and a body bias per
# body axis, least squares over the flight against the truth), the mean wind at the
# vehicle's height, and the statistics of what is left, the misfit: white noise plus a
# first-order Gauss-Markov process on the airspeed it measures, which is (F1)-(F2)'s w
# (``FloorModel.turbulence_*``), now measured instead of SITL's (white) turbulence.

#: the vehicle is airborne (the law applies: no ground contact) above this height, m
AIRBORNE_HEIGHT_M = 2.0
#: the longest correlation time looked for, s (the misfit's autocovariance is read up to
#: it; a longer one is taken as this: the flights' are 0.08-3.6 s)
MISFIT_MAX_TAU_S = 20.0
#: the fewest airborne samples a law is fitted on (3 unknowns per body axis; fewer than
#: this leaves no degrees of freedom worth the name)
MIN_FIT_SAMPLES = 10


@dataclass(frozen=True)
class LawMisfit:
    """The drag law's misfit on one earth axis, in airspeed units (m/s)."""

    white_sigma_mps: float  # σ of its white part (per velocity sample)
    slow_sigma_mps: float  # σ of its Gauss-Markov part
    slow_tau_s: float  # the Gauss-Markov part's time constant, s


def height_above_start_m(t_s: FloatArray, v_down_mps: FloatArray) -> FloatArray:
    """The height above the first sample (the ground: the flights start landed), from the
    truth's down velocity integrated (trapezoid rule), m."""
    dh = -0.5 * (v_down_mps[1:] + v_down_mps[:-1]) * np.diff(t_s)
    out: FloatArray = np.concatenate([[0.0], np.cumsum(dh)])
    return out


def law_misfit_ne_mps(
    meta: dict[str, Any],
    t_s: FloatArray,
    *,
    v_truth_ned_mps: FloatArray,
    height_m: FloatArray,
    e_body_to_ned: FloatArray,
    f_mean_body_mps2: FloatArray,
    fit_mask: NDArray[np.bool_] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Per velocity sample: whether it is usable (airborne, finite) and the drag law's
    misfit on the n and e axes, m/s, shape (m, 2).

    ``fit_mask``: the samples the law is fitted on (of the usable ones; default all): the
    causal floor fits it on the samples before a loss and reads its misfit after.

    The body airspeed u = Eᵀ(v − w), w the sidecar's mean wind at the height (true
    velocity, the EKF's attitude: what the service has); per body axis j ∈ {x, y} the law
    f_j = −k_j u_j − q_j u_j|u_j| + b_j fitted by least squares over the usable samples;
    its residual over the law's slope k_j + 2q_j|u_j| is an airspeed error, rotated to the
    earth axes by E's horizontal block (tilt neglected: < 1 % at the flights' ≤ 10°)."""
    wind = np.array(
        [
            (*mean_wind_ne_mps(wind_params_at(meta, float(t)), float(h)), 0.0)
            for t, h in zip(t_s, height_m, strict=True)
        ]
    )
    u = np.einsum("kji,kj->ki", e_body_to_ned, v_truth_ned_mps - wind)
    ok = (height_m > AIRBORNE_HEIGHT_M) & np.all(np.isfinite(f_mean_body_mps2), axis=1)
    fit = ok if fit_mask is None else ok & fit_mask
    if int(fit.sum()) < MIN_FIT_SAMPLES:
        raise ValueError(f"{meta.get('name')}: fewer than {MIN_FIT_SAMPLES} airborne samples")
    err_body = np.zeros((len(t_s), 2))
    for j in range(2):
        a = np.column_stack([-u[:, j], -u[:, j] * np.abs(u[:, j]), np.ones(len(t_s))])
        theta, *_ = np.linalg.lstsq(a[fit], f_mean_body_mps2[fit, j], rcond=None)
        slope = np.maximum(theta[0] + 2.0 * theta[1] * np.abs(u[:, j]), 1e-3)
        # f − f_law = −slope·δu: the airspeed error the law reads
        err_body[:, j] = -(f_mean_body_mps2[:, j] - a @ theta) / slope
    err_ne: FloatArray = np.einsum("kij,kj->ki", e_body_to_ned[:, :2, :2], err_body)
    return ok, err_ne


def misfit_statistics(err_mps: FloatArray, dt_s: float, *, keep_mean: bool = False) -> LawMisfit:
    """White σ, Gauss-Markov σ and τ of a misfit series (one axis, uniform samples dt_s
    apart). With C(L) its autocovariance (mean removed: a constant part is learnt before
    any loss), a white part adds to C(0) only and a Gauss-Markov part gives C(L) =
    σ_m² exp(−L dt/τ) at every lag. So the decay from lag 1 on is the Gauss-Markov part's
    alone: C(L_e) = C(1)/e at L_e = 1 + τ/dt (L_e interpolated linearly between lags),
    σ_m² = C(1) exp(dt/τ) (at most C(0)) and σ_e² = C(0) − σ_m². A τ beyond
    MISFIT_MAX_TAU_S is taken as that.

    ``keep_mean``: the mean is not removed (the causal floor: a law fitted before the loss
    is off after it by a constant too, which nothing during the loss can learn). Its
    square m² then adds to every lag: the slow part takes it in, and where m² ≥ C(1)/e
    C never falls to C(1)/e and τ is MISFIT_MAX_TAU_S."""
    r = np.asarray(err_mps, dtype=np.float64)
    if not keep_mean:
        r = r - float(np.mean(r))
    n = len(r)
    max_lag = min(int(MISFIT_MAX_TAU_S / dt_s) + 1, n // 3)
    if max_lag < 2:
        raise ValueError("too few samples for the misfit's statistics")
    c = np.array([float(np.dot(r[lag:], r[: n - lag])) / (n - lag) for lag in range(max_lag + 1)])
    c0, c1 = float(c[0]), float(c[1])
    if c1 <= 0.0:  # nothing correlated from one sample to the next: all white
        return LawMisfit(math.sqrt(c0), 0.0, dt_s)
    target = c1 / math.e
    below = np.nonzero(c[2:] < target)[0]
    if below.size == 0:
        tau = MISFIT_MAX_TAU_S
    else:
        lag = int(below[0]) + 2
        # C(lag − 1) ≥ target > C(lag): L_e between them
        frac = (float(c[lag - 1]) - target) / (float(c[lag - 1]) - float(c[lag]))
        tau = max(lag - 2 + frac, 1e-3) * dt_s
    slow2 = min(c1 * math.exp(dt_s / tau), c0)
    return LawMisfit(math.sqrt(c0 - slow2), math.sqrt(slow2), tau)


def as_flown_floor_model(oracle: FloorModel, misfit: LawMisfit) -> FloorModel:
    """The oracle's model (``ardupilot_floor_model``) with the drag's airspeed noise as
    measured on the flight: the misfit's white part for ε_u (it contains the quantisation
    and the white turbulence the oracle models) and its Gauss-Markov part as w."""
    return replace(
        oracle,
        drag_sigma_mps=misfit.white_sigma_mps,
        turbulence_sigma_mps=misfit.slow_sigma_mps,
        turbulence_time_constant_s=max(misfit.slow_tau_s, 1e-3),
    )


def causal_hand_over(m: FloorModel, known_slow_sigma_mps: float) -> FloatArray:
    """The causal floor's hand-over covariance: the healthy steady state of ``m``, with the
    part of the slow misfit w that the healthy filter could not have measured added as an
    independent unknown, P_ww += σ_w² − σ_known² (≥ 0). σ_known (``known_slow_sigma_mps``)
    is the as-flown misfit's slow σ, what a law fitted over the whole flight leaves and
    the healthy filter tracks; what a law fitted before the loss will be off by after it,
    in a regime it has not seen, no measurement before the loss tells. (Added, not
    substituted: P₀ only grows, so no σ after the loss shrinks.)"""
    p = np.array(steady_state(m, healthy=True), dtype=np.float64)
    p[2, 2] += max(m.turbulence_sigma_mps**2 - known_slow_sigma_mps**2, 0.0)
    return p
