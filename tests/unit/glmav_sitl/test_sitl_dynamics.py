"""Physics of the GLMAV model (paper eqs (1)-(10)) in NED/FRD: signs, trim, invariants."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

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
    make_rhs,
    make_stepper,
    rk4_step,
    trim_rotor_speeds,
)
from glmav_sitl.params import VehicleParams, load_vehicle_params

P = load_vehicle_params()
NO_WIND = (0.0, 0.0, 0.0)
Vec3 = tuple[float, float, float]


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
    """rhs.pyx (compiled) and rhs.pyi (what mypy reads) are generated: after an edit of
    the template in codegen.py, ``python -m glmav_sitl.dynamics.codegen`` must be rerun
    (and ``pip install -e .`` to compile it)."""
    from glmav_sitl.dynamics import codegen

    assert codegen.TARGET.name == "rhs.pyx"
    assert codegen.TARGET.read_text(encoding="utf-8") == codegen.module_source()
    assert codegen.STUB_TARGET.read_text(encoding="utf-8") == codegen.stub_source()
    assert codegen.main(["--check"]) == 0
    names = [name for name, _ in codegen.COEFFICIENTS]
    assert sorted(names) == sorted(coefficients(P, None)), "rhs.Rhs's arguments"
    # the module that runs is the compiled one, and it has no Python copy beside it
    import glmav_sitl.dynamics.rhs as rhs_module

    assert Path(rhs_module.__file__ or "").suffix in {".so", ".pyd"}
    assert not codegen.TARGET.with_suffix(".py").exists()


def _template_derivative(
    coef: dict[str, Any],
) -> Callable[[Sequence[float], Sequence[float], Sequence[float]], tuple[list[float], Vec3]]:
    """The oracle: the template's equations (codegen.CLIP + codegen.RHS) run by Python."""
    from glmav_sitl.dynamics import codegen

    body = "\n".join(
        [
            codegen.CLIP,
            *(f"X{i} = x[{i}]" for i in range(codegen.N_STATE)),
            codegen.RHS,
            "out = ([" + ", ".join(f"D{i}" for i in range(codegen.N_STATE)) + "], (sfx, sfy, sfz))",
        ]
    )
    code = compile(body, "<template>", "exec")

    def f(
        x: Sequence[float], u: Sequence[float], wind: Sequence[float]
    ) -> tuple[list[float], Vec3]:
        ns: dict[str, Any] = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt, **coef}
        ns.update(x=x, u=u, wind=wind)
        exec(code, ns)
        out: tuple[list[float], Vec3] = ns["out"]
        return out

    return f


OPTIONS = [
    ModelOptions(),
    ModelOptions(rotors=False),
    ModelOptions(aerodynamics=False),
    ModelOptions(aerodynamics=False, gravity=False),
]


@pytest.mark.parametrize("opt", OPTIONS)
def test_compiled_rhs_equals_the_templates_equations(opt: ModelOptions) -> None:
    """The compiled derivative against the template evaluated by CPython, on random
    states, commands (some beyond the limits: clipped) and winds. Every operation is
    the template's in its order in C doubles without fused multiply-add, and sin, cos,
    sqrt are the same libm calls, so the two agree to the last bit; the bound asked is
    1e-12 relative (a few roundings of ~1e3-sized terms would already be ~1e-13)."""
    f = make_derivative(P, opt)
    ref = _template_derivative(coefficients(P, opt))
    rng = np.random.default_rng(7)
    for _ in range(200):
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        x = [
            *rng.uniform(-50.0, 50.0, 3),
            *rng.uniform(-10.0, 10.0, 3),
            *q,
            *rng.uniform(-3.0, 3.0, 3),
            *rng.uniform(0.0, 300.0, 2),
            *rng.uniform(-0.3, 0.3, 2),
        ]
        x = [float(v) for v in x]
        u = [float(v) for v in (*rng.uniform(-50.0, 500.0, 2), *rng.uniform(-0.5, 0.5, 2))]
        wind = tuple(float(v) for v in rng.uniform(-8.0, 8.0, 3))
        dx, sf = f(x, u, wind)
        dx_ref, sf_ref = ref(x, u, wind)
        assert len(dx) == 17
        for a, b in zip([*dx, *sf], [*dx_ref, *sf_ref], strict=True):
            assert abs(a - b) <= 1e-12 * max(1.0, abs(b))


def test_compiled_rk4_against_an_adaptive_integrator() -> None:
    """1 s of a manoeuvre (cyclic and differential input from a tilted, moving hover,
    with wind) stepped by the compiled RK4 at the default dt = 1e-3 s, against scipy's
    DOP853 at rtol = atol = 1e-12 on the template's equations. RK4's global error is
    O(h^4): test_rk4_step_size_convergence bounds it below 1e-6 in v and q at 1e-3 s."""
    from scipy.integrate import solve_ivp

    opt = ModelOptions()
    ref = _template_derivative(coefficients(P, opt))
    step = make_stepper(P, opt)
    w1, w2 = trim_rotor_speeds(P)
    x0 = initial_state((0, 0, -10), (1.0, 0.5, 0.0), (0.1, -0.1, 0.3), rotor_radps=(w1, w2))
    u = [w1 * 1.03, w2 * 0.98, 0.05, -0.04]
    wind = (2.0, -1.0, 0.2)
    x = list(x0)
    for _ in range(1000):
        x = step(x, u, wind, 1e-3)
    sol = solve_ivp(
        lambda _t, y: ref(list(y), u, wind)[0],
        (0.0, 1.0),
        x0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
    )
    y = sol.y[:, -1]
    assert sol.success
    assert max(abs(a - b) for a, b in zip(x[3:6], y[3:6], strict=True)) < 1e-6  # m/s
    assert max(abs(a - b) for a, b in zip(x[6:10], y[6:10], strict=True)) < 1e-6  # quaternion
    assert max(abs(a - b) for a, b in zip(x[0:3], y[0:3], strict=True)) < 1e-6  # m
    # and it moved: the comparison is not of two resting states
    assert math.dist(x[0:3], x0[0:3]) > 0.5


def test_step_into_equals_repeated_steps() -> None:
    """``step_into`` (n steps in place, one call) is the same arithmetic as n ``step``s."""
    rhs = make_rhs(P)
    w1, w2 = trim_rotor_speeds(P)
    x = initial_state((0, 0, -10), (1.0, 0.5, 0.0), (0.1, -0.1, 0.3), rotor_radps=(w1, w2))
    u = [w1 * 1.01, w2, 0.02, -0.01]
    wind = (1.0, 0.0, 0.0)
    a = list(x)
    for _ in range(7):
        a = rhs.step(a, u, wind, 1e-3)
    b = list(x)
    rhs.step_into(b, u, wind, 1e-3, 7)
    assert a == b
    with pytest.raises(ValueError, match="17 floats"):
        rhs.step(x[:16], u, wind, 1e-3)
