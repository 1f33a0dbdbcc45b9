"""Physics of the GLMAV model (paper eqs (1)-(10)) in NED/FRD: signs, trim, invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest

from glmav_sitl.dynamics.frames import (
    euler_from_quat,
    euler_matrix,
    quat_from_euler,
    rotation_from_quat,
)
from glmav_sitl.dynamics.model import (
    ModelOptions,
    coefficients,
    initial_state,
    make_derivative,
    make_stepper,
    rk4_step,
    trim_rotor_speeds,
)
from glmav_sitl.params import VehicleParams, load_vehicle_params

P = load_vehicle_params()
NO_WIND = (0.0, 0.0, 0.0)


def _fly(
    p: VehicleParams,
    x: list[float],
    u: list[float],
    t_s: float,
    h: float,
    *,
    opt: ModelOptions | None = None,
) -> list[float]:
    f = make_derivative(p, opt)
    for _ in range(round(t_s / h)):
        x = rk4_step(f, x, u, NO_WIND, h)
    return x


def test_rotation_matches_paper_eq13_and_euler_round_trip() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        phi, psi = rng.uniform(-3.0, 3.0, 2)
        theta = rng.uniform(-1.5, 1.5)
        q = quat_from_euler(phi, theta, psi)
        # both are the same rotation: agree to float rounding
        assert np.allclose(rotation_from_quat(*q), euler_matrix(phi, theta, psi), atol=1e-12)
        assert np.allclose(euler_from_quat(*q), (phi, theta, psi), atol=1e-9)


def test_trim_hovers_exactly_and_nominal_speeds_balance_weight() -> None:
    # design.md: sigma*(alpha*190^2 + beta*200^2) = 1.963 N ~ m g = 1.962 N (0.1 % rounding)
    t_nominal = P.sigma * (P.alpha * P.omega1_nominal**2 + P.beta * P.omega2_nominal**2)
    assert t_nominal == pytest.approx(P.m * P.g, rel=1e-3)
    # yaw balance of eq. (10) at the nominal pair: 0.0361 - 0.0361 N m
    assert P.gamma1 * P.omega1_nominal**2 + P.gamma2 * P.omega2_nominal**2 == pytest.approx(
        0.0, abs=1e-9
    )
    w1, w2 = trim_rotor_speeds(P)
    f = make_derivative(P)
    x = initial_state((0, 0, -10), rotor_radps=(w1, w2))
    dx, f_body = f(x, [w1, w2, 0.0, 0.0], NO_WIND)
    # every acceleration vanishes to rounding (1e-12 m/s^2 on ~10 m/s^2 terms)
    assert max(abs(a) for a in dx[3:6]) < 1e-12
    assert max(abs(a) for a in dx[10:13]) < 1e-10  # N/Izz: 0.0361 N m terms / 2e-4 -> 1e-10
    # the accelerometer at hover reads (0, 0, -g) in FRD
    assert f_body == pytest.approx((0.0, 0.0, -P.g), abs=1e-12)
    # with aerodynamics off the trim is the nominal pair to the 0.1 % rounding of design.md
    w1n, w2n = trim_rotor_speeds(P, ModelOptions(aerodynamics=False))
    assert w1n == pytest.approx(190.0, rel=1e-3) and w2n == pytest.approx(200.0, rel=1e-3)


def test_hover_at_trim_holds_altitude_60s_open_loop() -> None:
    w1, w2 = trim_rotor_speeds(P)
    x = initial_state((0, 0, -10), rotor_radps=(w1, w2))
    x = _fly(P, x, [w1, w2, 0.0, 0.0], 60.0, 1e-3)
    # issue: within 0.1 m for 60 s with no noise
    assert abs(x[2] + 10.0) < 0.1
    assert math.hypot(x[0], x[1]) < 0.1


def test_free_fall_gives_g_at_any_attitude() -> None:
    opt = ModelOptions(rotors=False, aerodynamics=False)
    x = initial_state((0, 0, 0), (1.0, -2.0, 0.5), (0.4, -0.3, 1.0), (0.3, -0.2, 0.5))
    v0 = rotation_from_quat(*x[6:10]) @ np.array(x[3:6])
    t = 2.0
    x1 = _fly(P, x, [0.0, 0.0, 0.0, 0.0], t, 1e-3, opt=opt)
    v1 = rotation_from_quat(*x1[6:10]) @ np.array(x1[3:6])
    # NED velocity gains g t downwards; RK4 is exact for this polynomial motion up to rounding
    assert np.allclose(v1 - v0, [0.0, 0.0, P.g * t], atol=1e-9)
    p1 = np.array(x1[0:3])
    assert np.allclose(p1, v0 * t + [0.0, 0.0, 0.5 * P.g * t * t], atol=1e-8)
    # the accelerometer of a falling body reads zero
    f = make_derivative(P, opt)
    assert f(x1, [0.0] * 4, NO_WIND)[1] == (0.0, 0.0, 0.0)


def test_torque_free_body_conserves_energy_and_momentum() -> None:
    p = P.replace(iyy=1.6e-3)  # asymmetric inertia so that the motion is not trivial
    opt = ModelOptions(rotors=False, aerodynamics=False, gravity=False)
    inertia = np.diag([p.ixx, p.iyy, p.izz])
    x = initial_state(euler_rad=(0.2, 0.1, -0.3), omega_body_radps=(2.0, -1.0, 8.0))

    def invariants(s: list[float]) -> tuple[float, np.ndarray]:
        w = np.array(s[10:13])
        return 0.5 * w @ inertia @ w, rotation_from_quat(*s[6:10]) @ (inertia @ w)

    e0, h0 = invariants(x)
    x1 = _fly(p, x, [0.0] * 4, 10.0, 1e-4, opt=opt)
    e1, h1 = invariants(x1)
    # issue: 1e-6 relative over 10 s at dt = 1e-4 (RK4 local error ~ (|w| dt)^5 per step)
    assert abs(e1 - e0) / e0 < 1e-6
    assert np.linalg.norm(h1 - h0) / np.linalg.norm(h0) < 1e-6
    # and the rates did change (the body tumbles): the test is not vacuous
    assert abs(x1[10] - 2.0) > 1e-2


def test_rotor_forces_and_moments_match_eqs_5_and_10_in_frd() -> None:
    f = make_derivative(P, ModelOptions(aerodynamics=False, gravity=False))
    w1, w2, dcx, dcy = 180.0, 210.0, 0.1, -0.2
    x = initial_state(rotor_radps=(w1, w2), swash_rad=(dcx, dcy))
    dx, sf = f(x, [w1, w2, dcx, dcy], NO_WIND)
    b2 = P.beta * w2**2
    force = np.array(sf) * P.m
    expected_force = [
        -b2 * math.sin(dcy) * math.cos(dcx),  # eq. (5) x
        -b2 * math.sin(dcx),  # eq. (5) y
        -P.sigma * (P.alpha * w1**2 + b2 * math.cos(dcx) * math.cos(dcy)),  # eq. (5) z, FRD: up
    ]
    assert np.allclose(force, expected_force, rtol=1e-12)
    moments = np.array(dx[10:13]) * [P.ixx, P.iyy, P.izz]
    expected_moments = [
        -P.d * b2 * math.sin(dcx),  # eq. (10) L
        P.d * b2 * math.sin(dcy) * math.cos(dcx),  # eq. (10) M
        P.gamma1 * w1**2 + P.gamma2 * w2**2,  # eq. (10) N
    ]
    assert np.allclose(moments, expected_moments, rtol=1e-12)


@pytest.mark.parametrize(("axis", "sign"), [("cx", 1.0), ("cx", -1.0), ("cy", 1.0), ("cy", -1.0)])
def test_positive_cyclic_gives_moment_and_acceleration_in_the_same_sense(
    axis: str, sign: float
) -> None:
    """+dcy pitches nose up (M > 0) and pushes backwards (-x); the pitch-up tilts the
    main thrust backwards too: both effects move the vehicle the same way (north < 0).
    +dcx rolls left (L < 0) and pushes left (-y): both move it west."""
    w1, w2 = trim_rotor_speeds(P)
    delta = 0.1 * sign
    u = [w1, w2, delta, 0.0] if axis == "cx" else [w1, w2, 0.0, delta]
    x0 = initial_state((0, 0, -10), rotor_radps=(w1, w2))
    f = make_derivative(P)
    x = x0
    for _ in range(50):  # 5 ms: the swash servo (10 ms) is moving, the attitude barely
        x = rk4_step(f, x, u, NO_WIND, 1e-4)
    dx, _ = f(x, u, NO_WIND)
    i_rate, i_acc = (10, 1) if axis == "cx" else (11, 0)
    # direct effect: angular acceleration and horizontal (NED) acceleration
    a_ned = rotation_from_quat(*x[6:10]) @ np.array(dx[3:6])
    if axis == "cx":
        assert dx[i_rate] * sign < 0.0 and a_ned[i_acc] * sign < 0.0  # L < 0, east accel < 0
    else:
        assert dx[i_rate + 0] * sign > 0.0 and a_ned[i_acc] * sign < 0.0  # M > 0, north accel < 0
    # after 0.3 s the attitude has turned and the vehicle moves the same way, faster
    x = x0
    for _ in range(300):
        x = rk4_step(f, x, u, NO_WIND, 1e-3)
    phi, theta, _ = euler_from_quat(*x[6:10])
    v_ned = rotation_from_quat(*x[6:10]) @ np.array(x[3:6])
    if axis == "cx":
        assert phi * sign < -0.05 and v_ned[1] * sign < -0.05
    else:
        assert theta * sign > 0.05 and v_ned[0] * sign < -0.05


def test_body_drag_opposes_motion_and_follows_the_wind() -> None:
    opt = ModelOptions(rotors=False, gravity=False)
    f = make_derivative(P, opt)
    x = initial_state(v_body_mps=(5.0, 0.0, 0.0))
    dx, _ = f(x, [0.0] * 4, NO_WIND)
    # eqs (6)-(8): f_x = 1/2 rho (l D) Cx (-u) |u| = -0.3675 N -> -1.8375 m/s^2
    assert dx[3] == pytest.approx(-0.5 * P.rho * P.side_area_m2 * P.cx * 25.0 / P.m, rel=1e-12)
    # a wind blowing towards the north pushes a body at rest northwards; heading east
    # (psi = +pi/2) north is -y_b, so the force is along -y_b
    x = initial_state(euler_rad=(0.0, 0.0, math.pi / 2))
    dx, _ = f(x, [0.0] * 4, (3.0, 0.0, 0.0))
    assert dx[4] < 0.0 and abs(dx[3]) < 1e-12
    # the downwash loads the body downwards (+z) in hover
    w1, w2 = trim_rotor_speeds(P)
    x = initial_state(rotor_radps=(w1, w2))
    f_aero = make_derivative(P, ModelOptions(gravity=False))
    f_noaero = make_derivative(P, ModelOptions(gravity=False, aerodynamics=False))
    download = f_aero(x, [w1, w2, 0, 0], NO_WIND)[1][2] - f_noaero(x, [w1, w2, 0, 0], NO_WIND)[1][2]
    kz = 0.5 * P.rho * P.top_area_m2 * P.cz
    thrust = P.m * P.g / (1 - kz * P.downwash_hover**2 / (P.m * P.g))
    v_dw2 = P.downwash_hover**2 * thrust / (P.m * P.g)
    assert download == pytest.approx(kz * v_dw2 / P.m, rel=1e-9)


def test_rk4_step_size_convergence() -> None:
    """A manoeuvre (cyclic and differential rotor input from hover) at dt = 1e-3 s agrees
    with dt = 1e-4 s to well under the sensor noise (0.05 m/s, 0.005 rad)."""
    w1, w2 = trim_rotor_speeds(P)
    x0 = initial_state((0, 0, -10), (1.0, 0.5, 0.0), (0.1, -0.1, 0.0), rotor_radps=(w1, w2))
    u = [w1 * 1.03, w2 * 0.98, 0.05, -0.04]
    xa = _fly(P, x0, u, 1.0, 1e-3)
    xb = _fly(P, x0, u, 1.0, 1e-4)
    dv = max(abs(a - b) for a, b in zip(xa[3:6], xb[3:6], strict=True))
    dq = max(abs(a - b) for a, b in zip(xa[6:10], xb[6:10], strict=True))
    assert dv < 1e-6 and dq < 1e-6


@pytest.mark.parametrize(
    "opt",
    [ModelOptions(), ModelOptions(rotors=False), ModelOptions(aerodynamics=False, gravity=False)],
)
def test_fused_stepper_equals_rk4_of_the_derivative(opt: ModelOptions) -> None:
    f = make_derivative(P, opt)
    step = make_stepper(P, opt)
    x = initial_state(
        (1, 2, -3),
        (2.0, -1.0, 0.5),
        (0.3, -0.2, 1.0),
        (0.4, -0.3, 0.2),
        rotor_radps=(180.0, 210.0),
        swash_rad=(0.05, -0.1),
    )
    u = [400.0, 150.0, 0.5, -0.1]  # includes commands beyond the limits (clipped)
    wind = (1.0, -2.0, 0.3)
    for _ in range(20):
        a = rk4_step(f, x, u, wind, 1e-3)
        b = step(x, u, wind, 1e-3)
        assert a == b  # same operations in the same order: bit-identical
        x = b


def test_checked_in_rhs_is_the_generators_output() -> None:
    """rhs.py is generated (ruff and mypy check it as written): after an edit of the
    template in codegen.py, ``python -m glmav_sitl.dynamics.codegen`` must be rerun."""
    from glmav_sitl.dynamics import codegen

    assert codegen.TARGET.read_text(encoding="utf-8") == codegen.module_source()
    assert codegen.main(["--check"]) == 0
    names = [name for name, _ in codegen.COEFFICIENTS]
    assert sorted(names) == sorted(coefficients(P, None)), "rhs.build's arguments"
