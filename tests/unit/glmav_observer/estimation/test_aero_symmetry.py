"""One drag along body x and y (``DragModelConfig.symmetric_xy``, :mod:`.aero.symmetry`,
issue 32): (S1) is the Gaussian update of one row with the other's (k, q), (S2) refuses
two rows that each know their drag and disagree, and a flight along body x lets the model
see the lost axis through the hovering y row."""

from __future__ import annotations

import numpy as np
import pytest

from glmav_observer.config import parse_config
from glmav_observer.estimation.aero import DragModel, DragModelConfig
from glmav_observer.estimation.aero.symmetry import share_drag, shared_drag_chi2
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.frames import e_exact

RATE_HZ = 25.0
K_TRUE = 0.24  # 1/s: ArduPilot's SITL quad in hover
Q_TRUE = 0.035  # 1/m
IDX = (1, 4)  # k and q in θ = (c, k, k·w_n, k·w_e, q)


def _rows() -> tuple[np.ndarray, np.ndarray]:
    """Row x knows its k (σ 0.01) and q; row y hovered: its k is the prior's (σ 2) and
    its intercept c is tied to k along a ridge (correlation 0.99)."""
    th = np.array([[0.01, 0.24, 0.0, 0.0, 0.035], [0.05, -0.3, 0.0, 0.0, 0.0]])
    P = np.stack([np.diag([1e-4, 1e-4, 1e-2, 1e-2, 4e-6]), np.diag([0.25, 4.0, 25.0, 25.0, 1.0])])
    P[1, 0, 1] = P[1, 1, 0] = 0.99 * 0.5 * 2.0
    return th, P


def test_sharing_is_the_information_form_update_with_the_other_rows_k_q() -> None:
    th, P = _rows()
    th_s, P_s = share_drag(th, P, IDX)
    # the same posterior by another route: information Λ = P⁻¹, η = Λθ, plus the other
    # row's marginal on (k, q) as a measurement of this row's: Λ += Sᵀ M⁻¹ S, η += Sᵀ M⁻¹ m
    S = np.zeros((2, 5))
    S[0, 1] = S[1, 4] = 1.0
    for j in (0, 1):
        o = 1 - j
        M = P[o][np.ix_(IDX, IDX)]
        lam = np.linalg.inv(P[j]) + S.T @ np.linalg.inv(M) @ S
        eta = np.linalg.inv(P[j]) @ th[j] + S.T @ np.linalg.inv(M) @ th[o, list(IDX)]
        # double round-off through 5×5 inverses of condition ≤ ~1e6: 1e-8 relative
        assert th_s[j] == pytest.approx(np.linalg.solve(lam, eta), rel=1e-8, abs=1e-10)
        assert P_s[j] == pytest.approx(np.linalg.inv(lam), rel=1e-8, abs=1e-12)
    # both rows end with the precision-weighted k: (0.24/1e-4 − 0.3/4)/(1/1e-4 + 1/4)
    k_w = (0.24 / 1e-4 - 0.3 / 4.0) / (1.0 / 1e-4 + 1.0 / 4.0)
    assert th_s[:, 1] == pytest.approx([k_w, k_w], abs=1e-12)
    # the hovering row's c moves along its ridge: by cov(c, k)/var(k) × Δk (the update's
    # gain on c), here 0.99·0.5/2 × (0.24 + 0.3) ≈ 0.134 m/s²
    dk = th_s[1, 1] - th[1, 1]
    assert th_s[1, 0] - th[1, 0] == pytest.approx(0.99 * 0.5 / 2.0 * dk, rel=1e-4)
    th0, P0 = _rows()
    assert np.array_equal(th, th0) and np.array_equal(P, P0)  # the inputs are not modified


def test_two_rows_that_each_know_their_drag_and_disagree_fail_the_gate() -> None:
    th, P = _rows()
    # the hovering row's σ(k) = 2: any k of it passes (χ² ≈ 0.54²/4 ≈ 0.07)
    assert shared_drag_chi2(th, P, IDX) < 1.0
    # both rows identified (σ 0.01) and 0.16 1/s apart: χ² = 0.16²/(2e-4) = 128 ≫ 11.8
    P2 = P.copy()
    P2[1] = P[0]
    th2 = th.copy()
    th2[1] = th[0]
    th2[1, 1] = 0.40
    assert shared_drag_chi2(th2, P2, IDX) == pytest.approx(0.16**2 / 2e-4, rel=1e-9)


def _flight_along_x(config: DragModelConfig | None, seed: int = 1) -> DragModel:
    """60 s at heading 0 flying back and forth along north (body x: 3 m/s amplitude) while
    body y hovers (2 cm/s of jitter); f = −k u − q u|u| + white noise 0.02 m/s² per axis."""
    model = DragModel(config)
    E = e_exact(np.array([0.0, 0.0, 0.0]))
    rng = np.random.default_rng(seed)
    for i in range(1500):
        t = i / RATE_HZ
        v = np.array([3.0 * np.sin(0.2 * t), rng.normal(0.0, 0.02), 0.0])
        u = E.T @ v
        f = np.array([*(-K_TRUE * u[:2] - Q_TRUE * u[:2] * np.abs(u[:2])), -9.81])
        f[:2] += rng.normal(0.0, 0.02, 2)
        model.learn(t, f, E, v)
    return model


def test_a_hovering_row_sees_the_lost_axis_with_the_other_rows_k() -> None:
    E = e_exact(np.array([0.0, 0.0, 0.0]))
    v = np.array([1.0, 0.5, 0.0])  # east 0.5 m/s: only body y (r_y = (0, 1, 0)) sees it
    f = np.array([*(-K_TRUE * v[:2] - Q_TRUE * v[:2] * np.abs(v[:2])), -9.81])
    alone = _flight_along_x(None)
    assert "y: speed spread" in alone.trust().reason
    assert alone.pseudo_measurement(f, E, v, 1, validated=False) is None
    model = _flight_along_x(DragModelConfig(symmetric_xy=True))
    assert model.trust().ok, model.trust().reason
    # the hovering row's own k is poorly known (measured σ 0.04 1/s against row x's
    # 0.0015: 2 cm/s of jitter against 0.02 m/s² of noise); it borrows x's
    sd_k = np.sqrt(model.cov_theta[:, 1, 1])
    assert sd_k[1] > 10.0 * sd_k[0]
    pm = model.pseudo_measurement(f, E, v, 1, validated=False)
    assert pm is not None
    # σ: the white part σ_f/k ≈ 0.02/0.26 (k + 2q|s| at 0.5 m/s) ≈ 0.08 m/s and the
    # model part, the shared k's σ (~1e-3) times 0.5 m/s plus the y row's intercept:
    # below 0.15 m/s; the truth within 4σ of it
    assert pm.sigma_mps < 0.15
    assert abs(pm.v_mps - 0.5) <= 4.0 * pm.sigma_mps
    # only the hovering row borrows: row x, whose speeds identify its k, keeps its own fit
    used = model._use_lists()
    assert used.theta[0] == model.theta[0].tolist()
    # ...and y's k is the precision-weighted mean, pulled from x's by its own at most
    # σ_x²/(σ_x² + σ_y²) |k_y − k_x| ≈ (0.0015/0.04)² × 0.04 ≈ 6e-5 1/s
    assert used.theta[1][1] == pytest.approx(model.k_per_s[0], abs=2e-4)
    # the learning is untouched: the rows' own fits are the same with and without
    assert model.theta == pytest.approx(alone.theta, rel=1e-12, abs=1e-15)


def test_the_config_key_is_off_by_default() -> None:
    default = parse_config({}).estimation
    assert default.aero_symmetric_xy is False
    est = VehicleEstimator(1, default)
    assert est.aiding is not None and est.aiding.model.config == DragModelConfig()
    on = parse_config({"estimation": {"aero_symmetric_xy": True}}).estimation
    est_on = VehicleEstimator(1, on)
    assert est_on.aiding is not None
    assert est_on.aiding.model.config == DragModelConfig(symmetric_xy=True)
