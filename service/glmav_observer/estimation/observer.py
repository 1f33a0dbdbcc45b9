"""The paper's time-varying velocity observer as pure functions (numpy in, numpy out).

Koehl, Rafaralahy, Boutayeb, Martinez, *Time-Varying Observers for Launched Unmanned
Aerial Vehicle*, IFAC 2011. Equation numbers refer to ``shared/paper/equations.md``.

Conventions (everywhere in this module):

- earth frame NED, body frame FRD, Euler angles ZYX ``euler_rad = (roll φ, pitch θ, yaw ψ)``;
- ``E`` maps body vectors to earth vectors (13): ``v_ned = E @ v_body``
  (:mod:`glmav_observer.frames` computes it);
- the state is the body-frame velocity ``x_hat_body_mps`` (u, v, w) in m/s;
- ``omega_body_radps`` = (p, q, r) body rates in rad/s, ``A = -[ω]×`` (11);
- ``Gamma_body_mps2`` = Γ = F/m, the total force per unit mass *including weight* (12), i.e.
  the accelerometer's specific force plus gravity in body axes (:func:`gamma_body_mps2`);
- a measurement mask ``meas_mask`` (…, 3) bool selects the NED axes measured now; the
  paper's C_i are the rows of the identity it selects, ``D = CᵀC = diag(mask)``
  (:mod:`glmav_observer.configurations` holds each configuration's mask and C).

Every function broadcasts over leading batch dimensions ``...``.

The discrete-time update :func:`zoh_step` is the exact solution of (16) over one interval
with all inputs held (zero-order hold); ``docs/design/observer-notes.md`` derives it.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glmav_observer.frames import G_MPS2 as G_MPS2  # noqa: PLC0414 -- re-exported: the estimator's g
from glmav_observer.frames import ShapeError, e_exact, rotate, rotate_t
from glmav_observer.frames import as_vectors as _array

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
EForm = Literal["exact", "small_angle"]

#: Below this |γ·Δt| the φ-functions use their Taylor series (no cancellation).
_PHI_SERIES_BELOW = 0.1
#: Taylor terms of the φ-functions: the first neglected term is < 0.1⁹/9! ≈ 3e-15 relative.
_PHI_SERIES_TERMS = 9


class NonFiniteInputError(ValueError):
    """A NaN or infinite value where a finite input is required."""


class ObserverGains(NamedTuple):
    """The matrices of (17), (18), (23), (27)-(29) at one instant.

    ``Q = C E`` (p×3), ``Q_pinv = Qᵀ(QQᵀ)⁻¹`` (3×p, (23)), ``K = A Q⁺ + γ EᵀCᵀ`` (3×p,
    (27)-(29)), ``N = A − K Q`` (3×3, (17)).
    """

    Q: FloatArray
    Q_pinv: FloatArray
    K: FloatArray
    N: FloatArray


# --------------------------------------------------------------------------- validation


def _require_finite(name: str, arr: FloatArray) -> None:
    if not np.isfinite(arr).all():
        raise NonFiniteInputError(f"{name}: NaN or infinite value in {np.asarray(arr).tolist()!r}")


# --------------------------------------------------------------------------- kinematics


def e_small_angle(euler_rad: ArrayLike) -> FloatArray:
    """The paper's small-angle E (15), shape (..., 3, 3). Not orthogonal."""
    eul = _array("euler_rad", euler_rad, (3,))
    phi, th, psi = eul[..., 0], eul[..., 1], eul[..., 2]
    one = np.ones_like(phi)
    rows = (
        (one, phi * th - psi, th + phi * psi),
        (psi, phi * th * psi + one, th * psi - phi),
        (-th, phi, one),
    )
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def e_matrix(euler_rad: ArrayLike, e_form: EForm = "exact") -> FloatArray:
    """E by (13) (``"exact"``) or (15) (``"small_angle"``)."""
    if e_form == "exact":
        return e_exact(euler_rad)
    if e_form == "small_angle":
        return e_small_angle(euler_rad)
    raise ValueError(f"e_form must be 'exact' or 'small_angle', got {e_form!r}")


def gravity_body_mps2(euler_rad: ArrayLike, g_mps2: float = G_MPS2) -> FloatArray:
    """Weight per unit mass in body axes (9)/m: g·(−sinθ, cosθ sinφ, cosθ cosφ), FRD."""
    eul = _array("euler_rad", euler_rad, (3,))
    sphi, cphi = np.sin(eul[..., 0]), np.cos(eul[..., 0])
    sth, cth = np.sin(eul[..., 1]), np.cos(eul[..., 1])
    return g_mps2 * np.stack((-sth, cth * sphi, cth * cphi), axis=-1)


def gamma_body_mps2(
    f_body_mps2: ArrayLike, euler_rad: ArrayLike, g_mps2: float = G_MPS2
) -> FloatArray:
    """Γ of (12): accelerometer specific force plus gravity in body axes, m/s².

    At rest and level the accelerometer reads f = (0, 0, −g) (FRD) and Γ = 0.
    """
    f = _array("f_body_mps2", f_body_mps2, (3,))
    return f + gravity_body_mps2(euler_rad, g_mps2)


def skew(v: ArrayLike) -> FloatArray:
    """[v]× such that [v]× w = v × w, shape (..., 3, 3)."""
    a = _array("v", v, (3,))
    z = np.zeros_like(a[..., 0])
    x, y, w = a[..., 0], a[..., 1], a[..., 2]
    return np.stack(
        (np.stack((z, -w, y), -1), np.stack((w, z, -x), -1), np.stack((-y, x, z), -1)), -2
    )


def a_matrix(omega_body_radps: ArrayLike) -> FloatArray:
    """A = −[ω]× (11): [[0, r, −q], [−r, 0, p], [q, −p, 0]], shape (..., 3, 3)."""
    return -skew(omega_body_radps)


# --------------------------------------------------------------------------- the observer


def _mv(M: FloatArray, v: FloatArray) -> FloatArray:
    """Batched matrix-vector product M @ v over leading dimensions."""
    out: FloatArray = np.matmul(M, v[..., None])[..., 0]
    return out


def gamma_full_optimal(  # noqa: PLR0917 -- the noise figures of J(γ), then the bounds
    sigma_y_mps: float,
    f_y_hz: float,
    q_imu_mps2_sq_per_hz: float,
    b_mps2: float,
    gamma_min: float = 4.0,
    gamma_max: float = 40.0,
) -> float:
    """The gain of ``full`` that minimises its steady-state mean-square error (1/s).

    With all three axes measured, the earth-frame error of (16) obeys
    ė = −γ e + w − γ n + b: w the IMU's white noise (PSD q = σ_f²/f_imu), n the
    measurement's white noise (PSD σ_y²/f_y), b an unmodelled acceleration (the
    accelerometer's bias). Its mean square is

        J(γ) = (b/γ)² + q/(2γ) + γ σ_y²/(2 f_y),

    convex in γ > 0; the minimum is found by bisection on J'(γ) = 0 within
    [``gamma_min``, ``gamma_max``]. With design.md's noise (σ_y = 0.05 m/s at 30 Hz,
    σ_f = 4e-3·√250 m/s² at 250 Hz, b = 0.2 m/s²) it gives 12.4 s⁻¹, the fixed default.
    """
    r = sigma_y_mps**2 / max(f_y_hz, 1e-9)

    def dj(g: float) -> float:
        return -2.0 * b_mps2**2 / g**3 - q_imu_mps2_sq_per_hz / (2.0 * g * g) + r / 2.0

    lo, hi = gamma_min, gamma_max
    if dj(lo) >= 0.0:
        return lo
    if dj(hi) <= 0.0:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if dj(mid) > 0.0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def observer_gains(
    E: ArrayLike, C: ArrayLike, gamma_gain: ArrayLike, omega_body_radps: ArrayLike
) -> ObserverGains:
    """Q, Q⁺, K and N of (17), (18), (23), (27)-(29).

    ``E`` (..., 3, 3), ``C`` (p, 3) or (..., p, 3), ``gamma_gain`` γ > 0 (1/s, scalar or (...)),
    ``omega_body_radps`` (..., 3): K = A Q⁺ + γ EᵀCᵀ needs A = −[ω]×.
    Q⁺ is computed by (23) for any E; for the exact E it equals Qᵀ (QQᵀ = I).
    """
    E_ = _array("E", E, (3, 3))
    C_ = np.asarray(C, dtype=np.float64)
    if C_.ndim < 2 or C_.shape[-1] != 3:
        raise ShapeError(f"C: expected shape (..., p, 3), got {C_.shape}")
    g = np.asarray(gamma_gain, dtype=np.float64)[..., None, None]
    A = a_matrix(omega_body_radps)
    Q = C_ @ E_  # (18): Q = C E
    Qt = np.swapaxes(Q, -1, -2)
    Q_pinv = Qt @ np.linalg.inv(Q @ Qt)  # (23): Q⁺ = Qᵀ (Q Qᵀ)⁻¹
    K = A @ Q_pinv + g * (np.swapaxes(E_, -1, -2) @ np.swapaxes(C_, -1, -2))  # (27)-(29)
    N = A - K @ Q  # (17)
    return ObserverGains(Q=Q, Q_pinv=Q_pinv, K=K, N=N)


def observer_rhs(  # noqa: PLR0917 -- positional API mirrors the paper's symbols
    x_hat_body_mps: ArrayLike,
    omega_body_radps: ArrayLike,
    Gamma_body_mps2: ArrayLike,
    E: ArrayLike,
    C: ArrayLike,
    gamma_gain: ArrayLike,
    y: ArrayLike,
) -> FloatArray:
    """dx̂/dt of (16): A x̂ + Γ + K (y − Q x̂), m/s²; ``y`` (..., p) = the measured C·V_ned."""
    x = _array("x_hat_body_mps", x_hat_body_mps, (3,))
    gains = observer_gains(E, C, gamma_gain, omega_body_radps)
    A = a_matrix(omega_body_radps)
    y_ = np.asarray(y, dtype=np.float64)
    innov = y_ - _mv(gains.Q, x)  # y − Q x̂
    return _mv(A, x) + _array("Gamma_body_mps2", Gamma_body_mps2, (3,)) + _mv(gains.K, innov)


# --------------------------------------------------------------------------- φ-functions


def phi1_phi2(x: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """φ1(x) = (eˣ − 1)/x and φ2(x) = (eˣ − 1 − x)/x², accurate for all x ≤ 0.

    Taylor series for |x| < 0.1 (no cancellation), expm1 above.
    """
    x_ = np.asarray(x, dtype=np.float64)
    small = np.abs(x_) < _PHI_SERIES_BELOW
    xs = np.where(small, x_, 0.0)
    # Horner: φ1 = Σ x^k/(k+1)!, φ2 = Σ x^k/(k+2)!, k < _PHI_SERIES_TERMS
    p1s = np.zeros_like(xs)
    p2s = np.zeros_like(xs)
    for k in range(_PHI_SERIES_TERMS - 1, -1, -1):
        p1s = p1s * xs + 1.0 / math.factorial(k + 1)
        p2s = p2s * xs + 1.0 / math.factorial(k + 2)
    xl = np.where(small, -1.0, x_)
    p1l = np.expm1(xl) / xl
    p2l = (p1l - 1.0) / xl
    return np.where(small, p1s, p1l), np.where(small, p2s, p2l)


def phi1_phi2_scalar(x: float) -> tuple[float, float]:
    """Scalar twin of :func:`phi1_phi2` (plain floats, for the single-vehicle fast path)."""
    if -_PHI_SERIES_BELOW < x < _PHI_SERIES_BELOW:
        # the same 9-term Taylor polynomials as phi1_phi2, unrolled (Horner)
        f = _INV_FACT
        p1 = f[1] + x * (
            f[2]
            + x * (f[3] + x * (f[4] + x * (f[5] + x * (f[6] + x * (f[7] + x * (f[8] + x * f[9]))))))
        )
        p2 = f[2] + x * (
            f[3]
            + x
            * (f[4] + x * (f[5] + x * (f[6] + x * (f[7] + x * (f[8] + x * (f[9] + x * f[10]))))))
        )
        return p1, p2
    p1 = math.expm1(x) / x
    return p1, (p1 - 1.0) / x


_INV_FACT = tuple(1.0 / math.factorial(k) for k in range(_PHI_SERIES_TERMS + 2))


# --------------------------------------------------------------------------- matrix exponential


def expm(M: ArrayLike) -> FloatArray:
    """Batched matrix exponential (..., n, n): scaling and squaring with a degree-14 Taylor.

    After scaling, ‖M/2ˢ‖₁ ≤ 0.5, so the first neglected term is < 0.5¹⁵/15! ≈ 2e-17.
    """
    M_ = np.asarray(M, dtype=np.float64)
    n = M_.shape[-1]
    norm = float(np.abs(M_).sum(axis=-2).max()) if M_.size else 0.0
    s = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    X = M_ / (2.0**s)
    eye = np.broadcast_to(np.eye(n), M_.shape)
    T = eye.copy()
    for k in range(14, 0, -1):  # Horner: I + X/1 (I + X/2 (I + ... ))
        T = eye + (X @ T) / k
    for _ in range(s):
        T = T @ T
    return T


def _affine_flow(
    M: FloatArray, c: FloatArray, dt_s: FloatArray, z0: FloatArray, c1: FloatArray | None = None
) -> FloatArray:
    """Exact z(Δt) of ż = M z + c + c1 τ (M, c, c1 held; c1 None: 0): the exponential of
    the augmented [[M, c1, c], [0, 0, 1], [0, 0, 0]] acting on (z, τ, 1)."""
    if c1 is None:
        batch = np.broadcast_shapes(M.shape[:-2], c.shape[:-1], dt_s.shape, z0.shape[:-1])
        aug = np.zeros((*batch, 4, 4))
        aug[..., :3, :3] = M
        aug[..., :3, 3] = c
        F = expm(aug * np.asarray(dt_s)[..., None, None])
        return _mv(F[..., :3, :3], np.broadcast_to(z0, (*batch, 3))) + F[..., :3, 3]
    batch = np.broadcast_shapes(
        M.shape[:-2], c.shape[:-1], c1.shape[:-1], dt_s.shape, z0.shape[:-1]
    )
    aug = np.zeros((*batch, 5, 5))
    aug[..., :3, :3] = M
    aug[..., :3, 3] = c1
    aug[..., :3, 4] = c
    aug[..., 3, 4] = 1.0
    F = expm(aug * np.asarray(dt_s)[..., None, None])
    return _mv(F[..., :3, :3], np.broadcast_to(z0, (*batch, 3))) + F[..., :3, 4]


# --------------------------------------------------------------------------- ZOH update


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """a × b over the last axis (cheaper than np.cross for small batches)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def zoh_step(  # noqa: PLR0917 -- positional API mirrors the paper's symbols
    x_hat_body_mps: ArrayLike,
    omega_body_radps: ArrayLike,
    Gamma_body_mps2: ArrayLike,
    E: ArrayLike,
    y_ned_mps: ArrayLike,
    meas_mask: ArrayLike,
    gamma_gain: ArrayLike,
    dt_s: ArrayLike,
    *,
    orthogonal_e: bool,
    y_rate_ned_mps2: ArrayLike | None = None,
) -> FloatArray:
    """x̂(t+Δt): the exact solution of (16) over Δt with ω, Γ, E, y and the mask held.

    ``y_rate_ned_mps2`` (..., 3): the measurement moves over the step, y(τ) = y + ρ τ (the
    held measurement carried forward with the IMU: ρ = E (f − b̂) + g e_d); None: held.

    ``x_hat_body_mps``, ``omega_body_radps``, ``Gamma_body_mps2``, ``y_ned_mps`` (..., 3);
    ``E`` (..., 3, 3); ``meas_mask`` (..., 3) bool (NED axes measured now: the configuration's
    C and the measurement's validity); ``gamma_gain`` γ > 0 in 1/s and ``dt_s`` ≥ 0 in s,
    scalars or (...). Masked-out entries of ``y_ned_mps`` are ignored (may be NaN).

    ``orthogonal_e=True`` (the exact E (13)): Q⁺ = Qᵀ and the closed form in "frozen earth"
    coordinates z = E x̂ is used (two or three measured axes), the augmented matrix
    exponential otherwise. ``orthogonal_e=False`` (the small-angle E (15)): Q⁺ by (23) and the
    matrix exponential of N = A − K Q in body coordinates. Both are exact for held inputs:
    stable for any γ·Δt.

    Raises :class:`ShapeError` and :class:`NonFiniteInputError` (nothing is modified: pure).
    """
    x = _array("x_hat_body_mps", x_hat_body_mps, (3,))
    w = _array("omega_body_radps", omega_body_radps, (3,))
    G = _array("Gamma_body_mps2", Gamma_body_mps2, (3,))
    E_ = _array("E", E, (3, 3))
    y = _array("y_ned_mps", y_ned_mps, (3,))
    mask = np.asarray(meas_mask)
    if mask.dtype != np.bool_ or mask.ndim < 1 or mask.shape[-1] != 3:
        raise ShapeError(f"meas_mask: expected bool (..., 3), got {mask.dtype} {mask.shape}")
    gam = np.asarray(gamma_gain, dtype=np.float64)
    h = np.asarray(dt_s, dtype=np.float64)
    try:
        batch = np.broadcast_shapes(
            x.shape[:-1], w.shape[:-1], G.shape[:-1], E_.shape[:-2], y.shape[:-1],
            mask.shape[:-1], gam.shape, h.shape,
        )  # fmt: skip
    except ValueError as exc:
        raise ShapeError(f"inputs do not broadcast: {exc}") from exc
    for name, arr in (("x_hat_body_mps", x), ("omega_body_radps", w), ("Gamma_body_mps2", G),
                      ("E", E_), ("gamma_gain", gam), ("dt_s", h)):  # fmt: skip
        _require_finite(name, arr)
    if (h < 0).any():
        raise ValueError(f"dt_s must be >= 0, got {h.tolist()!r}")
    if (gam <= 0).any():
        raise ValueError(f"gamma_gain must be > 0, got {gam.tolist()!r}")
    ybar = np.where(mask, y, 0.0)  # Ȳ = D y (Cᵀ y embedded in NED), unmeasured axes 0
    if not np.isfinite(ybar).all():
        raise NonFiniteInputError("y_ned_mps: NaN or infinite value on an axis meas_mask selects")
    rho = None
    if y_rate_ned_mps2 is not None:
        rate = _array("y_rate_ned_mps2", y_rate_ned_mps2, (3,))
        rho = np.where(mask, rate, 0.0)
        if not np.isfinite(rho).all():
            raise NonFiniteInputError("y_rate_ned_mps2: NaN or infinite on a measured axis")
    if orthogonal_e:
        # z = E x̂, ω_e = E ω, a = E Γ with E held over the step
        z1 = zoh_earth(rotate(E_, x), rotate(E_, w), rotate(E_, G), ybar, mask, gam, h, rho=rho)
        return rotate_t(np.broadcast_to(E_, (*batch, 3, 3)), z1)  # x̂ = Eᵀ z
    return _zoh_general_e(x, w, G, E_, ybar, mask, gam, h, rho)


def frame_ramp_mps2(omega_ned_radps: ArrayLike, y_ned_mps: ArrayLike) -> FloatArray:
    """The measurement's rate seen from the frame of a step, −ω_e × y (..., 3) m/s², to
    add to ``zoh_step``'s ramp of a configuration measuring all three axes
    (``EstimatorConfig.rotate_measurement``).

    Over a step the bank holds the E of its start while the body turns at ω: in the frozen
    earth coordinates z = E x̂ (docs/design/observer-notes.md, "Discrete-time update") a
    measurement y fixed in NED reads exp(−[ω_e]× τ) y ≈ y − (ω_e × y) τ, ω_e = E ω; first
    order in ω τ (the τ² term is |ω|² |y| τ²/2: 3e-4 m/s at 0.5 rad/s, 6 m/s and 20 ms).
    Down, −(ω_n y_e − ω_e y_n) is a pitch or roll rate times the horizontal speed (3 m/s²
    at 0.5 rad/s and 6 m/s); north and east, a yaw rate times the other horizontal
    component and a roll or pitch rate times the vertical one. Without it the held y
    leaves that much in the correction: a lead of about Δt/2 in turns (which the
    autopilot's own lag made look good on north) and a push the wrong way at a roll's
    onset in a climb or descent (docs/field-failures.md, "The frame of a step")."""
    w = np.asarray(omega_ned_radps, dtype=np.float64)
    y = np.asarray(y_ned_mps, dtype=np.float64)
    w_b, y_b = np.broadcast_arrays(w, y)
    out: FloatArray = -np.cross(w_b, y_b)
    return out


def phi_terms(gam: FloatArray, h: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """exp(−γh), h φ1(−γh), h² φ2(−γh) with a trailing axis of 1 for broadcasting."""
    xg = -gam * h
    if xg.size <= 16:  # few distinct (γ, h): plain floats are cheaper than array calls
        flat = xg.ravel().tolist()
        ph = [phi1_phi2_scalar(v) for v in flat]
        p1 = np.array([p[0] for p in ph]).reshape(xg.shape)
        p2 = np.array([p[1] for p in ph]).reshape(xg.shape)
    else:
        p1, p2 = phi1_phi2(xg)
    e = np.exp(xg)
    return e[..., None], (h * p1)[..., None], (h * h * p2)[..., None]


def zoh_earth(  # noqa: PLR0917 -- positional API mirrors the paper's symbols
    z0: FloatArray,
    we: FloatArray,
    a: FloatArray,
    ybar: FloatArray,
    mask: BoolArray,
    gam: FloatArray,
    h: FloatArray,
    terms: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    rho: FloatArray | None = None,
) -> FloatArray:
    """The exact-E update in frozen earth coordinates (docs/design/observer-notes.md, "Discrete-time update").

    ``z0 = E x̂``, ``we = ω_e = E ω``, ``a = E Γ``, ``ybar = Ȳ = D y`` (…, 3); ``mask`` the
    measured axes (D = diag(mask)); ``gam`` γ and ``h`` Δt broadcast to the batch. With
    w = (I − D) z + Ȳ, (16) reads ż = a + γ D (Ȳ − z) − ω_e × w. With two measured axes the
    lost axis l has ż_l = r_l, r = a − ω_e × Ȳ (constant: (ω_e × w)_l does not involve w_l),
    and each measured axis ż_m = −γ z_m + f0 + f1 t, solved with φ-functions. With three
    measured axes f1 = 0. With fewer than two, the augmented matrix exponential.
    ``terms`` optionally gives precomputed (e^{−γΔt}, Δt φ1, Δt² φ2) with a trailing axis of
    1 (:func:`phi_terms`; a fixed-rate caller reuses them). ``mask`` may be a smaller array
    that broadcasts (e.g. the (4, 3) configuration masks for (n, 4, 3) states).

    The measurement's ramp: ``rho`` = D ρ (…, 3; None: 0) when Ȳ moves as Ȳ + ρ τ over
    the step (docs/design/observer-notes.md, "The measurement's ramp"). The forcing gains
    c1 τ with c1 = γ D ρ − ω_e × D ρ: the measured axes take Δt² φ2 c1 (exact), the lost
    axis c1_l Δt²/2 (exact); the lost axis's τ² term then reaches the measured axes
    through −(ω_e × e_l) z_l and is left out: |ω_e|² |ρ| Δt³/6, 1e-5 m/s at 1 rad/s, 5
    m/s² and a 20 ms step (the fewer-than-two-axes path below is exact).
    Returns z(Δt) (…, 3). No validation (callers validate).
    """
    d = mask.astype(np.float64)
    u = 1.0 - d
    r = a - _cross(we, ybar)
    zl0 = (u * z0).sum(-1)[..., None]  # lost-axis value (0 when all three are measured)
    cl = (u * r).sum(-1)[..., None]  # its constant rate ż_l
    wxu = _cross(we, u)  # ω_e × e_l
    e, hp1, h2p2 = phi_terms(gam, h) if terms is None else terms
    g = gam[..., None]
    # z_m(Δt) = e^{−γΔt} z_m0 + Δt φ1 f0 + Δt² φ2 f1,  f0 = r + γȲ − (ω_e×e_l) z_l0, f1 = −(ω_e×e_l) ż_l
    z_meas = e * z0 + hp1 * (r + g * ybar - wxu * zl0) - h2p2 * (wxu * cl)
    c1 = None
    if rho is not None:
        c1 = g * rho - _cross(we, rho)
        z_meas = z_meas + h2p2 * c1
        zl0 = zl0 + (u * c1).sum(-1)[..., None] * (0.5 * h[..., None] * h[..., None])
    z1 = d * z_meas + u * (zl0 + cl * h[..., None])
    degenerate = mask.sum(-1) < 2
    if degenerate.any():  # one or no measured axis: the generic exact path
        batch = z1.shape[:-1]
        M = -(g[..., None] * (d[..., :, None] * np.eye(3))) - skew(we) * u[..., None, :]
        zg = _affine_flow(M, r + g * ybar, h, z0, c1)
        z1 = np.where(np.broadcast_to(degenerate, batch)[..., None], zg, z1)
    out: FloatArray = z1
    return out


def _zoh_general_e(  # noqa: PLR0917 -- positional API mirrors the paper's symbols
    x: FloatArray,
    w: FloatArray,
    G: FloatArray,
    E: FloatArray,
    ybar: FloatArray,
    mask: BoolArray,
    gam: FloatArray,
    h: FloatArray,
    rho: FloatArray | None = None,
) -> FloatArray:
    """Any invertible E: ẋ = N x + (Γ + K y) with N = A − K Q (17), Q⁺ by (23), exactly
    (with the measurement's ramp ``rho`` = D ρ: + K ρ τ).

    Embedded form for any mask: Q⁺ y = Eᵀ D G⁻¹ Ȳ with G = D E Eᵀ D + (I − D), which is
    Qᵀ(QQᵀ)⁻¹ C Cᵀ y with the measured rows of Q.
    """
    Dm = mask.astype(np.float64)[..., :, None] * np.eye(3)
    Et = np.swapaxes(E, -1, -2)
    Gm = Dm @ E @ Et @ Dm + (np.eye(3) - Dm)
    Qpe = Et @ Dm @ np.linalg.inv(Gm) @ Dm  # Q⁺ embedded (23)
    A = a_matrix(w)
    g = gam[..., None, None]
    K = A @ Qpe + g * Et  # K applied to Ȳ: (27)-(29); rows of unmeasured axes are 0 in Ȳ
    N = A - K @ Dm @ E  # (17): N = A − K Q
    b = G + _mv(K, ybar)  # Γ + K y
    return _affine_flow(N, b, h, x, None if rho is None else _mv(K, rho))
