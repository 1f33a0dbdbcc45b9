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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from glmav_sitl.params import VehicleParams

N_STATE = 17
I_POS, I_VEL, I_QUAT, I_RATE, I_ROTOR, I_SWASH = 0, 3, 6, 10, 13, 15

State = list[float]
# (dx, f_body): the state derivative and the specific force (F_total - weight)/m in FRD
Derivative = Callable[
    [Sequence[float], Sequence[float], Sequence[float]], tuple[State, tuple[float, float, float]]
]


@dataclass(frozen=True)
class ModelOptions:
    """Switches for tests: rotor forces/moments, body aerodynamics, gravity, actuator lags."""

    rotors: bool = True
    aerodynamics: bool = True
    gravity: bool = True


# The right-hand side of eqs (1)-(10), written once as straight-line Python over scalar
# names: inputs X0..X16 (state), c1, c2, cx_, cy_ (clipped commands), wn, we, wd (wind,
# NED); outputs D0..D16 (state derivative) and sfx, sfy, sfz (specific force, FRD).
# It is compiled into the derivative ``f`` and, inlined four times, into the fused RK4
# step ``step`` (no lists inside the step: ~2x faster than calling ``f`` four times).
_RHS = """
vu = X3; vv = X4; vw = X5; qw = X6; qx = X7; qy = X8; qz = X9
wp = X10; wq = X11; wr = X12; W1 = X13; W2 = X14; dcx = X15; dcy = X16
# rotation body -> earth, R = E of eq. (13)
r11 = 1.0 - 2.0 * (qy * qy + qz * qz)
r12 = 2.0 * (qx * qy - qw * qz)
r13 = 2.0 * (qx * qz + qw * qy)
r21 = 2.0 * (qx * qy + qw * qz)
r22 = 1.0 - 2.0 * (qx * qx + qz * qz)
r23 = 2.0 * (qy * qz - qw * qx)
r31 = 2.0 * (qx * qz - qw * qy)
r32 = 2.0 * (qy * qz + qw * qx)
r33 = 1.0 - 2.0 * (qx * qx + qy * qy)
fx = fy = fz = 0.0
L = M = N = 0.0
t_axial = 0.0
if rotors_on:
    W1s = W1 * W1
    W2s = W2 * W2
    sx = sin(dcx)
    cxx = cos(dcx)
    sy = sin(dcy)
    cyy = cos(dcy)
    b2 = beta * W2s
    # eq. (5) in FRD (thrust along -z_b)
    frx = -b2 * sy * cxx
    fry = -b2 * sx
    t_axial = sa * W1s + sb * W2s * cxx * cyy
    fx = frx
    fy = fry
    fz = -t_axial
    # eq. (10): r_O2 x F with r_O2 = (0, 0, -d)
    L = d * fry
    M = -d * frx
    N = gam1 * W1s + gam2 * W2s
if aero_on:
    # wind in body axes R^T w; eq. (6): V_tot = V_prop - V_body + V_wind
    vprop = dw_gain * sqrt(t_axial) if t_axial > 0.0 else 0.0
    ax_ = r11 * wn + r21 * we + r31 * wd - vu
    ay_ = r12 * wn + r22 * we + r32 * wd - vv
    az_ = r13 * wn + r23 * we + r33 * wd + vprop - vw
    nrm = sqrt(ax_ * ax_ + ay_ * ay_ + az_ * az_)
    # eqs (7)-(8): signed quadratic drag
    fx += kx * ax_ * nrm
    fy += ky * ay_ * nrm
    fz += kz * az_ * nrm
sfx = fx * inv_m
sfy = fy * inv_m
sfz = fz * inv_m
# eq. (1): p_dot = R v
D0 = r11 * vu + r12 * vv + r13 * vw
D1 = r21 * vu + r22 * vv + r23 * vw
D2 = r31 * vu + r32 * vv + r33 * vw
# eq. (3) with weight (9): v_dot = F/m + g R^T e3 - omega x v
D3 = sfx + g * r31 - (wq * vw - wr * vv)
D4 = sfy + g * r32 - (wr * vu - wp * vw)
D5 = sfz + g * r33 - (wp * vv - wq * vu)
# attitude kinematics (eq. (2) in quaternion form): q_dot = 1/2 q (0, omega)
D6 = 0.5 * (-qx * wp - qy * wq - qz * wr)
D7 = 0.5 * (qw * wp + qy * wr - qz * wq)
D8 = 0.5 * (qw * wq - qx * wr + qz * wp)
D9 = 0.5 * (qw * wr + qx * wq - qy * wp)
# eq. (4): I omega_dot = tau - omega x (I omega)
D10 = (L - (wq * izz * wr - wr * iyy * wq)) / ixx
D11 = (M - (wr * ixx * wp - wp * izz * wr)) / iyy
D12 = (N - (wp * iyy * wq - wq * ixx * wp)) / izz
# actuator lags
D13 = (c1 - W1) * inv_tm
D14 = (c2 - W2) * inv_tm
D15 = (cx_ - dcx) * inv_ts
D16 = (cy_ - dcy) * inv_ts
"""

_CLIP = """
c1 = u[0]
c1 = 0.0 if c1 < 0.0 else (wmax if c1 > wmax else c1)
c2 = u[1]
c2 = 0.0 if c2 < 0.0 else (wmax if c2 > wmax else c2)
cx_ = u[2]
cx_ = -slim if cx_ < -slim else (slim if cx_ > slim else cx_)
cy_ = u[3]
cy_ = -slim if cy_ < -slim else (slim if cy_ > slim else cy_)
wn = wind[0]
we = wind[1]
wd = wind[2]
"""


def _indent(code: str) -> str:
    return "\n".join("    " + ln if ln.strip() else ln for ln in code.strip("\n").split("\n"))


def _source() -> str:
    """Python source of ``f(x, u, wind)`` and ``step(x, u, wind, h)`` from :data:`_RHS`."""
    n = N_STATE
    xs = ", ".join(f"X{i}" for i in range(n))
    ds = ", ".join(f"D{i}" for i in range(n))
    f_src = (
        "def f(x, u, wind):\n"
        + _indent(_CLIP)
        + f"\n    {xs} = x\n"
        + _indent(_RHS)
        + f"\n    return [{ds}], (sfx, sfy, sfz)\n"
    )
    body = [_CLIP, f"x0_ = x\n{xs} = x", "h2 = 0.5 * h"]
    for k, coef in (("k1", "h2"), ("k2", "h2"), ("k3", "h"), ("k4", "")):
        body.append(_RHS)
        body.append("\n".join(f"{k}_{i} = D{i}" for i in range(n)))
        if coef:
            body.append("\n".join(f"X{i} = x0_[{i}] + {coef} * D{i}" for i in range(n)))
    body.append("h6 = h / 6.0")
    body.append(
        "\n".join(
            f"o{i} = x0_[{i}] + h6 * (k1_{i} + 2.0 * (k2_{i} + k3_{i}) + k4_{i})" for i in range(n)
        )
    )
    body.append(
        "nq = 1.0 / sqrt(o6 * o6 + o7 * o7 + o8 * o8 + o9 * o9)\n"
        "o6 *= nq\no7 *= nq\no8 *= nq\no9 *= nq"
    )
    body.append("return [" + ", ".join(f"o{i}" for i in range(n)) + "]")
    step_src = "def step(x, u, wind, h):\n" + "\n".join(_indent(b) for b in body) + "\n"
    return f_src + "\n\n" + step_src


def _compile(p: VehicleParams, options: ModelOptions | None) -> dict[str, Any]:
    opt = options or ModelOptions()
    ns: dict[str, Any] = {
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
        "sqrt": math.sqrt,
        "sin": math.sin,
        "cos": math.cos,
    }
    exec(compile(_source(), "<glmav_sitl.dynamics.model._RHS>", "exec"), ns)
    return ns


def make_derivative(p: VehicleParams, options: ModelOptions | None = None) -> Derivative:
    """The right-hand side ``f(x, u, wind_ned_mps) -> (x_dot, f_body_mps2)`` of eqs (1)-(10).

    ``wind_ned_mps`` is the wind in earth axes (held constant over a step).
    ``f_body_mps2`` is what an ideal accelerometer at G measures (FRD).
    """
    f: Derivative = _compile(p, options)["f"]
    return f


Stepper = Callable[[Sequence[float], Sequence[float], Sequence[float], float], State]


def make_stepper(p: VehicleParams, options: ModelOptions | None = None) -> Stepper:
    """The fused RK4 step ``step(x, u, wind_ned_mps, h) -> x_next`` of the same equations.

    Identical in exact arithmetic to ``rk4_step(make_derivative(p), x, u, wind, h)``
    (tested to rounding); used by the simulator for speed.
    """
    step: Stepper = _compile(p, options)["step"]
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
