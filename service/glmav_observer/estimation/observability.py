"""Observability of the reduced model (11)-(12) with the output y = C E x, from a history.

The paper's rank condition (assumption 4, remark 2) uses Ω = [C E; C Ė]. The observability
matrix of the linear time-varying pair (A(t), Q(t) = C E(t)) is O = [Q; Q̇ + Q A]. With
consistent kinematics Ė = E [ω]× and A = −[ω]×, so Q̇ + Q A = C E [ω]× − C E [ω]× = 0 and
O = [C E; 0] has rank 2 for every c_i: the earth-frame axis C does not measure is never
observed, whatever the motion. Over an interval the same holds for the stacked
C E(t_k) Φ(t_k, t_0) (Φ the transition of ẋ = A x), which equals C E(t_0) for all k.

Q̇ is taken from the attitude history by second-order finite differences, so these
functions test the kinematics of the history they are given (docs/design/observer-notes.md).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from glmav_observer.configurations import LOST_INDEX_OF_CONFIG, output_matrix
from glmav_observer.estimation.observer import FloatArray, a_matrix, expm
from glmav_observer.frames import ShapeError, e_exact

ObservabilityForm = Literal["true", "paper", "interval"]


def _histories(
    euler_history_rad: ArrayLike, omega_history_radps: ArrayLike, dt_s: float
) -> tuple[FloatArray, FloatArray]:
    eul = np.asarray(euler_history_rad, dtype=np.float64)
    om = np.asarray(omega_history_radps, dtype=np.float64)
    if eul.ndim != 2 or eul.shape[1] != 3 or eul.shape[0] < 3:
        raise ShapeError(f"euler_history_rad: expected (T >= 3, 3), got {eul.shape}")
    if om.shape != eul.shape:
        raise ShapeError(f"omega_history_radps: expected {eul.shape}, got {om.shape}")
    if not (np.isfinite(eul).all() and np.isfinite(om).all()):
        raise ValueError("histories contain NaN or infinite values")
    if not dt_s > 0:
        raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
    return eul, om


def observability_matrices(
    config: str,
    euler_history_rad: ArrayLike,
    omega_history_radps: ArrayLike,
    dt_s: float,
    form: ObservabilityForm = "true",
) -> FloatArray:
    """The observability matrix per sample, (T, 2p, 3), or the interval matrix (1, pT, 3).

    ``"true"``: O(t) = [Q; Q̇ + Q A] with Q = C E(t); ``"paper"``: Ω(t) = [C E; C Ė];
    ``"interval"``: the rows C E(t_k) Φ(t_k, t_0) stacked over the history (Φ from ω with
    the midpoint rate, exact per step for a rate constant over the step).
    """
    eul, om = _histories(euler_history_rad, omega_history_radps, dt_s)
    C = output_matrix(config)
    E = e_exact(eul)  # (13)
    Q = C @ E  # (18)
    if form == "interval":
        w_mid = 0.5 * (om[1:] + om[:-1])
        steps = expm(a_matrix(w_mid) * dt_s)  # Φ(t_{k+1}, t_k) = exp(A Δt), A = −[ω]× (11)
        phi = np.empty((eul.shape[0], 3, 3))
        phi[0] = np.eye(3)
        for k in range(steps.shape[0]):
            phi[k + 1] = steps[k] @ phi[k]
        return (Q @ phi).reshape(1, -1, 3)
    Q_dot = np.gradient(Q, dt_s, axis=0, edge_order=2)
    if form == "true":
        return np.concatenate((Q, Q_dot + Q @ a_matrix(om)), axis=1)
    if form == "paper":
        return np.concatenate((Q, Q_dot), axis=1)  # C Ė = Q̇
    raise ValueError(f"form must be 'true', 'paper' or 'interval', got {form!r}")


def observability_rank(  # noqa: PLR0917 -- history arguments in the API order
    config: str,
    euler_history_rad: ArrayLike,
    omega_history_radps: ArrayLike,
    dt_s: float,
    form: ObservabilityForm = "true",
    rel_tol: float = 1e-3,
) -> int:
    """Numerical rank (maximum over the history) of the matrix :func:`observability_matrices`.

    Singular values below ``rel_tol`` × the largest count as zero. The default 1e-3 sits far
    above the finite-difference error of Q̇ (≈ Δt² |ω|³ / 6, 2e-5 for Δt = 0.01 s,
    |ω| = 1 rad/s) and far below the σ ≈ |ω| that a rotating vehicle gives the paper's Ω.
    Expected: 2 for c1..c3 with ``"true"`` and ``"interval"``; 3 with ``"paper"`` whenever ω
    has a component off the lost axis.
    """
    obs = observability_matrices(config, euler_history_rad, omega_history_radps, dt_s, form)
    s = np.linalg.svd(obs, compute_uv=False)  # (T, 3)
    ranks = (s > rel_tol * s[:, :1]).sum(axis=1)
    return int(ranks.max())


def unobserved_direction_body(
    config: str,
    euler_history_rad: ArrayLike,
    omega_history_radps: ArrayLike,
    dt_s: float,
) -> FloatArray:
    """Unit body-frame (FRD) direction not observed at each sample, (T, 3).

    The right singular vector of the smallest singular value of the true O(t), signed to
    point along +Eᵀ e_l (the lost NED axis l expressed in body axes, which it equals for
    consistent kinematics). ``full`` observes everything: ``ValueError``.
    """
    lost = LOST_INDEX_OF_CONFIG.get(config)
    if lost is None:
        raise ValueError(f"config {config!r} has no unobserved direction (use c1, c2 or c3)")
    obs = observability_matrices(config, euler_history_rad, omega_history_radps, dt_s, "true")
    _, _, vt = np.linalg.svd(obs)
    null = vt[:, -1, :]  # (T, 3)
    E = e_exact(np.asarray(euler_history_rad, dtype=np.float64))
    ref = E[:, lost, :]  # Eᵀ e_l = row l of E
    sign = np.where((null * ref).sum(axis=1) < 0, -1.0, 1.0)
    out: FloatArray = null * sign[:, None]
    return out
