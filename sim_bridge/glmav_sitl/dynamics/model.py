"""The GLMAV model of the paper's section 2, eqs (1)-(10), in NED / FRD.

Pure functions of plain floats (no numpy in the inner loop: one RK4 step at
dt = 1e-4 s is evaluated 40 000 times per simulated second).

State vector ``x`` (17 floats, SI):

====  =========================  ==========================================
index name                       meaning
====  =========================  ==========================================
0-2   p_ned_m                    position of G, earth NED
3-5   v_body_mps                 (u, v, w), velocity of G in body FRD
6-9   q                          (w, x, y, z), body-to-earth unit quaternion
10-12 omega_body_radps           (p, q, r), body rates FRD
13-14 rotor_radps                (Omega1 upper, Omega2 lower), >= 0
15-16 swash_rad                  (delta_cx, delta_cy), actual swash-plate tilt
====  =========================  ==========================================

Input ``u`` (4 floats): commanded rotor speeds (Omega1, Omega2) in rad/s and
commanded swash-plate angles (delta_cx, delta_cy) in rad; commands are clipped to
``[0, omega_max]`` and ``[-swash_limit, swash_limit]``; actual values follow with
first-order lags (motor and servo time constants).

Signs (derived in docs/model.md, tested in tests/unit/glmav_sitl):

- Rotor force, body FRD, eq. (5) with z flipped because thrust points along -z_b:
  ``F_r = (-beta W2^2 sin dcy cos dcx, -beta W2^2 sin dcx,
  -sigma (alpha W1^2 + beta W2^2 cos dcx cos dcy))``.
- The lower rotor force acts at the hub O2 = (0, 0, -d) (above G), so
  ``tau = r_O2 x F = (d F_y, -d F_x, 0)``, which is exactly eq. (10):
  ``L = -d beta sin dcx W2^2``, ``M = d beta sin dcy cos dcx W2^2``; yaw
  ``N = gamma1 W1^2 + gamma2 W2^2``.
- Air velocity at the body, eq. (6): ``V_tot = V_prop - v_body + V_wind_body``
  with the downwash ``V_prop = (0, 0, +v_dw)`` (down, +z_b) and
  ``v_dw = downwash_hover sqrt(T / (m g))`` (momentum theory, T the axial rotor
  thrust; zero when the rotors stop).
- Body aerodynamics, eqs (7)-(8): ``f_i = 1/2 rho S_i C_i [V_tot]_i |V_tot|``
  (the air pushes the body along the relative flow).
- Weight, eq. (9): ``m g R^T e_3 = m g (-s theta, c theta s phi, c theta c phi)``.
- Eq. (3): ``v_dot = F/m - omega x v``; eq. (4): ``I omega_dot = tau - omega x I omega``;
  eq. (1): ``p_dot = R v``; eq. (2) is integrated as ``q_dot = 1/2 q (0, omega)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from glmav_sitl.dynamics import rhs
from glmav_sitl.params import VehicleParams

I_POS, I_VEL, I_QUAT, I_RATE, I_ROTOR, I_SWASH = 0, 3, 6, 10, 13, 15

State = list[float]
# (dx, f_body): the state derivative and the specific force (F_total - weight)/m in FRD
Derivative = rhs.Derivative


@dataclass(frozen=True)
class ModelOptions:
    """Switches for tests: rotor forces/moments, body aerodynamics, gravity, actuator lags."""

    rotors: bool = True
    aerodynamics: bool = True
    gravity: bool = True


def coefficients(p: VehicleParams, options: ModelOptions | None) -> dict[str, Any]:
    """The constants of the right-hand side (``rhs.build``'s keyword arguments)."""
    opt = options or ModelOptions()
    return {
        "rotors_on": opt.rotors,
        "aero_on": opt.aerodynamics,
        "g": p.g if opt.gravity else 0.0,
        "inv_m": 1.0 / p.m,
        "sa": p.sigma * p.alpha,
        "sb": p.sigma * p.beta,
        "beta": p.beta,
        "d": p.d,
        "gam1": p.gamma1,
        "gam2": p.gamma2,
        "ixx": p.ixx,
        "iyy": p.iyy,
        "izz": p.izz,
        "kx": 0.5 * p.rho * p.side_area_m2 * p.cx,  # eq. (7), x: 1/2 rho (l D) Cx
        "ky": 0.5 * p.rho * p.side_area_m2 * p.cy,
        "kz": 0.5 * p.rho * p.top_area_m2 * p.cz,  # eq. (7), z: 1/2 rho (pi D^2/4) Cz
        "dw_gain": p.downwash_hover / math.sqrt(p.m * p.g),  # v_dw = dw_gain sqrt(T)
        "wmax": p.omega_max,
        "slim": p.swash_limit,
        "inv_tm": 1.0 / p.motor_time_constant,
        "inv_ts": 1.0 / p.swash_time_constant,
    }


def make_derivative(p: VehicleParams, options: ModelOptions | None = None) -> Derivative:
    """The right-hand side ``f(x, u, wind_ned_mps) -> (x_dot, f_body_mps2)`` of eqs (1)-(10).

    ``wind_ned_mps`` is the wind in earth axes (held constant over a step).
    ``f_body_mps2`` is what an ideal accelerometer at G measures (FRD).
    """
    f, _ = rhs.build(**coefficients(p, options))
    return f


Stepper = rhs.Stepper


def make_stepper(p: VehicleParams, options: ModelOptions | None = None) -> Stepper:
    """The fused RK4 step ``step(x, u, wind_ned_mps, h) -> x_next`` of the same equations.

    Identical in exact arithmetic to ``rk4_step(make_derivative(p), x, u, wind, h)``
    (tested to rounding); used by the simulator for speed.
    """
    _, step = rhs.build(**coefficients(p, options))
    return step


def rk4_step(
    f: Derivative, x: Sequence[float], u: Sequence[float], wind: Sequence[float], h: float
) -> State:
    """One classical Runge-Kutta 4 step of length ``h`` (s), inputs held; quaternion renormalised."""
    k1 = f(x, u, wind)[0]
    h2 = 0.5 * h
    x2 = [a + h2 * b for a, b in zip(x, k1, strict=True)]
    k2 = f(x2, u, wind)[0]
    x3 = [a + h2 * b for a, b in zip(x, k2, strict=True)]
    k3 = f(x3, u, wind)[0]
    x4 = [a + h * b for a, b in zip(x, k3, strict=True)]
    k4 = f(x4, u, wind)[0]
    h6 = h / 6.0
    out = [
        a + h6 * (b1 + 2.0 * (b2 + b3) + b4)
        for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4, strict=True)
    ]
    qw, qx, qy, qz = out[6], out[7], out[8], out[9]
    n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    out[6] = qw * n
    out[7] = qx * n
    out[8] = qy * n
    out[9] = qz * n
    return out


def trim_rotor_speeds(p: VehicleParams, options: ModelOptions | None = None) -> tuple[float, float]:
    """Rotor speeds (Omega1, Omega2) rad/s that hover: level, zero cyclic, no wind.

    Yaw balance fixes the ratio Omega1/Omega2 (eq. (10), N = 0), as in the nominal pair.
    The body sits in the downwash, whose download ``kz v_dw^2`` is proportional to the
    thrust T (v_dw^2 = downwash_hover^2 T / (m g)): the vertical balance of eqs (5)-(9)
    ``T - c T = m g`` gives ``T = m g / (1 - c)`` with ``c = kz downwash_hover^2 / (m g)``.
    """
    opt = options or ModelOptions()
    r2 = -p.gamma2 / p.gamma1  # Omega1^2 / Omega2^2 for N = 0
    c = 0.0
    if opt.aerodynamics:
        kz = 0.5 * p.rho * p.top_area_m2 * p.cz
        c = kz * p.downwash_hover**2 / (p.m * p.g)
    thrust = p.m * p.g / (1.0 - c)
    w2s = thrust / (p.sigma * (p.alpha * r2 + p.beta))
    return (math.sqrt(r2 * w2s), math.sqrt(w2s))


def initial_state(
    p_ned_m: Sequence[float] = (0.0, 0.0, 0.0),
    v_body_mps: Sequence[float] = (0.0, 0.0, 0.0),
    euler_rad: Sequence[float] = (0.0, 0.0, 0.0),
    omega_body_radps: Sequence[float] = (0.0, 0.0, 0.0),
    *,
    rotor_radps: Sequence[float] = (0.0, 0.0),
    swash_rad: Sequence[float] = (0.0, 0.0),
) -> State:
    """Assemble a state vector (see the module docstring) from Euler angles (ZYX)."""
    from glmav_sitl.dynamics.frames import quat_from_euler

    q = quat_from_euler(*euler_rad)
    return [
        *map(float, p_ned_m),
        *map(float, v_body_mps),
        *q,
        *map(float, omega_body_radps),
        *map(float, rotor_radps),
        *map(float, swash_rad),
    ]
