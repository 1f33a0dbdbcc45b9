"""The drag model of issue 13's aiding: learnt while healthy, used for a lost axis.

(Over 500 lines: one recursive fit; the pseudo-measurement and the model's own tests read
its internal state, so they stay with it.)

A rotorcraft's accelerometer feels the horizontal drag of the air flowing past it. In body
axes (FRD), per horizontal body axis j ∈ {x, y}:

    f_j = c_j − k_j u_j − q_j s_j|s_j|,   u = Eᵀ(v_ned − w_ned),  s = Eᵀ v_ned,  w_d = 0

with ``f`` the specific force (m/s², what the accelerometer reads), ``u`` the body-frame
airspeed and ``s`` the body-frame ground speed (m/s), ``E`` the body→NED rotation (13)
(:func:`glmav_observer.frames.e_exact`), ``k_j`` (1/s) the linear and ``q_j`` (1/m) the quadratic drag
coefficient, ``c_j`` (m/s²) a constant (accelerometer bias, trim force), ``w`` the wind.
With ``r_j`` the j-th row of Eᵀ (= the j-th column of E, a vector over n, e, d) this is
linear in θ_j = (c_j, k_j, k_j·w_n, k_j·w_e, q_j):

    f_j = φ_jᵀ θ_j,   φ_j = (1, −r_j·v, r_j,n, r_j,e, −s_j|s_j|),  s_j = r_j·v       (A1)

With ``DragModelConfig.control`` each row gains the swash-plate cyclic term b_j ρ_j of
:mod:`.control` (C1): θ_j = (c_j, k_j, k_j·w_n, k_j·w_e, q_j, b_j), φ_j ends with ρ_j, and
every call needs ρ (a sample without it is neither learnt nor used). Without it the model
is the five-parameter one, computed with the same floats.

The quadratic term is taken in the ground speed, not the airspeed (A2: exact without wind;
with wind q·u|u| = q·(s − w_j)|s − w_j| differs by a cross term −2q·w_j·s that shifts the
row's k by −2q·w_j, w_j the wind along the row, which turns with the heading, and by a
sign term where airspeed and ground speed differ in sign: no linear term absorbs either
once the heading varies. On ArduPilot's quads (q/k = 0.14 1/(m/s)) a 4 m/s wind leaves a
residual twice the airspeed form's on the wind tuning flights and a learnt k that is
clearly negative on one row for most of the flight: ``refuse_negative_k``). Taking it in the
estimated airspeed makes the regression depend on its own output, which diverged on
ArduPilot's SITL quad (a 10 m/s phantom wind within 20 s). ArduPilot's quad needs it: on
h_quad_gps_glitch a linear-only batch fit leaves 0.16 m/s² of residual on x, with
q ≈ 0.035 1/m 0.023 m/s².

**Per-axis fit, wind reconciled afterwards.** Each body axis is fitted on its own (two
5-parameter linear least-squares problems). Fitting the wind jointly would make the model
nonlinear (the products k_j·w) for no gain in what is used: the pseudo-measurement needs
only the prediction φ_jᵀθ_j, which each axis's fit gives with its covariance. At a constant
heading c_j and k_j·w enter through the same regressor; the prior on c (σ 0.5 m/s², a
calibrated MEMS bias plus trim, :class:`DragModelConfig`) splits them towards the wind,
which rotates with the heading; the covariance carries what the data leave open, and the
prediction's variance φᵀPφ is what the σ uses. The wind is reported (for display) as the
precision-weighted mean of the two axes' (k_j·w)/k_j (:meth:`DragModel.wind_ne_mps`).

**Learning** (:meth:`DragModel.learn`, while all three axes are healthy, at the velocity
measurement rate, ``f`` averaged by the caller over the interval): exponentially weighted
Bayesian least squares with forgetting *towards the prior* (time constant ``tau_s``,
default 90 s), each sample weighted by 1/σ_f²:

    Λ ← λ Λ + (1 − λ) Λ₀ + φ φᵀ/σ_f²,   η ← λ η + φ f/σ_f²,   λ = exp(−Δt/τ),  θ = Λ⁻¹η

so the information never decays below the weak prior Λ₀ (no covariance wind-up while the
vehicle hovers) and Cov(θ) = Λ⁻¹. It runs in covariance form (RLS: P/λ and a rank-one
update per sample, in plain floats; the prior's share put back exactly every 25 samples).
The residual spread σ_f,j is the exponentially weighted RMS of the one-step-ahead residual
e = f − φᵀθ_prev scaled by σ_f²/(σ_f² + φᵀPφ), floored at 0.02 m/s². A sample whose
residual exceeds 5σ is not learnt (a GPS glitch) unless 25 come in a row.

**Its own tests.** Per body row (:meth:`DragModel.trusted_rows`): enough data (effective
sample count), enough excitation (spread of the body-frame speed r_j·v ≥ 0.3 m/s), a
residual spread below ``sigma_f_max_mps2`` (off by default since issue 32: σ_f sets the
pseudo-measurement's σ, which the aided filter weighs) and k_j clearly positive
(k_j ≥ 5σ(k_j)); only passing rows are used, and none while a row's k is clearly
negative (k_j ≤ −5σ(k_j): drag dissipates, so the law does not hold there; a steady wind
breaks (A2), ``refuse_negative_k``). Both rows refuse themselves while the
model is *changing*: more than 5 samples (exponentially weighted over 5 s) that a model
which had passed these tests could not explain at 5σ (a wind change, a payload; on
a_quad_wind the 4 m/s wind switched on at 63.7 s gave 51 then 90 outliers in the next
two 5 s spans, the clean coax none); the count is frozen during a loss (nothing is
learnt), so a model that was changing at the hand-over is not used for that loss. Per earth axis (validation): while healthy,
every 5th sample the pseudo-measurement of one axis in turn is compared with its
measurement before the sample is learnt; an axis is aided only after ≥ 10 (effective)
validations, with σ inflated by √NEES when the normalised squared error exceeds 1 and
refused above 4 (``nees_max``: beyond a consistent model's 3σ). During a fault: when
both rows see the lost axis their two values must agree within 3σ; if they disagree in
> 20 % of recent calls the model is
:attr:`DragModel.broken` (a wind change, another airframe) until it learns again.

**Pseudo-measurement** (:meth:`DragModel.pseudo_measurement`): with the two measured earth
axes known, each passing body row (A1) gives s_j (the root of the quadratic on the sign
branch of the linear solution; where a fitted q_j < 0 leaves the drag non-monotone there,
k_j + 2q_j|s_j| ≤ 0, the linear part's s_j = a_j/k_j: ``quadratic_fallback_linear``) and
so the lost axis L:

    v_L,j = (s_j − Σ_{i≠L} r_j,i v_i) / r_j,L

with variance (σ_f,j² + φ_jᵀP_jφ_j + the measured axes' noise)/((k_j + 2q_j|s_j|) r_j,L)²;
the two rows are combined by inverse-variance weighting. None when no row passes, the axis
is not observable at this attitude (|r_j,L| < ``row_min``: a level vehicle cannot see d
through horizontal drag), the axis is not in ``aided_axes`` (d is not, by default: the
benchmark's numbers in ``docs/benchmarks/aero.md``), its validation has not passed, or σ
exceeds ``sigma_max_mps`` (the aided filter passes ``AidedAxisConfig.pm_sigma_max_mps``,
∞ by default: in a hover in gusts each pseudo-measurement's σ is 2-4 m/s, their average
what the floor shows useful).

The lost axis's filter and the calls from the estimator: the package docstring
(:mod:`glmav_observer.estimation.aero`) and :mod:`.aided`.

Cost (``benchmarks/aero.py``, same run as a baseline ``e_exact``): ``learn`` ~20 list
operations on 5-vectors per body axis plus a pseudo-measurement every 5th call.
"""

from __future__ import annotations

import copy
import math
from collections.abc import MutableSequence, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from glmav_observer.estimation.aero.rows import RowFits
from glmav_observer.estimation.aero.symmetry import share_drag, shared_drag_chi2

FloatArray = NDArray[np.float64]

#: Number of parameters per body axis: (c, k, k·w_n, k·w_e, q).
N_PARAM = 5
#: Index of k (the linear drag coefficient) and q (the quadratic one) in θ; with the
#: cyclic regressor (``DragModelConfig.control``) its gain b is θ[N_PARAM].
_K = 1
_Q = 4


@dataclass(frozen=True, slots=True)
class DragModelConfig:
    """Settings of :class:`DragModel` (defaults: uninformed, see each comment)."""

    #: forgetting time constant, s (issue 13: slow, ~60-120 s)
    tau_s: float = 90.0
    #: prior σ of θ = (c m/s², k 1/s, k·w_n m/s², k·w_e m/s², q 1/m) around θ₀ = 0. k, k·w
    #: and q: several times any plausible value (k < 1 1/s, |w| < 10 m/s, q < 0.2 1/m),
    #: uninformed. c: 0.5 m/s², the size of a MEMS accelerometer's bias after calibration
    #: (≤ 50 mg) plus a trim force. This one matters: at a constant heading c and k·w enter
    #: (A1) through the same regressor (r_j ≈ const) and only the prior splits them; a
    #: physical c puts the offset where it belongs (the wind, which rotates with the
    #: heading) instead of a constant that does not (measured on f_coax_clean: an
    #: uninformed c gave a 1.4 m/s phantom wind and 2 m/s errors after the next turn)
    prior_sigma_theta: tuple[float, float, float, float, float] = (0.5, 2.0, 5.0, 5.0, 1.0)
    #: σ_f before 10 effective samples, m/s² (large: untrusted until data says otherwise)
    sigma_f_initial_mps2: float = 1.0
    #: floor of σ_f, m/s²: a simulator's accelerometer can be cleaner than any real one
    #: (ArduPilot SITL fits to 0.003); below ~0.02 (a MEMS accelerometer's noise averaged
    #: over 40 ms, plus vibration) the model would claim more than a real sensor supports
    sigma_f_floor_mps2: float = 0.02
    #: effective number of samples before the model may be trusted (≈ 10 s at 10 Hz)
    n_eff_min: float = 100.0
    #: minimum spread (std) of the body-frame speed r_j·v per axis, m/s
    speed_spread_min_mps: float = 0.3
    #: k_j / σ(k_j) at least this (k clearly > 0)
    k_z_min: float = 5.0
    #: σ_f,j at most this, m/s² (a model that explains little is refused). Off (∞) by
    #: default: σ_f already sets the pseudo-measurement's σ (σ_f/k per row), which the
    #: aided filter weighs and rule 5 refuses when no better than dead reckoning; a fixed
    #: 0.15 refused every hover in turbulence, where σ_f is the gusts' drag (0.24-0.49
    #: m/s² in glmav-sitl's `gusts`) while the average of many pseudo-measurements still
    #: carries the airspeed (issue 32: the floor)
    sigma_f_max_mps2: float = math.inf
    #: a sample whose one-step residual exceeds this many σ is not learnt (a GPS glitch)...
    outlier_sigma: float = 5.0
    #: ...unless this many come in a row (the vehicle changed: learn it, σ_f grows)
    outlier_run_max: int = 25
    #: the model is *changing* (a wind change, a payload) while the exponentially weighted
    #: count of outliers over the last ``changing_window_s`` exceeds ``changing_outliers``:
    #: both rows refuse themselves until it decays. A model that fits sees a 5σ outlier in
    #: 6e-7 of its samples per row, so 5 within ~5 s is a change, not noise; an isolated
    #: glitch of a few samples passes. Measured: a_quad_wind's 4 m/s wind switched on at
    #: 63.7 s gave 51 then 90 outliers in the next two 5 s spans, the clean coax none
    #: (docs/benchmarks/aero.md)
    changing_outliers: float = 5.0
    changing_window_s: float = 5.0
    #: the prior's share of the forgetting is put back every this many samples
    prior_every: int = 25
    #: one validation (module docstring) every this many learnt samples
    validate_every: int = 5
    #: validation while healthy: the pseudo-measurement of each axis (one axis per learn
    #: call, in turn, made before the sample is learnt) against the measured value, whose
    #: noise is this σ, m/s
    sigma_v_meas_mps: float = 0.05
    #: effective number of validations per axis before that axis may be aided
    nees_n_min: float = 10.0
    #: normalised squared error above this: the axis is refused; between 1 and this, σ
    #: is inflated by √NEES. A consistent model's mean NEES over n independent
    #: validations is χ²_n/n, σ √(2/n); the nees_n_min = 10 validations of an axis are
    #: correlated over the misfit's 1-3.5 s (docs/benchmarks/aero.md) against one per
    #: 0.6 s per axis, so n ≈ 10/3 and 3σ above 1 is 3.3: a NEES above 4 is a model whose
    #: errors are not its σ's (a bias: inflating σ does not stop the filter averaging it
    #: in). It was 25 (σ inflated up to 5 times); measured on the wind tuning flights, with
    #: ``refuse_negative_k``, the inflated models' losses were worse than dead reckoning in
    #: 1 of 40 standard and 9 of 24 later losses (by up to 0.31 m/s RMS), none at 4 (6 and
    #: 9 left 5 and 9); the price, aiding in 3 fewer of the calm tuning flights' 24 later
    #: losses and 2 of glmav-sitl's 20 calm ones (docs/design/observer-notes.md, "A steady
    #: wind")
    nees_max: float = 4.0
    #: NED axes that may be aided (0 n, 1 e, 2 d). d is off by default: through the body
    #: x/y rows it is seen only as −sinθ·v_d, an extrapolation the learning data barely
    #: check (v_d ≈ 0 in cruise), and on ArduPilot's SITL quads forcing it on made d worse
    #: than dead reckoning in 5 of 40 cases (worst 60 s RMS 1.68 vs 0.16 m/s) and better in
    #: none, where dead reckoning on d holds 0.37 m/s median at 60 s
    #: (docs/benchmarks/aero.md, "aiding forced on")
    aided_axes: tuple[int, ...] = (0, 1)
    #: both rows used and their two values of the lost axis differ by more than this many
    #: σ: the model no longer fits (a wind change during the fault): no pseudo-measurement
    row_consistency_sigma: float = 3.0
    #: ...and when that happens in more than this fraction of the recent two-row
    #: pseudo-measurements (exponential average over ~``inconsistency_window`` calls, at
    #: least 10 of them), every pseudo-measurement is refused until the model learns again
    inconsistency_max: float = 0.2
    inconsistency_window: float = 25.0
    #: gaps longer than this reset nothing but are clipped (a long gap forgets at most this), s
    max_gap_s: float = 5.0
    #: fit the quadratic term q_j·u_j|u_j| (A2); False: linear drag only
    quadratic: bool = True
    #: a sixth parameter per body axis: the gain b_j of the swash-plate cyclic regressor
    #: ρ_j (:mod:`.control`, (C1)); every learn and pseudo-measurement then needs ρ, and a
    #: sample without it is neither learnt nor used. False: the drag model alone
    control: bool = False
    #: prior σ of b_j, m/s² per unit of ρ: uninformed (the default GLMAV's is 1.1)
    prior_sigma_control: float = 5.0
    #: an informed prior on the linear drag k_j of both rows, (mean 1/s, σ 1/s), e.g. from
    #: the vehicle file (equations.md eqs. 7-8 linearised in the rotor's downwash:
    #: k ≈ ρ S C v_dw / (2m), 0.437 1/s for glmav-sitl's default vehicle). With it a row
    #: whose body speed barely varied (a hover: k not identifiable from the data) passes
    #: the spread test while its k is prior-dominated (posterior variance ≥ half the
    #: prior's) and still has to pass the k test (k ≥ k_z_min σ(k)). None (default):
    #: uninformed (σ prior_sigma_theta[1] around 0), the model bit for bit as without it
    prior_k: tuple[float, float] | None = None
    #: validation (module docstring) compares pseudo-measurements up to this σ, m/s: its
    #: z² is normalised by σ, so a large σ is as testable as a small one; capped (at the
    #: aiding's own 1 m/s) no validation accumulates where each pseudo-measurement is
    #: noisy (hover in turbulence, where only their average carries information)
    #: where a fitted q < 0 makes a row's drag non-monotone (k + 2q|s| ≤ 0 at the root:
    #: drag dissipates, so q < 0 is an artefact of a fit on low speeds, e.g. a hover) the
    #: row uses its linear part alone instead of giving nothing. False: such a row is
    #: skipped (in glmav-sitl's `gusts` hover that was 95 % of the pseudo-measurements)
    quadratic_fallback_linear: bool = field(
        default=True,
        metadata={
            "unit": "bool",
            "source": "physics: drag dissipates energy, q ≥ 0",
            "reason": "a negative fitted q leaves no root: use the linear part",
        },
    )
    #: a body row whose k is clearly negative (k ≤ −k_z_min σ(k)) shows that the law does
    #: not hold where the vehicle flies: drag dissipates energy (k ≥ 0), so a force that
    #: grows *with* the speed along a row is something else the form has no term for (in
    #: a steady wind the ground-speed quadratic (A2)'s cross term −2q·w_j·s_j; a heli's
    #: cyclic flapping under velocity control). The other row shares the vehicle, the
    #: wind and the attitude: no pseudo-measurement is made from either while it lasts.
    #: Measured (docs/benchmarks/aero.md): on the ArduPilot wind tuning flights, 7 of the
    #: 8 losses whose aided RMS was above dead reckoning's by more than 0.02 m/s (by up
    #: to 0.77) had one row clearly negative; off: the model bit for bit as before
    refuse_negative_k: bool = field(
        default=True,
        metadata={
            "unit": "bool",
            "source": "physics: drag dissipates energy, k ≥ 0 (z-test at k_z_min)",
            "reason": "a row the law clearly does not fit: the other is no better evidence",
        },
    )
    #: the vehicle's drag is the same along body x and y (a quad, hexa or octa: rotors
    #: symmetric about z; ArduPilot's frame model has one drag for both): a row whose own
    #: speed barely varied (spread test) is updated with the (k, q) of the other row, whose
    #: speed did (:mod:`.symmetry`, (S1)); a row whose data identify its k keeps its own.
    #: A user's statement about the airframe, not learnt; off: the model bit for bit as
    #: before
    symmetric_xy: bool = field(
        default=False,
        metadata={
            "unit": "bool",
            "source": "physics: a symmetric rotor layout has one drag in x and y",
            "reason": "a hovering row's k from the other row's data (S1)",
        },
    )
    #: (S2): a row borrows the other's (k, q) only while their difference's χ² is below
    #: this (2 degrees of freedom: 11.8 is the 99.73 % point, one dimension's 3σ)
    symmetric_gate_chi2: float = field(
        default=11.8,
        metadata={
            "unit": "χ² (2 dof)",
            "source": "statistic: −2 ln(0.0027), the 3σ level in two dimensions",
            "reason": "two rows that each know their drag and disagree keep their own",
        },
    )
    holdout_s: float = field(
        default=10.0,
        metadata={
            "unit": "s",
            "source": "requirement: the aiding's first bound is at +10 s",
            "reason": "validate the model as a loss this long would use it",
        },
    )
    validate_sigma_max_mps: float = field(
        default=math.inf,
        metadata={
            "unit": "m/s",
            "source": "statistic: z² is normalised by σ",
            "reason": "validate the noisy pseudo-measurements that the aiding averages",
        },
    )


class _Used(NamedTuple):
    """θ (rows of floats) and P per body row as the model is used, whether the rows'
    (k, q) are shared (``symmetric_xy``, (S1)), and those rows as fits (for φᵀ P φ:
    the model's own, or a copy holding the shared θ and P)."""

    theta: list[list[float]]
    cov: list[list[list[float]]]
    shared: bool
    rows: RowFits


class PseudoMeasurement(NamedTuple):
    """The lost axis's velocity from the drag model, m/s, and its 1σ, m/s.

    ``sigma_model_mps`` is the part of σ from the coefficients' uncertainty, which is the
    same from one sample to the next (not averaged away by repeated updates)."""

    v_mps: float
    sigma_mps: float
    sigma_model_mps: float


class Trust(NamedTuple):
    """The model's own test: ``ok`` and the reason when not."""

    ok: bool
    reason: str


def _mean_z2(z_sum: Sequence[float], z_n: Sequence[float]) -> FloatArray:
    """Σ z² / Σ weights per NED axis, NaN where there is no weight yet."""
    n = np.asarray(z_n)
    with np.errstate(invalid="ignore", divide="ignore"):
        out: FloatArray = np.where(n > 0.0, np.asarray(z_sum) / n, np.nan)
    return out


class DragModel:
    """Per-body-axis (x, y) drag with wind, learnt online (see the module docstring)."""

    def __init__(self, config: DragModelConfig | None = None) -> None:
        self.config = config or DragModelConfig()
        cfg = self.config
        #: parameters per body axis: the drag's N_PARAM, and b with the cyclic regressor
        self.n_param = N_PARAM + (1 if cfg.control else 0)
        n = self.n_param
        sig0 = list((*cfg.prior_sigma_theta, cfg.prior_sigma_control)[:n])
        th0 = [0.0] * n
        if cfg.prior_k is not None:
            th0[_K], sig0[_K] = cfg.prior_k
        #: prior information Λ₀ = diag(1/σ_θ²), per axis (2, n, n)
        self._lam0 = np.broadcast_to(np.diag(1.0 / np.asarray(sig0) ** 2), (2, n, n)).copy()
        #: Λ₀θ₀ per axis, θ₀ the prior mean (0 but for an informed k: then not None)
        self._lam0_th0: FloatArray | None = (
            np.einsum("jpq,q->jp", self._lam0, np.asarray(th0)) if cfg.prior_k is not None else None
        )
        #: θ and P = Λ⁻¹ = Cov(θ) per axis, with the residual and speed sums, in C arrays
        #: (:class:`.rows.RowFits`: its rank-one update is compiled); as lists for the
        #: tests and the pseudo-measurement (:meth:`_lists`), numpy arrays on demand
        #: (:attr:`_theta`, :attr:`_P`)
        self._rows = RowFits(n, [th0, th0], np.linalg.inv(self._lam0).tolist())
        self._list_cache: tuple[list[list[float]], list[list[list[float]]]] | None = None
        #: (``symmetric_xy``) the lists the shared (k, q) were computed from, and θ, P
        #: after (S1) and whether it applied (:meth:`_use_lists`)
        self._use_cache: tuple[object, _Used] | None = None
        self._np_cache: tuple[FloatArray, FloatArray] | None = None
        #: Σ (1 − λ) since the prior was last put back (module docstring)
        self._prior_due = 0.0
        self._trust_cache: tuple[tuple[bool, bool], tuple[str, str]] | None = None
        #: Σ weights of the rows' exponentially weighted sums (``RowFits.res_sum``: Σ e²
        #: σ_f²/(σ_f² + φᵀPφ); ``s_sum``, ``s2_sum``: of r_j·v, the body ground speed)
        self._n_eff = 0.0
        self._t_last_s: float | None = None
        self.n_learned = 0
        #: samples not learnt because the cyclic regressor was missing (``control``)
        self.n_no_control = 0
        #: samples not learnt as outliers (one-step residual > outlier_sigma σ)
        self.n_outliers = 0
        self._outlier_run = 0
        #: exponentially weighted count of recent outliers (``changing_window_s``) and the
        #: time of the last sample it saw
        self._outliers_recent = 0.0
        self._t_seen_s: float | None = None
        #: per NED axis: exponentially weighted Σ z² and Σ weights of the validation
        #: z = (pseudo-measurement − measured) / √(σ² + σ_meas²), and its last time
        self._nees_sum = [0.0, 0.0, 0.0]
        self._nees_n = [0.0, 0.0, 0.0]
        self._nees_t_s = [math.nan, math.nan, math.nan]
        #: held-out-in-time validation (``holdout_s``): the same per NED axis for the
        #: pseudo-measurements of a copy of the model frozen holdout_s to 2 holdout_s
        #: earlier, that copy, the next one (frozen at the last snapshot) and its time
        self._ho_sum = [0.0, 0.0, 0.0]
        self._ho_n = [0.0, 0.0, 0.0]
        self._ho_t_s = [math.nan, math.nan, math.nan]
        self._ho_model: DragModel | None = None
        self._ho_next: DragModel | None = None
        self._ho_snap_t_s: float | None = None
        #: two-row pseudo-measurements since the last learn: count and EW inconsistency
        self._two_row_n = 0
        self._inconsistency = 0.0

    # ------------------------------------------------------------------ learning
    def learn(
        self,
        t_s: float,
        f_body_mps2: FloatArray | tuple[float, float, float],
        E: FloatArray,
        v_ned_mps: FloatArray | tuple[float, float, float],
        control: tuple[float, float] | None = None,
    ) -> None:
        """One healthy sample: mean specific force over the interval (FRD, m/s²), body→NED
        rotation E (3×3) and the measured NED velocity (m/s); ``control`` the cyclic
        regressors (ρ_x, ρ_y) of (C1) (:mod:`.control`), used (and needed) with
        ``config.control``. Non-finite input is ignored."""
        self.learn_flat(
            t_s,
            [float(x) for x in f_body_mps2],
            np.asarray(E, dtype=np.float64).ravel().tolist(),
            [float(x) for x in v_ned_mps],
            control,
        )

    def learn_flat(
        self,
        t_s: float,
        f: Sequence[float],
        e_flat: Sequence[float],
        v: Sequence[float],
        control: tuple[float, float] | None = None,
    ) -> None:
        """:meth:`learn` with plain floats: ``e_flat`` E row-major (9), as the bank keeps
        it (the estimator's call: no arrays built and taken apart per sample)."""
        cfg = self.config
        if cfg.control and control is None:
            self.n_no_control += 1
            return
        rho = (float(control[0]), float(control[1])) if cfg.control and control else None
        if not math.isfinite(sum(f) + sum(v) + sum(e_flat) + sum(rho or ())):
            return  # a NaN or infinity anywhere makes the sum non-finite
        sig_f = self._sigma_f_list()
        trusted = self._n_eff >= cfg.n_eff_min
        if self._t_seen_s is not None:
            gap = min(max(t_s - self._t_seen_s, 0.0), cfg.max_gap_s)
            self._outliers_recent *= math.exp(-gap / cfg.changing_window_s)
        self._t_seen_s = t_s
        # (A1), (A2): φ_j = (1, −s_j, r_j,n, r_j,e, −s_j|s_j|) per body row, r_j the j-th
        # column of E (and ρ_j with the cyclic regressor, (C1)); the one-step-ahead
        # residual e = f_j − φᵀθ_prev and φᵀPφ (compiled: RowFits.terms)
        outlier = self._rows.terms(
            f, e_flat, v, rho, sig_f, cfg.quadratic, trusted, cfg.outlier_sigma**2
        )
        self._two_row_n = 0
        self._inconsistency = 0.0
        if trusted and self.n_learned % cfg.validate_every == 0:
            self._validate(t_s, f, e_flat, v, rho)
        if outlier:
            self.n_outliers += 1
            self._outlier_run += 1
            if any(self._row_tests_fit()[0]):
                # only a model that passed its tests can be contradicted (the first
                # manoeuvre after a hover is news, not a change)
                self._outliers_recent += 1.0
            if self._outlier_run < cfg.outlier_run_max:
                return  # not learnt; the next sample's forgetting spans this interval too
        else:
            self._outlier_run = 0
        if self._t_last_s is None:
            lam = 1.0
        else:
            dt = min(max(t_s - self._t_last_s, 0.0), cfg.max_gap_s)
            lam = math.exp(-dt / cfg.tau_s)
        self._t_last_s = t_s
        self._n_eff = lam * self._n_eff + 1.0
        # σ_f: residual scaled to σ_f² by its expected variance σ_f² + φᵀPφ; Λ ← λΛ +
        # (1 − λ)Λ₀ + φφᵀ/σ_f² in covariance form: forgetting P/λ and the rank-one
        # (Sherman-Morrison, RLS) update every sample (RowFits.commit); the prior's
        # (1 − λ)Λ₀ collected and put back exactly every ``prior_every`` samples
        self._rows.commit(lam)
        self._prior_due = lam * self._prior_due + (1.0 - lam)
        self.n_learned += 1
        self._list_cache = None
        self._np_cache = None
        self._trust_cache = None
        if self.n_learned % cfg.prior_every == 0:
            self._put_prior_back()

    def _put_prior_back(self) -> None:
        """Λ += w Λ₀ (w the forgetting collected since the last time); θ = Λ⁻¹η with η
        unchanged (θ₀ = 0): θ ← Λ_new⁻¹ Λ_old θ; with an informed k (``prior_k``) η also
        gains w Λ₀θ₀ (forgetting towards the prior's mean)."""
        lam_old = np.linalg.inv(self._P)
        lam_old = 0.5 * (lam_old + np.swapaxes(lam_old, 1, 2))
        eta = np.einsum("jpq,jq->jp", lam_old, self._theta)
        if self._lam0_th0 is not None:
            eta = eta + self._prior_due * self._lam0_th0
        P = np.linalg.inv(lam_old + self._prior_due * self._lam0)
        self._rows.set(np.einsum("jpq,jq->jp", P, eta).tolist(), P.tolist())
        self._prior_due = 0.0
        self._list_cache = None
        self._np_cache = None

    def _validate(
        self,
        t_s: float,
        f: Sequence[float],
        e_flat: Sequence[float],
        v: Sequence[float],
        control: tuple[float, float] | None,
    ) -> None:
        """One axis in turn: how far the pseudo-measurement is from the measurement, of
        the model now (one step ahead) and of its copy frozen ``holdout_s`` to 2
        ``holdout_s`` earlier (held out in time: what a loss that long would have used)."""
        cfg = self.config
        axis = (self.n_learned // cfg.validate_every) % 3
        if cfg.holdout_s > 0.0:
            held = self._held_out_model(t_s)
            if held is not None:
                sums = (self._ho_sum, self._ho_n, self._ho_t_s)
                self._score(held, sums, t_s, f, e_flat, v, control, axis)
        sums = (self._nees_sum, self._nees_n, self._nees_t_s)
        self._score(self, sums, t_s, f, e_flat, v, control, axis)

    def _held_out_model(self, t_s: float) -> DragModel | None:
        """The copy of the model frozen ``holdout_s`` to 2 ``holdout_s`` ago (module
        docstring), None before there is one: a snapshot every ``holdout_s``, the
        previous one validated (held out in time, as a loss that long would use it)."""
        cfg = self.config
        if self._ho_snap_t_s is None or t_s - self._ho_snap_t_s >= cfg.holdout_s:
            gap = math.inf if self._ho_snap_t_s is None else t_s - self._ho_snap_t_s
            # a snapshot older than two periods (a gap in learning) is not this age
            self._ho_model = self._ho_next if gap < 2.0 * cfg.holdout_s else None
            self._ho_next = self._frozen()
            self._ho_snap_t_s = t_s
        return self._ho_model

    def _score(  # noqa: PLR0917 -- the sums, then the sample the model is scored on
        self,
        model: DragModel,
        sums: tuple[MutableSequence[float], MutableSequence[float], MutableSequence[float]],
        t_s: float,
        f: Sequence[float],
        e_flat: Sequence[float],
        v: Sequence[float],
        control: tuple[float, float] | None,
        axis: int,
    ) -> None:
        """``model``'s pseudo-measurement of ``axis`` against the measurement ``v``: its
        z² = (pm − v)² / (σ² + σ_meas²) into ``sums`` (Σ z², Σ weights, last time per
        axis), forgotten with time constant ``tau_s``."""
        cfg = self.config
        pm = model._pseudo_measurement(
            f,
            e_flat,
            v,
            axis,
            validated=False,
            sigma_max_mps=cfg.validate_sigma_max_mps,
            control=control,
        )
        if pm is None:
            return
        z_sum, z_n, z_t = sums
        t_last = z_t[axis]
        lam = 1.0 if math.isnan(t_last) else math.exp(-min(t_s - t_last, cfg.max_gap_s) / cfg.tau_s)
        z_t[axis] = t_s
        z2 = (pm.v_mps - float(v[axis])) ** 2 / (pm.sigma_mps**2 + cfg.sigma_v_meas_mps**2)
        z_sum[axis] = lam * z_sum[axis] + z2
        z_n[axis] = lam * z_n[axis] + 1.0

    def _frozen(self) -> DragModel:
        """A copy of the model as it is now that later learning does not change (the
        state a loss starting now would use), without its own held-out copies."""
        out = copy.copy(self)
        out._rows = self._rows.copy()
        out._nees_sum = list(self._nees_sum)
        out._nees_n = list(self._nees_n)
        out._nees_t_s = list(self._nees_t_s)
        out._ho_sum = list(self._ho_sum)
        out._ho_n = list(self._ho_n)
        out._ho_t_s = list(self._ho_t_s)
        out._ho_model = None
        out._ho_next = None
        out._list_cache = None
        out._np_cache = None
        out._trust_cache = None
        out._use_cache = None
        return out

    @property
    def nees_held_out(self) -> FloatArray:
        """The held-out-in-time validation's mean normalised squared error per NED axis
        (NaN before any)."""
        return _mean_z2(self._ho_sum, self._ho_n)

    def _lists(self) -> tuple[list[list[float]], list[list[list[float]]]]:
        """(θ, P) per row as lists, cached until the next learnt sample."""
        if self._list_cache is None:
            self._list_cache = (self._rows.theta(), self._rows.cov())
        return self._list_cache

    def _use_lists(self) -> _Used:
        """(θ, P, shared) per row as the model is *used* (its tests and pseudo-measurement):
        with ``symmetric_xy``, a row whose body speed barely varied (below the spread
        test) updated by (S1) with the (k, q) of the other row, whose speed did, when the
        rows pass (S2) (:mod:`.symmetry`); else the fit's own (θ, P, False). The learning
        never sees these (it keeps each row's own fit). Cached until the next learnt
        sample."""
        lists = self._lists()
        if not self.config.symmetric_xy:
            return _Used(lists[0], lists[1], False, self._rows)
        if self._use_cache is not None and self._use_cache[0] is lists:
            return self._use_cache[1]
        th, P = self._arrays()
        idx = (_K, _Q)
        used = _Used(lists[0], lists[1], False, self._rows)
        if shared_drag_chi2(th, P, idx) <= self.config.symmetric_gate_chi2:
            # only a row whose own speeds did not vary borrows, and only from a row whose
            # did: a row whose data identify its k keeps its own fit (the symmetry is the
            # user's statement; it is used only where the row's own data are silent)
            spread_ok = self.speed_spread_mps >= self.config.speed_spread_min_mps
            if spread_ok[0] != spread_ok[1]:
                j = 0 if spread_ok[1] else 1
                th_s, P_s = share_drag(th, P, idx, rows=(j,))
                th_l, P_l = th_s.tolist(), P_s.tolist()
                used = _Used(th_l, P_l, True, RowFits(self._rows.n_param, th_l, P_l))
        self._use_cache = (lists, used)
        return used

    def _arrays(self) -> tuple[FloatArray, FloatArray]:
        if self._np_cache is None:
            th, P = self._lists()
            self._np_cache = (np.array(th), np.array(P))
        return self._np_cache

    @property
    def _theta(self) -> FloatArray:
        return self._arrays()[0]

    @property
    def _P(self) -> FloatArray:
        return self._arrays()[1]

    @property
    def broken(self) -> bool:
        """The two body rows have disagreed too often since the last learnt sample."""
        cfg = self.config
        return self._two_row_n >= 10 and self._inconsistency > cfg.inconsistency_max

    @property
    def nees(self) -> FloatArray:
        """Validation's mean normalised squared error per NED axis (NaN before any)."""
        return _mean_z2(self._nees_sum, self._nees_n)

    # ------------------------------------------------------------------ state
    @property
    def theta(self) -> FloatArray:
        """θ per body axis (2, n_param): (c m/s², k 1/s, k·w_n m/s², k·w_e m/s², q 1/m) and,
        with ``config.control``, b (m/s² per unit of ρ, (C1))."""
        return self._theta.copy()

    def _sigma_f_list(self) -> list[float]:
        cfg = self.config
        if self._n_eff < 10.0:
            return [cfg.sigma_f_initial_mps2] * 2
        n = self._n_eff
        return [max(math.sqrt(r / n), cfg.sigma_f_floor_mps2) for r in self._rows.res_sum]

    @property
    def sigma_f_mps2(self) -> FloatArray:
        """Residual spread σ_f per body axis (x, y), m/s²."""
        cfg = self.config
        if self._n_eff < 10.0:
            return np.full(2, cfg.sigma_f_initial_mps2)
        out: FloatArray = np.maximum(
            np.sqrt(np.asarray(self._rows.res_sum) / self._n_eff), cfg.sigma_f_floor_mps2
        )
        return out

    @property
    def cov_theta(self) -> FloatArray:
        """Covariance of θ per body axis (2, n_param, n_param): Λ⁻¹."""
        out: FloatArray = np.array(self._P, dtype=np.float64)
        return out

    @property
    def k_per_s(self) -> FloatArray:
        """Linear drag coefficients (k_x, k_y), 1/s."""
        return self._theta[:, _K].copy()

    @property
    def q_per_m(self) -> FloatArray:
        """Quadratic drag coefficients (q_x, q_y), 1/m."""
        return self._theta[:, _Q].copy()

    @property
    def speed_spread_mps(self) -> FloatArray:
        """Weighted std of the body-frame ground speed r_j·v per axis, m/s."""
        if self._n_eff <= 0.0:
            return np.zeros(2)
        m = np.asarray(self._rows.s_sum) / self._n_eff
        out: FloatArray = np.sqrt(
            np.maximum(np.asarray(self._rows.s2_sum) / self._n_eff - m * m, 0.0)
        )
        return out

    def wind_ne_mps(self) -> tuple[float, float, float] | None:
        """Wind (w_n, w_e) m/s from the two axes' (k·w)/k, precision-weighted, and its σ
        (m/s, the larger of the two components'); None while k is not clearly positive."""
        k = self._theta[:, _K]
        cov = self.cov_theta
        var_k = cov[:, _K, _K]
        if not (k > 3.0 * np.sqrt(var_k)).all():
            return None
        w = self._theta[:, 2:4] / k[:, None]  # (2 axes, n e)
        # first-order variance of a/k: (var a + (a/k)² var k − 2 (a/k) cov(a, k)) / k²
        var_a = cov[:, (2, 3), (2, 3)]
        cov_ak = cov[:, (2, 3), _K]
        var = (var_a + w**2 * var_k[:, None] - 2.0 * w * cov_ak) / (k**2)[:, None]
        wt = 1.0 / np.maximum(var, 1e-12)
        w_ne = (wt * w).sum(axis=0) / wt.sum(axis=0)
        sig = np.sqrt(1.0 / wt.sum(axis=0))
        return float(w_ne[0]), float(w_ne[1]), float(sig.max())

    def trusted_rows(self) -> tuple[NDArray[np.bool_], str]:
        """Which body rows (x, y) pass the model's own test, and why the others do not."""
        ok, failed = self._row_tests()
        return np.array(ok), self._reasons(failed)

    def _row_tests(self) -> tuple[tuple[bool, bool], tuple[str, str]]:
        """Per row: passed, and the name of the first failed test ("" when passed)."""
        if self._outliers_recent > self.config.changing_outliers:
            return ((False, False), ("changing", "changing"))
        return self._row_tests_fit()

    def _row_tests_fit(self) -> tuple[tuple[bool, bool], tuple[str, str]]:
        """:meth:`_row_tests` but for the changing test: plain floats, cached until the
        next learnt sample."""
        if self._trust_cache is not None:
            return self._trust_cache
        cfg = self.config
        if self._n_eff < cfg.n_eff_min:
            out = ((False, False), ("n_eff", "n_eff"))
        else:
            n = self._n_eff
            floor2 = cfg.sigma_f_floor_mps2**2
            ok: list[bool] = []
            failed: list[str] = []
            rows = self._rows
            s_sum, s2_sum, res_sum = rows.s_sum, rows.s2_sum, rows.res_sum
            th, P, shared, _ = self._use_lists()
            spread2_rows = [s2_sum[i] / n - (s_sum[i] / n) ** 2 for i in range(2)]
            for j in range(2):
                spread2 = spread2_rows[j]
                if shared and spread2_rows[1 - j] >= cfg.speed_spread_min_mps**2:
                    # (S1): this row's k is the other row's, identified from that row's
                    # spread of speeds; the k test below still applies to the borrowed k
                    spread2 = spread2_rows[1 - j]
                var_f = max(res_sum[j] / n, floor2)
                k = th[j][_K]
                var_k = P[j][_K][_K]
                if spread2 < cfg.speed_spread_min_mps**2 and not (
                    # with an informed k, a row whose k is the prior's (the data carry at
                    # most as much information on k as the prior: posterior variance ≥
                    # half the prior's) needs no spread; data that low-spread speeds made
                    # "identify" k are refused as before
                    cfg.prior_k is not None and var_k >= 0.5 * cfg.prior_k[1] ** 2
                ):
                    failed.append("spread")
                elif var_f > cfg.sigma_f_max_mps2**2:
                    failed.append("residual")
                elif k < cfg.k_z_min * math.sqrt(var_k):
                    failed.append("k")
                else:
                    failed.append("")
                ok.append(not failed[-1])
            out = ((ok[0], ok[1]), (failed[0], failed[1]))
        self._trust_cache = out
        return out

    def _reasons(self, failed: tuple[str, str]) -> str:
        cfg = self.config
        if failed[0] == "n_eff":
            return f"n_eff {self._n_eff:.0f} < {cfg.n_eff_min:.0f}"
        if failed[0] == "changing":
            return (
                f"changing: {self._outliers_recent:.1f} recent outliers "
                f"> {cfg.changing_outliers:.0f} (wind change?)"
            )
        spread = self.speed_spread_mps
        sig_f = self.sigma_f_mps2
        th, P, _, _ = self._use_lists()  # the k the test judged (shared with symmetric_xy)
        k = np.array([th[0][_K], th[1][_K]])
        z = k / np.sqrt([P[0][_K][_K], P[1][_K][_K]])
        why: list[str] = []
        for j, name in enumerate("xy"):
            if failed[j] == "spread":
                why.append(f"{name}: speed spread {spread[j]:.2f} m/s")
            elif failed[j] == "residual":
                why.append(f"{name}: residual spread {sig_f[j]:.3f} m/s²")
            elif failed[j] == "k":
                why.append(f"{name}: k {k[j]:.3f} 1/s not clearly > 0 (z {z[j]:.1f})")
        return "; ".join(why) if why else "ok"

    def _negative_k(self) -> str:
        """With ``refuse_negative_k``: the row whose k is clearly negative and its z
        (k/σ(k) ≤ −k_z_min, the k test's threshold mirrored), "" when none is."""
        cfg = self.config
        if not cfg.refuse_negative_k or self._n_eff < cfg.n_eff_min:
            return ""
        th, P, _, _ = self._use_lists()
        for j, name in enumerate("xy"):
            k = th[j][_K]
            sigma_k = math.sqrt(P[j][_K][_K])
            if k <= -cfg.k_z_min * sigma_k:
                return f"{name}: k {k:.3f} 1/s clearly < 0 (z {k / sigma_k:.1f}): not drag"
        return ""

    def trust(self) -> Trust:
        """The model's own test (module docstring): trusted when at least one body row
        passes it (the pseudo-measurement uses only rows that do) and no row's k is
        clearly negative (``refuse_negative_k``), else the reasons."""
        ok, why = self.trusted_rows()
        negative = self._negative_k()
        if negative:
            return Trust(False, f"{negative}; {why}")
        return Trust(bool(ok.any()), why)

    # ------------------------------------------------------------------ using it
    def pseudo_measurement(
        self,
        f_body_mps2: FloatArray | tuple[float, float, float],
        E: FloatArray,
        v_ned_known_mps: FloatArray | tuple[float, float, float],
        lost_axis: int,
        *,
        sigma_v_known_mps: float = 0.1,
        row_min: float = 0.2,
        sigma_max_mps: float = 1.0,
        validated: bool = True,
        control: tuple[float, float] | None = None,
    ) -> PseudoMeasurement | None:
        """The lost NED axis (0 n, 1 e, 2 d) from the two body drag equations (module
        docstring), or None (untrusted model, axis unobservable at this attitude, σ too
        large). ``v_ned_known_mps[lost_axis]`` is ignored; the other two are measured with
        noise σ ``sigma_v_known_mps``. ``validated``: only for an axis whose validation
        while healthy passed, σ inflated by √NEES when that is above 1. ``control``: the
        cyclic regressors (ρ_x, ρ_y) of (C1), needed with ``config.control`` (None then:
        no pseudo-measurement)."""
        return self._pseudo_measurement(
            [float(x) for x in f_body_mps2],
            np.asarray(E, dtype=np.float64).ravel().tolist(),
            [float(x) for x in v_ned_known_mps],
            lost_axis,
            sigma_v_known_mps=sigma_v_known_mps,
            row_min=row_min,
            sigma_max_mps=sigma_max_mps,
            validated=validated,
            control=control,
        )

    def _pseudo_measurement(
        self,
        f: Sequence[float],
        e_flat: Sequence[float],
        v_known: Sequence[float],
        lost_axis: int,
        *,
        sigma_v_known_mps: float = 0.1,
        row_min: float = 0.2,
        sigma_max_mps: float = 1.0,
        validated: bool = True,
        control: tuple[float, float] | None = None,
    ) -> PseudoMeasurement | None:
        """:meth:`pseudo_measurement` with plain floats (``e_flat``: E row-major, 9)."""
        if lost_axis not in (0, 1, 2):
            raise ValueError(f"lost_axis must be 0, 1 or 2, got {lost_axis!r}")
        if self.config.control and control is None:
            return None
        rho = (float(control[0]), float(control[1])) if self.config.control and control else None
        v = list(v_known)
        v[lost_axis] = 0.0
        if not math.isfinite(sum(f) + sum(v) + sum(e_flat) + sum(rho or ())):
            return None
        cfg = self.config
        scale = 1.0
        if validated:
            if lost_axis not in cfg.aided_axes:
                return None
            n = self._nees_n[lost_axis]
            if n < cfg.nees_n_min:
                return None
            nees = self._nees_sum[lost_axis] / n
            if self._ho_n[lost_axis] >= cfg.nees_n_min:
                # held out in time (``holdout_s``): the larger of the two decides
                nees = max(nees, self._ho_sum[lost_axis] / self._ho_n[lost_axis])
            if not nees <= cfg.nees_max:
                return None
            if self._negative_k():  # ``refuse_negative_k``: the law does not hold here
                return None
            scale = math.sqrt(max(1.0, nees))
        ok, _ = self._row_tests()
        sig_f = self._sigma_f_list()
        th_rows, _, shared, used_rows = self._use_lists()
        known = [i for i in range(3) if i != lost_axis]
        parts: list[tuple[float, float, float]] = []
        for j in range(2):
            r = (e_flat[j], e_flat[3 + j], e_flat[6 + j])  # r_j: the j-th column of E
            r_lost = r[lost_axis]
            if not ok[j] or abs(r_lost) < row_min:
                continue
            c, k, kwn, kwe, q = th_rows[j][:N_PARAM]
            # (A2): f_j = a_j − k s_j − q s_j|s_j| with a_j = c + r_n k·w_n + r_e k·w_e
            # (+ b_j ρ_j, (C1)); solve for s_j = r_j·v (monotone while k + 2q|s| > 0): the
            # root of the quadratic on the sign branch of the linear solution
            a_j = c + r[0] * kwn + r[1] * kwe - f[j]
            if rho is not None:
                a_j += th_rows[j][N_PARAM] * rho[j]
            s_j = a_j / k
            if q != 0.0:
                sg = 1.0 if s_j >= 0.0 else -1.0
                disc = k * k + 4.0 * q * sg * a_j
                if disc >= 0.0:
                    s_j = sg * 2.0 * abs(a_j) / (k + math.sqrt(disc))  # stable form of the root
            slope = k + 2.0 * q * abs(s_j)  # −∂f_j/∂s_j
            if slope <= 0.0:
                if not cfg.quadratic_fallback_linear or k <= 0.0:
                    continue
                # a fitted q < 0 (drag dissipates: a fit artefact of low speeds) makes the
                # drag non-monotone here: the row's linear part alone
                s_j, slope = a_j / k, k
            g2 = (slope * r_lost) ** 2  # (∂f_j/∂v_L)²
            v_j = (s_j - sum(r[i] * v[i] for i in known)) / r_lost
            phi: tuple[float, ...] = (1.0, -s_j, r[0], r[1], -s_j * abs(s_j))
            if rho is not None:
                phi = (*phi, rho[j])
            var_model = used_rows.quad_form(j, phi) / g2  # φᵀ P_j φ (after (S1) if shared)
            var_white = (
                sig_f[j] ** 2 + sum((slope * r[i] * sigma_v_known_mps) ** 2 for i in known)
            ) / g2
            parts.append((v_j, var_white + var_model, var_model))
        if not parts:
            return None
        if len(parts) == 2:
            (v_x, var_x, _), (v_y, var_y, _) = parts
            bad = (v_x - v_y) ** 2 > cfg.row_consistency_sigma**2 * (var_x + var_y)
            if validated:
                self._two_row_n += 1
                self._inconsistency += (float(bad) - self._inconsistency) / cfg.inconsistency_window
            if bad:
                return None
        if validated and self.broken:
            return None
        den = sum(1.0 / var_j for _, var_j, _ in parts)
        var = 1.0 / den
        v_lost = var * sum(v_j / var_j for v_j, var_j, _ in parts)
        var_model_comb = sum((var / var_j) ** 2 * var_m for _, var_j, var_m in parts)
        if shared and len(parts) == 2:
            # (S1): one row borrowed the other's (k, q), so their model parts are
            # correlated: taken as fully correlated (an upper bound), (Σ w_j σ_m,j)² with
            # w_j = var/var_j, beside the white parts' Σ w_j² (var_j − var_m,j)
            var_model_comb = sum(var / var_j * math.sqrt(var_m) for _, var_j, var_m in parts) ** 2
            var = var_model_comb + sum(
                (var / var_j) ** 2 * (var_j - var_m) for _, var_j, var_m in parts
            )
        sigma = scale * math.sqrt(var)
        if sigma > sigma_max_mps:
            return None
        return PseudoMeasurement(v_lost, sigma, scale * math.sqrt(var_model_comb))
