"""The floor: the best lost-axis error any estimator can reach through drag in turbulence.

Issue 13 asks a lost horizontal axis aided through drag to stay within 0.1 m/s (median)
and 0.2 m/s (worst) 10 s after the loss and within 0.3 m/s after 60 s. Even a *perfect*
drag model only measures the **airspeed**; the ground velocity is airspeed + wind, and
the wind's turbulence is measured by nothing once the axis is lost. This module computes
the error of an *oracle* Kalman filter that knows everything an estimator could know —
the exact drag model, the mean wind and the gusts, the true attitude, the sensors'
statistics — and is left with only what no one can know: the IMU's noise, its
accelerometer-bias random walk and the turbulence on the lost axis. No estimator of the
lost axis from these sensors has a smaller error variance; when the floor is above a bound,
the bound is unattainable.

Model of one lost earth axis L (SI; NED, so one scalar axis), continuous time::

    v̇ = a_meas − b − n_a,   ḃ = n_b,   ẇ = −w/τ_w + n_w                         (F1)

v the ground velocity, a_meas the IMU's earth acceleration (known input), b the
accelerometer bias on the axis, w the turbulence (a first-order Gauss-Markov process,
glmav_sitl/wind.py: stationary σ_w, time constant τ_w); n_a, n_b, n_w white with PSDs
q_a = N_a² (accelerometer noise density N_a, m/s²/√Hz), q_b = N_b² (bias random walk
N_b, m/s³/√Hz), q_w = 2σ_w²/τ_w. Measurements at the velocity-sample rate 1/Δt::

    healthy axis:      z_v = v + ε_v,          var ε_v = σ_v²                    (F2)
    perfect drag:      z_u = v − w + ε_u,      var ε_u = σ_u² (0: a perfect model)

(z_u is the airspeed plus the known mean wind and gusts: the oracle subtracts what is
deterministic, only the turbulence is left.) Discretised exactly over Δt, x = (v, b, w)::

    Φ = [[1, −Δt, 0], [0, 1, 0], [0, 0, a]],   a = exp(−Δt/τ_w)                  (F3)
    Q = [[q_a Δt + q_b Δt³/3, −q_b Δt²/2, 0], [−q_b Δt²/2, q_b Δt, 0], [0, 0, σ_w²(1 − a²)]]

and the covariance follows the discrete Riccati recursion (Joseph form)::

    P⁻ = Φ P Φᵀ + Q,   K = P⁻Hᵀ (H P⁻ Hᵀ + R)⁻¹,   P = (I − KH) P⁻ (I − KH)ᵀ + K R Kᵀ   (F4)

The hand-over covariance is the healthy filter's steady state (both measurements of
(F2): v and w known to the velocity sensor's noise averaged, b to the bias random walk's
steady state); after the loss only z_u is fused ("aided") or nothing ("dead reckoning",
the oracle's own: P_vv = σ_v0² + σ_b0² t² + q_a t + q_b t³/3 from an uncorrelated start).

**Closed form, the double-integrator limit.** When τ_w is short against the filter's
time constant the turbulence is, at the frequencies the filter passes, white with the
Gauss-Markov process's low-frequency PSD r = 2σ_w²τ_w; with q_a negligible (F1)-(F2)
become a double integrator (b the rate, v the output) measured in white noise, whose
continuous algebraic Riccati equation 0 = FP + PFᵀ + Q − PHᵀHP/r solves to::

    P_vv = √2 q_b^{1/4} r^{3/4},   P_vb = −√(q_b r),   P_bb = √2 q_b^{3/4} r^{1/4},
    filter time constant T_f = (r/q_b)^{1/4}                                      (F5)

(the (1,1), (2,2), (1,2) entries give p_vb = −p_vv²/2r, p_vb² = q_b r, p_bb = −p_vv p_vb/r).
glmav-sitl's IMU (N_b = 6e-3 m/s³/√Hz) in the `gusts` turbulence (σ_w 0.8 m/s, τ_w 1 s):
r = 1.28 m²/s, T_f = 14 s ≫ τ_w, σ = √P_vv = 0.36 m/s.

**From σ to the issue's bounds.** The oracle's error is Gaussian with zero mean, so
median |e| = 0.674 σ (F6) and P(|e| ≤ B) = erf(B / (√2 σ)) (F7); n independent cases
all within B: P(|e| ≤ B)ⁿ.

Pure numpy; the caller supplies the numbers (the benchmark and the tests read them from
glmav-sitl's own config and scenario files).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: median of |e| per σ for a zero-mean Gaussian e: Φ⁻¹(0.75) (F6)
MEDIAN_ABS_PER_SIGMA = 0.6744897501960817
#: the Riccati recursion stops when P changes by less than this (relative) over
#: _CHECK_EVERY steps
_RTOL = 1e-8
_CHECK_EVERY = 64
_MAX_STEPS = 2_000_000

_EYE3 = np.eye(3)
#: (F2) over x = (v, b, w): the drag's z_u alone (a lost axis), and z_v with z_u (healthy)
H_DRAG = np.array([[1.0, 0.0, -1.0]])
H_HEALTHY = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, -1.0]])


@dataclass(frozen=True)
class FloorModel:
    """The noise of one lost horizontal axis (F1)-(F2), SI."""

    accel_noise_density: float  # N_a, m/s²/√Hz
    accel_bias_random_walk: float  # N_b, m/s³/√Hz
    turbulence_sigma_mps: float  # σ_w, m/s (stationary)
    turbulence_time_constant_s: float  # τ_w, s
    velocity_rate_hz: float  # 1/Δt: velocity samples, drag pseudo-measurements
    velocity_sigma_mps: float  # σ_v, the healthy axis's measurement noise
    drag_sigma_mps: float = 0.0  # σ_u, the drag model's own error (0: perfect)

    def __post_init__(self) -> None:
        for name in (
            "accel_noise_density",
            "accel_bias_random_walk",
            "turbulence_sigma_mps",
            "velocity_sigma_mps",
            "drag_sigma_mps",
        ):
            if not (getattr(self, name) >= 0.0 and math.isfinite(getattr(self, name))):
                raise ValueError(f"FloorModel.{name} = {getattr(self, name)}: must be >= 0")
        for name in ("turbulence_time_constant_s", "velocity_rate_hz"):
            if not (getattr(self, name) > 0.0 and math.isfinite(getattr(self, name))):
                raise ValueError(f"FloorModel.{name} = {getattr(self, name)}: must be > 0")

    @property
    def dt_s(self) -> float:
        return 1.0 / self.velocity_rate_hz

    @property
    def turbulence_psd_m2ps(self) -> float:
        """r = 2σ_w²τ_w, the Gauss-Markov turbulence's low-frequency PSD, m²/s (F5)."""
        return 2.0 * self.turbulence_sigma_mps**2 * self.turbulence_time_constant_s


def discrete_model(m: FloorModel) -> tuple[FloatArray, FloatArray]:
    """Φ and Q of (F3) over one velocity-sample interval."""
    dt = m.dt_s
    qa = m.accel_noise_density**2
    qb = m.accel_bias_random_walk**2
    a = math.exp(-dt / m.turbulence_time_constant_s)
    phi = np.array([[1.0, -dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, a]])
    q = np.array(
        [
            [qa * dt + qb * dt**3 / 3.0, -qb * dt**2 / 2.0, 0.0],
            [-qb * dt**2 / 2.0, qb * dt, 0.0],
            [0.0, 0.0, m.turbulence_sigma_mps**2 * (1.0 - a * a)],
        ]
    )
    return phi, q


def kalman_update(p: FloatArray, h: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(F4)'s update of the predicted P⁻ with measurement matrix H and noise R, Joseph
    form: (P, K)."""
    ph = p @ h.T
    s = h @ ph + r
    # K = P⁻Hᵀ S⁻¹ (S and P symmetric); a scalar division for one measurement
    k: FloatArray = (
        ph / float(s[0, 0]) if s.shape == (1, 1) else np.asarray(np.linalg.solve(s, ph.T).T)
    )
    i_kh = _EYE3 - k @ h
    p_new = i_kh @ p @ i_kh.T + k @ r @ k.T
    p_sym: FloatArray = 0.5 * (p_new + p_new.T)
    return p_sym, k


def measurement_model(m: FloorModel, healthy: bool) -> tuple[FloatArray, FloatArray]:
    """H and R of (F2): z_v and z_u (``healthy``) or z_u alone."""
    if healthy:
        return H_HEALTHY, np.diag([m.velocity_sigma_mps**2, m.drag_sigma_mps**2])
    return H_DRAG, np.array([[m.drag_sigma_mps**2]])


def steady_state(m: FloorModel, *, healthy: bool = False) -> FloatArray:
    """The posterior covariance P of (F4) in steady state: with the velocity measured as
    well (``healthy``: the hand-over) or through the drag alone (the lost axis's floor)."""
    phi, q = discrete_model(m)
    h, r = measurement_model(m, healthy)
    # without a bias random walk the bias is a constant that the infinite past has
    # pinned (P_bb = 0: a 1/n decay would never pass the convergence test)
    p_bb0 = 1.0 if m.accel_bias_random_walk > 0.0 else 0.0
    p = np.diag([m.velocity_sigma_mps**2, p_bb0, m.turbulence_sigma_mps**2])
    p_check = p
    for n in range(1, _MAX_STEPS + 1):
        p, _ = kalman_update(phi @ p @ phi.T + q, h, r)
        if n % _CHECK_EVERY == 0:
            # P converges geometrically: the change over _CHECK_EVERY steps bounds the rest
            if np.allclose(p, p_check, rtol=_RTOL, atol=0.0):
                return p
            p_check = p
    raise ArithmeticError("the floor's Riccati recursion did not converge")  # pragma: no cover


def sigma_after_loss_mps(
    m: FloorModel,
    t_since_loss_s: FloatArray,
    *,
    aided: bool = True,
    p0: FloatArray | None = None,
) -> FloatArray:
    """σ of the lost axis (√P_vv) at each time since the loss (s, ≥ 0; sampled on the
    velocity-sample grid, the last sample at or before t). From ``p0`` (default: the
    healthy steady state, the hand-over), (F4) with the drag measurement (``aided``) or
    with none (the oracle's dead reckoning)."""
    t = np.asarray(t_since_loss_s, dtype=np.float64)
    if t.size and (not np.all(np.isfinite(t)) or float(t.min()) < 0.0):
        raise ValueError("times since the loss must be finite and >= 0")
    phi, q = discrete_model(m)
    h, r = measurement_model(m, healthy=False)
    p = steady_state(m, healthy=True) if p0 is None else np.asarray(p0, dtype=np.float64)
    steps = np.floor(t * m.velocity_rate_hz + 1e-9).astype(np.int64)
    n = int(steps.max()) if steps.size else 0
    pvv = np.empty(n + 1)
    pvv[0] = p[0, 0]
    for k in range(1, n + 1):
        p = phi @ p @ phi.T + q
        if aided:
            p, _ = kalman_update(p, h, r)
        pvv[k] = p[0, 0]
    out: FloatArray = np.sqrt(pvv[steps])
    return out


class FloorFilter:
    """The oracle filter itself, (F1)-(F4) on data: state x = (v, b, w) of one axis.

    Per velocity-sample interval: :meth:`predict` with the IMU's earth acceleration
    integrated over the interval (Δv_imu = Σ a_meas dt, m/s), then :meth:`update` with the
    drag's z_u (airspeed + the known mean wind and gusts) and, while the axis is healthy,
    its measurement z_v. ``nis`` accumulates the normalised innovation squared of the
    z_u-only updates (a consistent filter's mean is 1)."""

    def __init__(self, m: FloorModel, x0: FloatArray, p0: FloatArray) -> None:
        self.model = m
        self.phi, self.q = discrete_model(m)
        self.x = np.asarray(x0, dtype=np.float64).copy()
        self.p = np.asarray(p0, dtype=np.float64).copy()
        self.nis_sum = 0.0
        self.nis_n = 0

    def predict(self, dv_imu_mps: float) -> None:
        self.x = self.phi @ self.x + np.array([dv_imu_mps, 0.0, 0.0])
        self.p = self.phi @ self.p @ self.phi.T + self.q

    def update(self, z_u_mps: float, z_v_mps: float | None = None) -> None:
        healthy = z_v_mps is not None
        h, r = measurement_model(self.model, healthy)
        z = np.array([z_v_mps, z_u_mps]) if healthy else np.array([z_u_mps])
        nu = z - h @ self.x
        if not healthy:
            s = float((h @ self.p @ h.T + r)[0, 0])
            self.nis_sum += float(nu[0]) ** 2 / s
            self.nis_n += 1
        self.p, k = kalman_update(self.p, h, r)
        self.x = self.x + k @ nu


def double_integrator_pvv_m2ps2(q_b_m2ps5: float, r_m2ps: float) -> float:
    """(F5): steady-state P_vv of a double integrator (bias random walk PSD q_b) measured
    in white noise of PSD r, m²/s²."""
    return float(math.sqrt(2.0) * q_b_m2ps5**0.25 * r_m2ps**0.75)


def error_autocovariance_m2ps2(m: FloorModel, n_lags: int) -> FloatArray:
    """E[e_k e_{k+j}] of the aided floor filter's steady-state velocity error for
    j = 0 … n_lags − 1: the posterior error evolves as e_{k+1} = (I − KH)(Φ e_k + noise)
    − K ε, so its autocovariance is [((I − KH)Φ)^j P]_vv."""
    phi, q = discrete_model(m)
    h, r = measurement_model(m, healthy=False)
    p = steady_state(m)
    _, k = kalman_update(phi @ p @ phi.T + q, h, r)
    a = (np.eye(3) - k @ h) @ phi
    out = np.empty(n_lags)
    c = p.copy()
    for j in range(n_lags):
        out[j] = c[0, 0]
        c = a @ c
    return out


def mean_square_relative_std(m: FloorModel, n_samples: int) -> float:
    """Relative standard deviation of the mean of e² over ``n_samples`` consecutive
    samples of the steady-state floor filter's error (Gaussian e: Var(e_i², e_j²)
    covariance 2C(i−j)², so Var(mean) = (2/N²) Σ_{|j|<N} (N − |j|) C(j)²), over its
    expectation P_vv. The RMS's relative spread is about half of it."""
    if n_samples < 1:
        raise ValueError("n_samples must be >= 1")
    c = error_autocovariance_m2ps2(m, n_samples)
    w = n_samples - np.arange(n_samples, dtype=np.float64)
    w[1:] *= 2.0
    var = 2.0 / n_samples**2 * float(np.sum(w * c**2))
    return math.sqrt(var) / float(c[0])


def p_within(bound_mps: float, sigma_mps: float) -> float:
    """(F7): P(|e| ≤ bound) for e ~ N(0, σ²)."""
    if sigma_mps <= 0.0:
        return 1.0
    return math.erf(bound_mps / (math.sqrt(2.0) * sigma_mps))


def median_abs_error_mps(sigma_mps: float) -> float:
    """(F6): median |e| for e ~ N(0, σ²)."""
    return MEDIAN_ABS_PER_SIGMA * sigma_mps
