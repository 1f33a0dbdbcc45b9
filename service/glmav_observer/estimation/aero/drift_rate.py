"""How fast dead reckoning really drifts on this vehicle: a run-time statistic (issue 32).

The lost axis's dead reckoning has a σ from a noise model (:class:`~.aided.AidedAxisConfig`:
an acceleration error of σ_b = 0.05 m/s² horizontally, constant since the hand-over). That
σ is a prior: ten times too large on ArduPilot's SITL (an exact accelerometer; its dead
reckoning is off by 0.17 m/s after 10 s where σ says 0.53) and several times too small
with glmav-sitl's autopilot sensor profile (a lagging, noisy attitude). Both hurt the
aiding's safety rules. Rule 2 compares the pseudo-measurements with the dead reckoning
against their combined σ: with a dead reckoning's σ three times its error, a model biased
by twice the dead reckoning's error passes, and the aided estimate ends worse than dead
reckoning (hf_quad_slow_imu25, held out). With a σ too small, σ covers the error 89 % of
the time instead of 95 % (glmav-sitl in wind, autopilot profile).

While every axis is healthy the vehicle's own data say how far a dead reckoning started
at any past instant would have drifted: :class:`DriftRate` keeps, once a second, the
integrated earth-frame acceleration A = ∫ E Γ dt, the integrated attitude B = ∫ E dt (the
estimator's own integrals, ``HeldInputs``) and the measured velocity v. For every past
instant t_i with a ``fit_window_s`` of data before it and a lag τ after it, it does what
the estimator does at a hand-over, then checks it:

1. the body-frame accelerometer bias b_i fitted over [t_i − W, t_i] from 1 s rows
   ΔA − Δv = ΔB b, each row weighted by its noise (two velocity measurements, √2 σ_v),
   with a prior of σ ``bias_prior_mps2`` on each component (:func:`body_bias_fit`, the
   same fit the aero benchmark uses as the service's stand-in);
2. the dead reckoning's error at t_i + τ against the measurement:
   e_i(τ) = (A(t_i+τ) − A(t_i)) − (v(t_i+τ) − v(t_i)) − (B(t_i+τ) − B(t_i)) b_i.

The statistic per NED axis is the *drift rate* r = max over the lags of RMS_i e_i(τ) / τ
(m/s²): the constant acceleration error that would have produced the largest realised
dead-reckoning error seen at any lag. It includes the velocity measurement's noise (√2 σ_v
/ τ: 0.03 m/s² at τ = 5 s with σ_v = 0.1), so it errs large. None until at least
``min_windows`` instants have been checked at the shortest lag.

Its two uses (:class:`~.aided.AidedAxis`, ``drift_rate_mps2``):

- **rule 2's test** uses the smaller of the two σ of the dead reckoning (the noise
  model's, and √(P₀ + (r τ)²) from the statistic): the test must not pass a model because
  the dead reckoning's σ is conservative. A smaller σ can only make the test stop the
  aiding sooner (never worse than dead reckoning; the aiding's gain may be lost);
- **the σ published**: the noise model's σ_b is raised to r where r is larger (the σ must
  cover the error); it is never lowered (a statistic from a short flight may be small by
  chance: for coverage the prior stands).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class DriftRateConfig:
    """Settings of :class:`DriftRate` (the module docstring says how each is used)."""

    #: the bias fit before each checked instant, s: the aero benchmark's (its
    #: ``BIAS_WINDOW_S``) stand-in for the service's FDI fit before a hand-over
    fit_window_s: float = field(
        default=15.0,
        metadata={
            "unit": "s",
            "source": "requirement: the benchmark's bias fit window",
            "reason": "the checked dead reckonings start as the estimator's does",
        },
    )
    #: the lags at which the realised dead-reckoning error is checked, s: from one
    #: measurement's noise (√2 σ_v / τ small against the drift from 5 s on) to a third of
    #: the benchmark's 60 s horizon (the longest a ~90 s ArduPilot flight can check a few
    #: times before its losses)
    lags_s: tuple[float, ...] = field(
        default=(5.0, 10.0, 20.0),
        metadata={
            "unit": "s",
            "source": "requirement: noise floor to horizon",
            "reason": "lags where the drift, not the velocity noise, dominates",
        },
    )
    #: one sample kept per this long, s (the bias fit's 1 s rows)
    sample_s: float = field(
        default=1.0,
        metadata={
            "unit": "s",
            "source": "requirement: the benchmark's BIAS_WINDOW_S rows",
            "reason": "one sample per row of the bias fit (1 s of integrals)",
        },
    )
    #: samples older than this are forgotten, s (the drag model's forgetting, 90 s, plus
    #: the fit window: what the vehicle does now, not an hour ago)
    span_s: float = field(
        default=105.0,
        metadata={
            "unit": "s",
            "source": "requirement: the drag model's memory (tau_s) + fit_window_s",
            "reason": "the statistic describes the vehicle as it flies now",
        },
    )
    #: checked instants at the shortest lag before the statistic is given
    min_windows: int = field(
        default=5,
        metadata={
            "unit": "count",
            "source": "statistic: an RMS of fewer is one sample's size",
            "reason": "an RMS needs a few instants",
        },
    )
    #: the velocity measurement's noise the fit's rows are weighted by, m/s
    sigma_v_mps: float = field(
        default=0.1,
        metadata={
            "unit": "m/s",
            "source": "requirement: the hand-over σ (SIGMA_HANDOVER_MPS)",
            "reason": "weight of a 1 s row of the bias fit",
        },
    )
    #: prior σ of each body-frame bias component in the fit, m/s²
    bias_prior_mps2: float = field(
        default=0.5,
        metadata={
            "unit": "m/s²",
            "source": "physics: a MEMS bias ≤ 50 mg",
            "reason": "steadies an unobserved direction of the fit",
        },
    )


def body_bias_fit(
    d_b: FloatArray, d_a_minus_v: FloatArray, sigma_v_mps: float, prior_mps2: float
) -> FloatArray:
    """The body-frame accelerometer bias b (m/s²) from rows ΔA − Δv = ΔB b: ``d_b`` (k, 3, 3)
    the rows' ∫E dt, ``d_a_minus_v`` (k, 3) their ∫EΓ dt less the measured velocity change;
    each row weighted by its noise (two velocity measurements, √2 ``sigma_v_mps``), a prior
    of σ ``prior_mps2`` on each component. (Weighted, the prior only steadies an
    unobserved direction; unweighted it shrank a 0.56 m/s² bias by ~20 % over 15 rows.)"""
    A = d_b.reshape(-1, 3)
    rhs = d_a_minus_v.reshape(-1)
    w = 1.0 / (2.0 * sigma_v_mps**2)
    prior = np.eye(3) / prior_mps2**2
    b = np.linalg.solve(w * (A.T @ A) + prior, w * (A.T @ rhs))
    return np.asarray(b, dtype=np.float64)


class DriftRate:
    """The realised dead-reckoning drift of a vehicle while healthy (module docstring)."""

    def __init__(self, config: DriftRateConfig | None = None) -> None:
        self.config = config or DriftRateConfig()
        #: (t s, A (3) m/s, B (9) s, v (3) m/s) once per ``sample_s``
        self._samples: deque[tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, ...]]]
        self._samples = deque()
        self._cache: tuple[float, float, float] | None = None
        self._dirty = False

    def clear(self) -> None:
        """Forget every sample (the integrals restarted)."""
        self._samples.clear()
        self._cache = None
        self._dirty = False

    def observe(
        self,
        t_s: float,
        a_int_ned_mps: Sequence[float],
        b_int_flat_s: Sequence[float],
        v_meas_ned_mps: Sequence[float],
    ) -> None:
        """A healthy measurement ``v_meas_ned_mps`` at ``t_s`` with the estimator's
        integrals then: A = ∫ E Γ dt (NED, m/s) and B = ∫ E dt (row-major 3×3, s), both
        cumulative from any origin (only their differences are used)."""
        cfg = self.config
        s = self._samples
        if s and (t_s <= s[-1][0] or t_s - s[-1][0] > cfg.span_s):
            self.clear()  # time went back or a gap longer than the memory: start afresh
        if s and t_s - s[-1][0] < cfg.sample_s:
            return
        a = tuple(float(x) for x in a_int_ned_mps)
        b = tuple(float(x) for x in b_int_flat_s)
        v = tuple(float(x) for x in v_meas_ned_mps)
        if not all(math.isfinite(x) for x in (*a, *b, *v)):
            return
        s.append((t_s, a, b, v))
        while s[-1][0] - s[0][0] > cfg.span_s:
            s.popleft()
        self._dirty = True

    def rate_mps2(self) -> tuple[float, float, float] | None:
        """Per NED axis, the drift rate r (m/s², module docstring), or None while fewer
        than ``min_windows`` instants are checked."""
        if self._dirty:
            self._cache = self._compute()
            self._dirty = False
        return self._cache

    def _compute(self) -> tuple[float, float, float] | None:
        cfg = self.config
        if len(self._samples) < 2:
            return None
        t = np.array([x[0] for x in self._samples])
        A = np.array([x[1] for x in self._samples])
        B = np.array([x[2] for x in self._samples]).reshape(-1, 3, 3)
        V = np.array([x[3] for x in self._samples])
        E = A - V  # the integrated acceleration less the measured velocity
        n_fit = round(cfg.fit_window_s / cfg.sample_s)
        best: FloatArray | None = None
        n_checked = 0
        for k, lag_s in enumerate(cfg.lags_s):
            ms: list[FloatArray] = []
            for i in range(n_fit, len(t)):
                j = int(np.searchsorted(t, t[i] + lag_s - 0.5 * cfg.sample_s))
                if j >= len(t):
                    break
                if t[i] - t[i - n_fit] > 1.5 * cfg.fit_window_s:
                    continue  # a gap in the fit window: not the estimator's fit
                d_b = np.diff(B[i - n_fit : i + 1], axis=0)
                d_e = np.diff(E[i - n_fit : i + 1], axis=0)
                b = body_bias_fit(d_b, d_e, cfg.sigma_v_mps, cfg.bias_prior_mps2)
                err = (E[j] - E[i]) - (B[j] - B[i]) @ b
                ms.append(err / (t[j] - t[i]))
            if k == 0:
                n_checked = len(ms)
            if not ms:
                break
            rate: FloatArray = np.sqrt(np.mean(np.square(np.asarray(ms)), axis=0))
            best = rate if best is None else np.maximum(best, rate)
        if best is None or n_checked < cfg.min_windows:
            return None
        return (float(best[0]), float(best[1]), float(best[2]))
