"""The accelerometer-change detector: is a failing residual a velocity step, an
accelerometer-bias step or an offset of the reference (:func:`classify_change`)?

Accelerometer faults are not velocity faults. Before a bias is isolated on axis j, two
explanations of the recent residuals of *all three* axes since a change time t_c are
compared (:func:`classify_change`): a velocity step on axis j alone (r_j = β) and an
accelerometer-bias step in body axes, which shows in every earth axis and rotates with the
attitude (r_k = −(B_k(τ) − B_k(t_c)) Δb, a ramp). The model with the lower BIC wins. An
accelerometer change re-anchors the reference at t_c (``accel_bias`` event with Δb) and
isolates no velocity axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from glmav_observer.records import AxisName

#: Samples of an axis before a candidate change time (classify_change: a step needs a before).
MIN_PRE_SAMPLES = 5

#: Time constants (s) of the low-pass a velocity step may come through: an autopilot's
#: velocity is its estimator's output, which smooths a step in the GPS velocity.
STEP_FILTER_TAUS_S = (0.0, 0.1, 0.2, 0.4)


def classify_change(
    axis: int,
    recent: list[tuple[float, int, float, tuple[float, ...]]],
    sigma_mps: tuple[float, float, float],
) -> tuple[str, tuple[float, float, float], float]:
    """Velocity step on ``axis``, accelerometer-bias step, or an offset of the reference?

    ``recent``: (t, axis, residual, B(t) flat 9) of every axis over the last
    ``change_window_s``. Three explanations of the residuals of all three axes:

    - ``"velocity"``: a step on ``axis`` alone at t_c, r_j = β (1 − e^{−(τ−t_c)/τ_f}) with
      τ_f in :data:`STEP_FILTER_TAUS_S` (a sensor bias, as the autopilot passes it on);
    - ``"accel"``: an accelerometer-bias step at t_c, r_k = −(B_k(τ) − B_k(t_c)) Δb on
      every axis: a ramp that rotates with the attitude;
    - ``"offset"``: a constant offset of ``axis`` over the whole window, no change at all
      (a reference fitted on too little data, e.g. just after a re-anchoring).

    A change must have at least ``MIN_PRE_SAMPLES`` samples of ``axis`` before it (a step
    needs a before); with fewer, ``"undecided"``. Each model is fitted for every candidate
    t_c (a sample time of ``axis``); residuals are weighted by their axis's σ_r; the lowest
    BIC wins (parameters: β, τ_f, t_c; Δb (3), t_c; the offset). Returns (kind, Δb (body,
    m/s²), t_c).
    """
    t = np.array([r[0] for r in recent])
    ax = np.array([r[1] for r in recent], dtype=np.intp)
    on_axis = ax == axis
    cand = t[on_axis][MIN_PRE_SAMPLES:-2]
    if len(cand) < 1:
        return "undecided", (0.0, 0.0, 0.0), math.nan
    res = np.array([r[2] for r in recent])
    Bf = np.array([r[3] for r in recent]).reshape(-1, 3, 3)
    s = np.asarray(sigma_mps)[ax]
    rw = res / s
    n_all = len(t)
    ln_n = math.log(n_all)

    def bic(sse: float, n_params: int) -> float:
        return n_all * math.log(max(sse, 1e-12) / n_all) + n_params * ln_n

    offset = float(np.median(res[on_axis]))
    best: tuple[float, str, tuple[float, float, float], float] = (
        bic(float(np.sum(((res - np.where(on_axis, offset, 0.0)) / s) ** 2)), 1),
        "offset",
        (0.0, 0.0, 0.0),
        float(t[on_axis][0]),
    )
    rows = np.arange(n_all)
    for tc in cand:
        after = t >= tc
        on_j = after & on_axis
        # velocity step on `axis`, through a low-pass of τ_f
        for tau in STEP_FILTER_TAUS_S:
            shape = np.where(on_j, 1.0, 0.0)
            if tau > 0.0:
                shape = shape * (1.0 - np.exp(-np.clip(t - tc, 0.0, None) / tau))
            u = shape / s
            uu = float(u @ u)
            if uu <= 0.0:
                continue
            beta = float(u @ rw) / uu
            b_v = bic(float(np.sum((rw - u * beta) ** 2)), 3 if tau > 0.0 else 2)
            if b_v < best[0]:
                best = (b_v, "velocity", (0.0, 0.0, 0.0), float(tc))
        # accelerometer step: r_k = −(B_k(τ) − B_k(t_c)) Δb for τ ≥ t_c
        Bc = Bf[int(np.searchsorted(t, tc))]
        Dw = (-(Bf - Bc)[rows, ax] * after[:, None]) / s[:, None]
        db = np.linalg.solve(Dw.T @ Dw + np.eye(3) * 1e-6, Dw.T @ rw)
        b_a = bic(float(np.sum((rw - Dw @ db) ** 2)), 4)
        if b_a < best[0]:
            best = (b_a, "accel", (float(db[0]), float(db[1]), float(db[2])), float(tc))
    return best[1], best[2], best[3]


@dataclass(frozen=True, slots=True)
class AccelChange:
    """An accelerometer-bias change found by :func:`classify_change` (isolates no axis)."""

    t_detect_s: float
    t_change_s: float
    delta_bias_body_mps2: tuple[float, float, float]
    triggered_by: AxisName
