"""The observer's pure functions: kinematics, gains, and the exact ZOH update of (16)."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from glmav_observer.commands.check import exact_kinematics_scenario
from glmav_observer.configurations import CONFIG_MASKS, output_matrix
from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.observer import (
    G_MPS2,
    NonFiniteInputError,
    a_matrix,
    e_small_angle,
    gamma_body_mps2,
    gravity_body_mps2,
    observer_gains,
    observer_rhs,
    phi1_phi2,
    phi1_phi2_scalar,
    zoh_step,
)
from glmav_observer.frames import ShapeError, e_exact

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
angles = arrays(np.float64, 3, elements=st.floats(-np.pi, np.pi))
rates = arrays(np.float64, 3, elements=st.floats(-3.0, 3.0))
vec = arrays(np.float64, 3, elements=st.floats(-20.0, 20.0))
masks = arrays(np.bool_, 3)

ROWS_OF_MASK = {"full": (True, True, True), "c1": (True, True, False)}


def _c_of_mask(mask: np.ndarray) -> np.ndarray:
    return np.eye(3)[np.flatnonzero(mask)]


def _rk4_held(N: np.ndarray, b: np.ndarray, x0: np.ndarray, dt: float, n: int) -> np.ndarray:
    """RK4 of ẋ = N x + b (held), n substeps; batched over leading dims of N, b, x0."""
    h = dt / n
    x = x0.copy()

    def f(x: np.ndarray) -> np.ndarray:
        return np.einsum("...ij,...j->...i", N, x) + b

    for _ in range(n):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def _held_system(  # noqa: PLR0917 -- the held inputs in zoh_step order
    omega: np.ndarray, Gam: np.ndarray, E: np.ndarray, y: np.ndarray, mask: np.ndarray, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """(16) with held inputs as ẋ = N x + b via observer_gains: N = A − K Q, b = Γ + K y."""
    if not mask.any():
        return a_matrix(omega), Gam
    C = _c_of_mask(mask)
    g = observer_gains(E, C, gamma, omega)
    return g.N, Gam + g.K @ (C @ y)


# ----------------------------------------------------------------------------- kinematics


@given(angles)
def test_e_exact_is_a_rotation(euler: np.ndarray) -> None:
    E = e_exact(euler)
    # orthogonal with det +1 to rounding (9 products of unit-size terms: 1e-15 scale)
    assert np.abs(E @ E.T - np.eye(3)).max() < 1e-14
    assert abs(np.linalg.det(E) - 1.0) < 1e-14


def test_e_exact_conventions_zyx_body_to_ned() -> None:
    # yaw 90°: body x (forward) points east; pitch +30°: forward points up (−down)
    E = e_exact([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(E @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    E = e_exact([0.0, np.pi / 6, 0.0])
    np.testing.assert_allclose(E @ [1.0, 0.0, 0.0], [np.cos(np.pi / 6), 0.0, -0.5], atol=1e-15)
    # roll +90°: body y (right) points down
    E = e_exact([np.pi / 2, 0.0, 0.0])
    np.testing.assert_allclose(E @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], atol=1e-15)


def test_small_angle_e_is_first_order_and_second_order_off_diagonal() -> None:
    """(15) = (13) + O(s²); the O(s²) part is exactly the diagonal −(·)²/2 terms (15) drops.

    The off-diagonal entries of (15) agree with (13) to second order (error O(s³)); the
    diagonal of (13) has 1 − (θ²+ψ²)/2, 1 − (φ²+ψ²)/2, 1 − (φ²+θ²)/2 where (15) keeps 1.
    """
    direction = np.array([0.7, -0.4, 0.55])
    scales = np.array([0.2, 0.1, 0.05, 0.025])
    err_total, err_rest = [], []
    for s in scales:
        phi, th, psi = s * direction
        d2 = np.diag([-(th**2 + psi**2) / 2, -(phi**2 + psi**2) / 2, -(phi**2 + th**2) / 2])
        diff = e_exact(s * direction) - e_small_angle(s * direction)
        err_total.append(np.abs(diff).max())
        err_rest.append(np.abs(diff - d2).max())
    order_total = np.polyfit(np.log(scales), np.log(err_total), 1)[0]
    order_rest = np.polyfit(np.log(scales), np.log(err_rest), 1)[0]
    assert abs(order_total - 2.0) < 0.05  # the difference is second order ...
    assert abs(order_rest - 3.0) < 0.1  # ... and, without the diagonal terms, third order
    # at the assumption-1 bound (0.18 rad) the dropped terms are ~3 % of the entries
    assert 0.01 < err_total[0] < 0.05


def test_small_angle_e_is_not_orthogonal() -> None:
    E = e_small_angle([0.18, 0.18, 0.18])
    assert np.abs(E @ E.T - np.eye(3)).max() > 1e-2


def test_rest_and_level_accelerometer_reads_minus_g_and_gamma_is_zero() -> None:
    euler = np.zeros(3)
    g_body = gravity_body_mps2(euler)
    np.testing.assert_array_equal(g_body, [0.0, 0.0, G_MPS2])  # weight points down (+z FRD)
    f_rest = -g_body  # at rest the accelerometer measures −(weight)/m
    np.testing.assert_array_equal(f_rest, [0.0, 0.0, -G_MPS2])
    np.testing.assert_array_equal(gamma_body_mps2(f_rest, euler), [0.0, 0.0, 0.0])


@given(angles)
def test_gravity_body_is_et_times_down(euler: np.ndarray) -> None:
    # (9)/m equals Eᵀ (0, 0, g) for the exact E; at rest, Γ = 0 at any attitude
    np.testing.assert_allclose(
        gravity_body_mps2(euler), e_exact(euler).T @ [0, 0, G_MPS2], atol=1e-13
    )
    f_rest = e_exact(euler).T @ [0.0, 0.0, -G_MPS2]
    assert np.abs(gamma_body_mps2(f_rest, euler)).max() < 1e-13


@given(rates, vec)
def test_a_matrix_is_minus_cross(omega: np.ndarray, x: np.ndarray) -> None:
    np.testing.assert_allclose(a_matrix(omega) @ x, -np.cross(omega, x), atol=1e-12)
    np.testing.assert_array_equal(
        a_matrix([1.0, 2.0, 3.0]), [[0, 3, -2], [-3, 0, 1], [2, -1, 0]]
    )  # (11) with p, q, r = 1, 2, 3


# ----------------------------------------------------------------------------- gains


@given(angles, rates, st.sampled_from(["c1", "c2", "c3", "full"]))
def test_gains_exact_e(euler: np.ndarray, omega: np.ndarray, config: str) -> None:
    E = e_exact(euler)
    C = output_matrix(config)
    g = observer_gains(E, C, 90.0, omega)
    np.testing.assert_allclose(g.Q_pinv, g.Q.T, atol=1e-13)  # QQᵀ = I ⇒ Q⁺ = Qᵀ
    P = g.Q.T @ g.Q
    np.testing.assert_allclose(P, E.T @ (C.T @ C) @ E, atol=1e-13)  # P = Eᵀ D E
    np.testing.assert_allclose(P @ P, P, atol=1e-13)  # a projector
    np.testing.assert_allclose(g.K, a_matrix(omega) @ g.Q.T + 90.0 * E.T @ C.T, atol=1e-12)
    np.testing.assert_allclose(g.N, a_matrix(omega) - g.K @ g.Q, atol=1e-12)


def test_gains_small_angle_pinv_is_not_transpose() -> None:
    E = e_small_angle([0.15, -0.1, 0.17])
    g = observer_gains(E, output_matrix("c1"), 90.0, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(g.Q @ g.Q_pinv, np.eye(2), atol=1e-13)  # right inverse (23)
    assert np.abs(g.Q_pinv - g.Q.T).max() > 1e-3


@given(angles, rates, vec, vec, vec)
def test_rhs_is_a_x_plus_gamma_plus_k_innovation(
    euler: np.ndarray, omega: np.ndarray, x: np.ndarray, Gam: np.ndarray, v_ned: np.ndarray
) -> None:
    E = e_exact(euler)
    C = output_matrix("c2")
    y = C @ v_ned
    g = observer_gains(E, C, 70.0, omega)
    expected = a_matrix(omega) @ x + Gam + g.K @ (y - g.Q @ x)  # (16)
    got = observer_rhs(x, omega, Gam, E, C, 70.0, y)
    np.testing.assert_allclose(got, expected, atol=1e-10)
    np.testing.assert_allclose(got, g.N @ x + Gam + g.K @ y, atol=1e-9)  # (17) form


# ----------------------------------------------------------------------------- φ-functions


def _phi2_reference(x: float) -> float:
    if abs(x) >= 1.0:
        return (np.expm1(x) - x) / (x * x)
    xf = Fraction(x)
    return float(sum(xf**k / math.factorial(k + 2) for k in range(40)))


def test_phi_functions_continuous_and_exact() -> None:
    x = np.array([0.0, -1e-12, -1e-3, -0.0999999, -0.1, -0.5, -9.0, -900.0])
    p1, p2 = phi1_phi2(x)
    ref1 = np.array([1.0] + [np.expm1(v) / v for v in x[1:]])
    # φ2 reference: the exact rational Taylor sum (40 terms) for |x| < 1, closed form above
    ref2 = np.array([_phi2_reference(float(v)) for v in x])
    np.testing.assert_allclose(p1, ref1, rtol=1e-14)
    # 9-term series below |x| = 0.1 (truncation < 0.1⁹/11! ≈ 3e-17) and (φ1 − 1)/x above
    # (cancellation ≤ eps/|x·φ2| ≈ 2e-15 at |x| = 0.1)
    np.testing.assert_allclose(p2, ref2, rtol=1e-14)
    for v, a, b in zip(x, p1, p2, strict=True):
        s1, s2 = phi1_phi2_scalar(float(v))
        assert s1 == pytest.approx(a, rel=1e-15) and s2 == pytest.approx(b, rel=1e-15)
    # continuity at the series switch (|x| = 0.1): relative jump ≤ 1e-14
    a1, a2 = phi1_phi2(np.array([-0.1 + 1e-15, -0.1 - 1e-15]))
    assert abs(a1[0] - a1[1]) < 1e-14 and abs(a2[0] - a2[1]) < 1e-14


# ----------------------------------------------------------------------------- ZOH update


@settings(max_examples=60, deadline=None)
@given(angles, rates, vec, vec, vec, masks, st.floats(1.0, 120.0), st.floats(0.0, 0.2))
def test_zoh_closed_form_equals_generic_exponential(  # noqa: PLR0917 -- hypothesis passes the drawn values positionally
    euler: np.ndarray,
    omega: np.ndarray,
    x0: np.ndarray,
    Gam: np.ndarray,
    y: np.ndarray,
    mask: np.ndarray,
    gamma: float,
    dt: float,
) -> None:
    """The exact-E closed form (2-3 measured axes; 0-1 use the 4×4 exponential) agrees
    with the generic path through N = A − K Q and (23) to rounding."""
    E = e_exact(euler)
    closed = zoh_step(x0, omega, Gam, E, y, mask, gamma, dt, orthogonal_e=True)
    generic = zoh_step(x0, omega, Gam, E, y, mask, gamma, dt, orthogonal_e=False)
    scale = 1.0 + np.abs(x0).max() + (np.abs(Gam).max() + gamma * np.abs(y).max()) * dt
    # both exact; rounding of O(10) operations on values of size `scale`: 1e-12 relative
    assert np.abs(closed - generic).max() <= 1e-12 * scale * (1 + gamma * dt)


@settings(max_examples=25, deadline=None)
@given(
    angles, rates, vec, vec, vec, masks, st.floats(5.0, 100.0), st.floats(1e-4, 0.05),
    st.booleans(),
)  # fmt: skip
def test_zoh_equals_fine_rk4_of_16(  # noqa: PLR0917 -- hypothesis passes the drawn values positionally
    euler: np.ndarray,
    omega: np.ndarray,
    x0: np.ndarray,
    Gam: np.ndarray,
    v_ned: np.ndarray,
    mask: np.ndarray,
    gamma: float,
    dt: float,
    small_angle: bool,
) -> None:
    """zoh_step is the exact solution of (16) over Δt with held inputs: a 400-substep RK4 of
    (16), built from observer_gains, agrees to ~1e-10 (RK4 error (γh)⁵/120 per substep)."""
    E = e_small_angle(0.18 * euler / np.pi) if small_angle else e_exact(euler)
    N, b = _held_system(omega, Gam, E, v_ned, mask, gamma)
    ref = _rk4_held(N, b, x0, dt, 400)
    got = zoh_step(x0, omega, Gam, E, v_ned, mask, gamma, dt, orthogonal_e=not small_angle)
    scale = 1.0 + np.abs(ref).max()
    assert np.abs(got - ref).max() <= 1e-9 * scale


@settings(max_examples=40, deadline=None)
@given(angles, rates, vec, vec, vec, vec, st.floats(1.0, 120.0), st.floats(0.0, 0.5))
def test_zoh_exact_invariants(  # noqa: PLR0917 -- hypothesis passes the drawn values positionally
    euler: np.ndarray,
    omega: np.ndarray,
    x_a: np.ndarray,
    x_b: np.ndarray,
    Gam: np.ndarray,
    y: np.ndarray,
    gamma: float,
    dt: float,
) -> None:
    """Properties of the exact solution, frozen earth frame z = E x̂ (E held over the step):
    the difference of two estimates (same inputs) shrinks by exactly e^{−γΔt} for C = I,
    and for c1..c3 the lost-axis difference is unchanged."""
    E = e_exact(euler)
    for i, mask in enumerate(CONFIG_MASKS):
        xa1 = zoh_step(x_a, omega, Gam, E, y, mask, gamma, dt, orthogonal_e=True)
        xb1 = zoh_step(x_b, omega, Gam, E, y, mask, gamma, dt, orthogonal_e=True)
        d0 = E @ (x_a - x_b)
        d1 = E @ (xa1 - xb1)
        tol = 1e-12 * (1.0 + np.abs(x_a).max() + np.abs(x_b).max() + (30 + gamma * 20) * dt)
        if i == 0:
            assert np.abs(d1 - np.exp(-gamma * dt) * d0).max() <= tol
        else:
            lost = int(np.flatnonzero(~mask)[0])
            assert abs(d1[lost] - d0[lost]) <= tol


def _rk4_ramp(  # noqa: PLR0917 -- the system, then the integration
    N: np.ndarray, b0: np.ndarray, b1: np.ndarray, x0: np.ndarray, dt: float, n: int
) -> np.ndarray:
    """RK4 of ẋ = N x + b0 + b1 τ over [0, dt], n substeps."""
    h = dt / n
    x = x0.copy()
    for k in range(n):
        t = k * h

        def f(x: np.ndarray, tau: float) -> np.ndarray:
            return N @ x + b0 + b1 * tau

        k1 = f(x, t)
        k2 = f(x + 0.5 * h * k1, t + 0.5 * h)
        k3 = f(x + 0.5 * h * k2, t + 0.5 * h)
        k4 = f(x + h * k3, t + h)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


@settings(max_examples=40, deadline=None)
@given(
    angles, rates, vec, vec, vec, vec, masks, st.floats(5.0, 100.0), st.floats(1e-4, 0.05),
    st.booleans(),
)  # fmt: skip
def test_zoh_ramp_equals_fine_rk4_of_16(  # noqa: PLR0917 -- hypothesis passes the drawn values positionally
    euler: np.ndarray,
    omega: np.ndarray,
    x0: np.ndarray,
    Gam: np.ndarray,
    v_ned: np.ndarray,
    rho: np.ndarray,
    mask: np.ndarray,
    gamma: float,
    dt: float,
    small_angle: bool,
) -> None:
    """With the measurement moving over the step, y(τ) = y + ρ τ (the held measurement
    carried forward with the IMU), zoh_step(y_rate_ned_mps2=ρ) solves (16): a 400-substep
    RK4 of ẋ = N x + Γ + K C (y + ρ τ) agrees to 1e-9 (as the held case), except for the
    one term the two-axis closed form leaves out (observer.zoh_earth): the lost axis's τ²
    reaching the measured ones, at most |ω|² |ρ| Δt³ / 6 (|ω_e| = |ω|; e^{−γ(Δt−s)} ≤ 1)."""
    E = e_small_angle(0.18 * euler / np.pi) if small_angle else e_exact(euler)
    N, b0 = _held_system(omega, Gam, E, v_ned, mask, gamma)
    _, b_y_rho = _held_system(omega, np.zeros(3), E, rho, mask, gamma)  # K C ρ
    ref = _rk4_ramp(N, b0, b_y_rho, x0, dt, 400)
    got = zoh_step(
        x0, omega, Gam, E, v_ned, mask, gamma, dt, orthogonal_e=not small_angle,
        y_rate_ned_mps2=rho,
    )  # fmt: skip
    scale = 1.0 + np.abs(ref).max()
    left_out = 0.0
    if not small_angle and mask.sum() == 2:
        left_out = float(omega @ omega) * float(np.abs(rho).max()) * np.sqrt(3) * dt**3 / 6
    assert np.abs(got - ref).max() <= 1e-9 * scale + left_out


@pytest.mark.parametrize("config", range(4))
def test_ramp_follows_a_measurement_moving_with_the_imu_without_lag(config: int) -> None:
    """A measurement that moves exactly as the IMU says (ρ = a = E Γ, the truth of a
    propagated y) and a state that starts on it: with the ramp the measured axes stay on
    y(Δt) = y + a Δt exactly, and the lost axis integrates a. Held (the former step) the
    state trails by a (Δt − Δt φ1(−γΔt)) ≈ a γ Δt²/2 per step: summed against the pull
    γ it is a lag of Δt/2, 10 ms at a 50 Hz stream (docs/design/observer-notes.md)."""
    E = e_exact(np.array([0.1, -0.2, 0.7]))
    Gam = np.array([1.5, -0.8, 0.4])  # specific force + gravity, body frame
    a_ned = E @ Gam
    y0 = np.array([3.0, -2.0, 0.5])
    x0 = E.T @ y0
    mask = CONFIG_MASKS[config]
    gamma, dt = 12.0, 0.02
    got = E @ zoh_step(x0, np.zeros(3), Gam, E, y0, mask, gamma, dt, orthogonal_e=True,
                       y_rate_ned_mps2=a_ned)  # fmt: skip
    np.testing.assert_allclose(got, y0 + a_ned * dt, rtol=0, atol=1e-13)  # exact up to rounding
    held = E @ zoh_step(x0, np.zeros(3), Gam, E, y0, mask, gamma, dt, orthogonal_e=True)
    trail = a_ned * (dt - (1 - math.exp(-gamma * dt)) / gamma)
    np.testing.assert_allclose((y0 + a_ned * dt - held)[mask], trail[mask], atol=1e-13)


def test_zoh_broadcasts_over_batches() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 4, 3))
    eul = rng.normal(size=(5, 1, 3))
    w = rng.normal(size=(5, 1, 3))
    G = rng.normal(size=(5, 1, 3))
    y = rng.normal(size=(5, 1, 3))
    gam = np.array([12.0, 90.0, 70.0, 70.0])
    dt = rng.uniform(0.001, 0.1, size=(5, 1))
    out = zoh_step(x, w, G, e_exact(eul), y, CONFIG_MASKS, gam, dt, orthogonal_e=True)
    assert out.shape == (5, 4, 3)
    for i in range(5):
        for j in range(4):
            one = zoh_step(x[i, j], w[i, 0], G[i, 0], e_exact(eul[i, 0]), y[i, 0],
                           CONFIG_MASKS[j], gam[j], dt[i, 0], orthogonal_e=True)  # fmt: skip
            np.testing.assert_allclose(out[i, j], one, rtol=0, atol=1e-13)


def test_zoh_rejects_bad_input_with_clear_errors() -> None:
    E = np.eye(3)
    z = np.zeros(3)
    m = np.array([True, True, False])
    with pytest.raises(NonFiniteInputError, match="omega_body_radps"):
        zoh_step(z, [np.nan, 0, 0], z, E, z, m, 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(NonFiniteInputError, match="Gamma_body_mps2"):
        zoh_step(z, z, [0, np.inf, 0], E, z, m, 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(NonFiniteInputError, match="y_ned_mps"):
        zoh_step(z, z, z, E, [np.nan, 0, 0], m, 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(ShapeError, match=r"x_hat_body_mps: expected shape \(\.\.\., 3\)"):
        zoh_step(np.zeros(4), z, z, E, z, m, 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(ShapeError, match="E: expected"):
        zoh_step(z, z, z, np.eye(2), z, m, 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(ShapeError, match="do not broadcast"):
        zoh_step(np.zeros((2, 3)), np.zeros((3, 3)), z, E, z, m, 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(ShapeError, match="meas_mask"):
        zoh_step(z, z, z, E, z, np.ones(3), 90.0, 0.01, orthogonal_e=True)
    with pytest.raises(ValueError, match="dt_s must be >= 0"):
        zoh_step(z, z, z, E, z, m, 90.0, -0.01, orthogonal_e=True)
    with pytest.raises(ValueError, match="gamma_gain must be > 0"):
        zoh_step(z, z, z, E, z, m, 0.0, 0.01, orthogonal_e=True)
    # a masked-out NaN is ignored
    out = zoh_step(z, z, z, E, [1.0, 2.0, np.nan], m, 90.0, 0.01, orthogonal_e=True)
    assert np.isfinite(out).all()


# ----------------------------------------------------------------------------- the requirements


PAPER_GAMMA = np.array([90.0, 90.0, 70.0, 70.0])  # full given 90 here too; c1..c3 as (49)


def _held_inputs(t: np.ndarray) -> tuple[np.ndarray, ...]:
    sc = exact_kinematics_scenario(t)
    E = e_exact(sc.euler_rad)
    Gam = gamma_body_mps2(sc.f_body_mps2, sc.euler_rad)
    return sc.omega_body_radps, Gam, E, sc.v_ned_mps, sc


def test_requirement_a_zoh_at_10khz_matches_rk4_of_16() -> None:
    """Paper's 1 s scenario ((48), x̂0 = 0 (49), γ 90/70/70): zoh_step fed at 10 kHz vs RK4
    of (16) at 1e-4 s with the same held inputs. Requirement: ≤ 1e-6 m/s."""
    dt = 1e-4
    n = 10_000
    omega, Gam, E, y, _ = _held_inputs(np.arange(n) * dt)
    # held system matrices for all steps and configurations at once (observer_gains batched)
    Ns, bs = [], []
    for mask, gam in zip(CONFIG_MASKS, PAPER_GAMMA, strict=True):
        C = _c_of_mask(mask)
        g = observer_gains(E, C, gam, omega)
        Ns.append(g.N)
        bs.append(Gam + np.einsum("tij,tj->ti", g.K, y @ C.T))
    N = np.stack(Ns, axis=1)  # (n, 4, 3, 3)
    b = np.stack(bs, axis=1)
    x_rk = np.zeros((4, 3))
    x_zoh = np.zeros((4, 3))
    max_diff = 0.0
    for k in range(n):
        x_rk = _rk4_held(N[k], b[k], x_rk, dt, 1)
        x_zoh = zoh_step(x_zoh, omega[k], Gam[k], E[k], y[k], CONFIG_MASKS, PAPER_GAMMA, dt,
                         orthogonal_e=True)  # fmt: skip
        max_diff = max(max_diff, float(np.abs(x_rk - x_zoh).max()))
    # RK4 local error ≈ (γh)⁵/120 |x| = (0.009)⁵/120·3 ≈ 1.5e-12 per step → ≲ 1e-8 over 1e4
    assert max_diff <= 1e-6
    assert max_diff <= 1e-8  # what the analysis above predicts (observed 4e-11)


@pytest.mark.parametrize("rate_hz", [10.0, 250.0])
def test_requirement_b_large_gamma_dt_stable_and_accurate(rate_hz: float) -> None:
    """γ = 90 for every configuration at 10 Hz (γΔt = 9) and 250 Hz (γΔt = 0.36), inputs
    sampled at that rate and held, over the 10 s scenario.

    Bound (docs/design/observer-notes.md): after the transient the measured-axis error is set by the hold,
    |e_m| ≲ Δt·(max|V̇| + max|ω|·max|V|): y is stale by up to V̇Δt and the held E is off by
    a rotation ωΔt, which turns V by |ω||V|Δt. The lost axis drifts by at most the summed
    hold error of the acceleration, ≲ T·Δt·(max|V̈| + max|ω|·max|V̇|)/2 + Δt·max|ω|·max|V|
    (a worst case: observed 13-20× below it). Observed/bound for the measured axes: 0.47 at
    10 Hz, 0.29 at 250 Hz.
    """
    dt = 1.0 / rate_hz
    n = round(10.0 * rate_hz)
    t = np.arange(n + 1) * dt
    sc = exact_kinematics_scenario(t)
    fine = exact_kinematics_scenario(np.linspace(0, 10, 20001))
    vdot = np.gradient(fine.v_ned_mps, fine.t_s, axis=0)
    vddot = np.gradient(vdot, fine.t_s, axis=0)
    max_vdot = np.linalg.norm(vdot, axis=1).max()
    max_vddot = np.linalg.norm(vddot, axis=1).max()
    max_w = np.linalg.norm(fine.omega_body_radps, axis=1).max()
    max_v = np.linalg.norm(fine.v_ned_mps, axis=1).max()
    bank = ObserverBank({"full": 90.0, "c1": 90.0, "c2": 90.0, "c3": 90.0})
    bank.reset(sc.v_body_mps[0])  # start on the truth: the hold error is what remains
    E_all = e_exact(sc.euler_rad)
    errs = np.empty((n, 4, 3))
    for k in range(n):
        bank.step(dt, sc.euler_rad[k], sc.omega_body_radps[k], sc.f_body_mps2[k], sc.v_ned_mps[k])
        errs[k] = bank.x_hat_body_mps @ E_all[k + 1].T - sc.v_ned_mps[k + 1]
    meas_bound = dt * (max_vdot + max_w * max_v)
    lost_bound = 10.0 * dt * (max_vddot + max_w * max_vdot) / 2 + dt * max_w * max_v
    for i, mask in enumerate(CONFIG_MASKS):
        meas_err = np.abs(errs[:, i, mask]).max()
        assert meas_err <= meas_bound, (i, meas_err, meas_bound)
        if i > 0:
            lost_err = np.abs(errs[:, i, ~mask]).max()
            assert lost_err <= lost_bound, (i, lost_err, lost_bound)
    # stable: the last second's error is no larger than the worst seen before it
    last = np.abs(errs[-round(rate_hz) :]).max()
    assert last <= np.abs(errs[: -round(rate_hz)]).max() + 1e-12


def test_continuous_observer_decays_at_gamma_and_lost_axis_stays_constant() -> None:
    """(16) with exact kinematics (inputs evaluated at every RK4 stage, not held), 10 s from
    x̂0 = 0 (49) and the truth (48): ‖measured-axis earth error‖ decays at exactly γ
    (d/dt ‖Dε‖² = −2γ‖Dε‖², the skew part is orthogonal) and the lost earth-axis error
    stays constant once they have converged. The paper's Fig. 6 shows it converging: with
    exact kinematics it does not.
    """
    h = 1e-3
    n = 10_000
    t_stage = np.arange(2 * n + 1) * (h / 2)  # t_k, t_k + h/2, t_k + h
    omega, Gam, E, v_ned, _sc = _held_inputs(t_stage)
    configs = CONFIG_MASKS[1:]
    gam = PAPER_GAMMA[1:]
    Ns, bs = [], []
    for mask, g_ in zip(configs, gam, strict=True):
        C = _c_of_mask(mask)
        g = observer_gains(E, C, g_, omega)
        Ns.append(g.N)
        bs.append(Gam + np.einsum("tij,tj->ti", g.K, v_ned @ C.T))
    N = np.stack(Ns, axis=1)  # (2n+1, 3, 3, 3)
    b = np.stack(bs, axis=1)

    def f(j: int, x: np.ndarray) -> np.ndarray:
        return np.einsum("cij,cj->ci", N[j], x) + b[j]

    x = np.zeros((3, 3))
    err = np.empty((n + 1, 3, 3))
    err[0] = x @ E[0].T - v_ned[0]
    for k in range(n):
        j = 2 * k
        k1 = f(j, x)
        k2 = f(j + 1, x + 0.5 * h * k1)
        k3 = f(j + 1, x + 0.5 * h * k2)
        k4 = f(j + 2, x + h * k3)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        err[k + 1] = x @ E[j + 2].T - v_ned[j + 2]
    t = np.arange(n + 1) * h
    for i, (mask, g_) in enumerate(zip(configs, gam, strict=True)):
        meas = np.linalg.norm(err[:, i, mask], axis=1)
        sel = (meas < 0.3 * meas[0]) & (meas > 1e-7 * meas[0])
        rate = -np.polyfit(t[sel], np.log(meas[sel]), 1)[0]
        assert abs(rate / g_ - 1.0) < 0.02  # requirement; observed < 1e-4
        lost = err[:, i, ~mask][:, 0]
        # after 1 s the measured error is e^{−70} of its start: the lost axis is frozen
        assert abs(lost[-1] - lost[1000]) <= 1e-6
        assert abs(lost[-1]) > 0.5  # and far from zero: no convergence (contradicts Fig. 6)
