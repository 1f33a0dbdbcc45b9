"""The observer bank: the four configurations (full, c1, c2, c3) of one vehicle, or of many.

:class:`ObserverBank` holds one vehicle's state and advances all configurations with the
exact zero-order-hold update of (16) (:func:`~glmav_observer.estimation.observer.zoh_step`).
For the exact E it runs a plain-float twin of the closed form (numpy call overhead dominates
for 4×3 arrays); tests check it against the numpy form to 1e-12. :class:`BatchedBank` does the
same for ``n`` vehicles with numpy, vectorised over vehicles and configurations.

Frames and units: ``euler_rad`` ZYX (φ, θ, ψ), ``omega_body_radps`` FRD, ``f_body_mps2`` the
accelerometer's specific force in FRD (reads (0, 0, −g) at rest and level),
``v_ned_meas_mps`` the measured NED velocity (NaN on an axis = not measured).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

from glmav_observer.estimation.observer import (
    G_MPS2,
    BoolArray,
    EForm,
    FloatArray,
    NonFiniteInputError,
    ShapeError,
    e_matrix,
    gamma_body_mps2,
    phi1_phi2_scalar,
    phi_terms,
    rotate,
    rotate_t,
    zoh_earth,
    zoh_step,
)
from glmav_observer.records import CONFIGS

#: Which NED axes (n, e, d) each configuration measures, in CONFIGS order (full, c1, c2, c3).
CONFIG_MASKS: BoolArray = np.array(
    [
        [True, True, True],  # full: C = I
        [True, True, False],  # c1: C1 = [[1,0,0],[0,1,0]], down lost
        [False, True, True],  # c2: C2 = [[0,1,0],[0,0,1]], north lost
        [True, False, True],  # c3: C3 = [[1,0,0],[0,0,1]], east lost
    ],
    dtype=bool,
)
CONFIG_MASKS.setflags(write=False)

#: γ (1/s) per configuration. c1..c3: the paper's (49). full: the minimiser of the steady
#: error² (b/γ)² + γ σ_y²/(2 f) with accelerometer bias b = 0.2 m/s², velocity noise
#: σ_y = 0.05 m/s at f = 30 Hz (design.md): γ³ = 4 f b²/σ_y² → γ ≈ 12.4 (docs/observer.md).
DEFAULT_GAMMA: dict[str, float] = {"full": 12.0, "c1": 90.0, "c2": 70.0, "c3": 70.0}

_MASK_TUPLES = tuple(tuple(bool(b) for b in row) for row in CONFIG_MASKS)
#: The masks of a step where every measured axis is valid and allowed (identity-checked).
_STANDARD_MASKS: list[tuple[bool, bool, bool]] = list(_MASK_TUPLES)  # type: ignore[arg-type]


def _gammas(gamma_per_config: Mapping[str, float] | None) -> tuple[float, ...]:
    merged = dict(DEFAULT_GAMMA)
    if gamma_per_config is not None:
        unknown = set(gamma_per_config) - set(CONFIGS)
        if unknown:
            raise ValueError(f"gamma_per_config: unknown configuration(s) {sorted(unknown)}")
        merged.update({k: float(v) for k, v in gamma_per_config.items()})
    for k, v in merged.items():
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"gamma_per_config[{k!r}] must be finite and > 0, got {v!r}")
    return tuple(merged[c] for c in CONFIGS)


def _config_index(config: str) -> int:
    try:
        return CONFIGS.index(config)
    except ValueError:
        raise ValueError(f"unknown configuration {config!r}; expected one of {CONFIGS}") from None


def _vec3(name: str, value: ArrayLike) -> list[float]:
    if type(value) is np.ndarray and value.shape == (3,) and value.dtype == np.float64:
        fast: list[float] = value.tolist()  # the common case, ~0.1 µs
        return fast
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise ShapeError(f"{name}: expected shape (3,), got {arr.shape}")
    out: list[float] = arr.tolist()
    return out


def _e_exact_list(phi: float, th: float, psi: float) -> list[float]:
    """(13) as a flat row-major list of plain floats."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(th), math.cos(th)
    sp, cp = math.sin(psi), math.cos(psi)
    return [
        ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp,
        ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp,
        -st, sf * ct, cf * ct,
    ]  # fmt: skip


def _update_one(  # noqa: PLR0917 -- the inputs of one step, in the API order
    x: list[float],
    E: list[float],
    we: list[float],
    a: list[float],
    y: list[float],
    m: tuple[bool, bool, bool],
    e: float,
    hp1: float,
    h2p2: float,
    g: float,
    h: float,
) -> list[float]:
    """One configuration, exact E, two or three measured axes: the closed form of
    ``observer._zoh_exact_e`` in plain floats. ``e = exp(−γh)``, ``hp1 = h φ1(−γh)``,
    ``h2p2 = h² φ2(−γh)``."""
    x0, x1, x2 = x
    z = [
        E[0] * x0 + E[1] * x1 + E[2] * x2,
        E[3] * x0 + E[4] * x1 + E[5] * x2,
        E[6] * x0 + E[7] * x1 + E[8] * x2,
    ]  # z = E x̂
    if m[0] and m[1] and m[2]:  # C = I: ż = a − ω_e × y + γ (y − z)
        y0, y1, y2 = y
        w0, w1, w2 = we
        z = [
            e * z[0] + hp1 * (a[0] - (w1 * y2 - w2 * y1) + g * y0),
            e * z[1] + hp1 * (a[1] - (w2 * y0 - w0 * y2) + g * y1),
            e * z[2] + hp1 * (a[2] - (w0 * y1 - w1 * y0) + g * y2),
        ]
    else:  # lost axis l, measured m1 = l+1, m2 = l+2 (cyclic)
        l_ = 0 if not m[0] else (1 if not m[1] else 2)
        m1 = (l_ + 1) % 3
        m2 = (l_ + 2) % 3
        wl, wm1, wm2 = we[l_], we[m1], we[m2]
        ym1, ym2 = y[m1], y[m2]
        zl0 = z[l_]
        cl = a[l_] - (wm1 * ym2 - wm2 * ym1)  # ż_l = (a − ω_e × Ȳ)_l
        z[l_] = zl0 + h * cl
        z[m1] = e * z[m1] + hp1 * (a[m1] + wl * ym2 + g * ym1 - wm2 * zl0) - h2p2 * wm2 * cl
        z[m2] = e * z[m2] + hp1 * (a[m2] - wl * ym1 + g * ym2 + wm1 * zl0) + h2p2 * wm1 * cl
    z0, z1, z2 = z
    return [
        E[0] * z0 + E[3] * z1 + E[6] * z2,
        E[1] * z0 + E[4] * z1 + E[7] * z2,
        E[2] * z0 + E[5] * z1 + E[8] * z2,
    ]  # x̂ = Eᵀ z


def _step_standard(  # noqa: PLR0917 -- the inputs of one step, in the API order
    xs: list[list[float]],
    E: list[float],
    we: list[float],
    a: list[float],
    y: list[float],
    terms: list[tuple[float, float, float]],
    gammas: tuple[float, ...],
    h: float,
) -> list[list[float]]:
    """The four standard configurations (all of y valid and allowed), unrolled.

    The same closed form as :func:`_update_one` with the lost axes fixed: full none, c1 the
    down axis, c2 north, c3 east. ``terms[i] = (e^{−γh}, h φ1(−γh), h² φ2(−γh))``.
    """
    e00, e01, e02, e10, e11, e12, e20, e21, e22 = E
    w0, w1, w2 = we
    a0, a1, a2 = a
    y0, y1, y2 = y
    out: list[list[float]] = []
    for i in range(4):
        u0, u1, u2 = xs[i]
        z0 = e00 * u0 + e01 * u1 + e02 * u2  # z = E x̂
        z1 = e10 * u0 + e11 * u1 + e12 * u2
        z2 = e20 * u0 + e21 * u1 + e22 * u2
        e, p1, p2 = terms[i]
        g = gammas[i]
        if i == 0:  # full: ż = a − ω_e × y + γ (y − z)
            z0, z1, z2 = (
                e * z0 + p1 * (a0 - (w1 * y2 - w2 * y1) + g * y0),
                e * z1 + p1 * (a1 - (w2 * y0 - w0 * y2) + g * y1),
                e * z2 + p1 * (a2 - (w0 * y1 - w1 * y0) + g * y2),
            )
        elif i == 1:  # c1: down (2) lost, ż_2 = a_2 − (ω_e × Ȳ)_2
            c = a2 - (w0 * y1 - w1 * y0)
            z0, z1, z2 = (
                e * z0 + p1 * (a0 + w2 * y1 + g * y0 - w1 * z2) - p2 * w1 * c,
                e * z1 + p1 * (a1 - w2 * y0 + g * y1 + w0 * z2) + p2 * w0 * c,
                z2 + h * c,
            )
        elif i == 2:  # c2: north (0) lost
            c = a0 - (w1 * y2 - w2 * y1)
            z0, z1, z2 = (
                z0 + h * c,
                e * z1 + p1 * (a1 + w0 * y2 + g * y1 - w2 * z0) - p2 * w2 * c,
                e * z2 + p1 * (a2 - w0 * y1 + g * y2 + w1 * z0) + p2 * w1 * c,
            )
        else:  # c3: east (1) lost
            c = a1 - (w2 * y0 - w0 * y2)
            z0, z1, z2 = (
                e * z0 + p1 * (a0 - w1 * y2 + g * y0 + w2 * z1) + p2 * w2 * c,
                z1 + h * c,
                e * z2 + p1 * (a2 + w1 * y0 + g * y2 - w0 * z1) - p2 * w0 * c,
            )
        out.append(
            [
                e00 * z0 + e10 * z1 + e20 * z2,  # x̂ = Eᵀ z
                e01 * z0 + e11 * z1 + e21 * z2,
                e02 * z0 + e12 * z1 + e22 * z2,
            ]
        )
    return out


class ObserverBank:
    """All four configurations of one vehicle (CONFIGS order: full, c1, c2, c3).

    ``step`` advances every configuration by ``dt_s`` with the inputs held (exact ZOH of
    (16)); inputs are validated before any state changes. A NaN axis of the measured
    velocity is treated as not measured (``last_meas_mask`` shows what was used).
    """

    def __init__(
        self,
        gamma_per_config: Mapping[str, float] | None = None,
        e_form: EForm = "exact",
        g_mps2: float = G_MPS2,
    ) -> None:
        if e_form not in ("exact", "small_angle"):
            raise ValueError(f"e_form must be 'exact' or 'small_angle', got {e_form!r}")
        self.e_form: EForm = e_form
        self.g_mps2 = float(g_mps2)
        self.gamma_gain: tuple[float, ...] = _gammas(gamma_per_config)
        self._gamma_arr = np.array(self.gamma_gain)
        self._x: list[list[float]] = [[0.0, 0.0, 0.0] for _ in CONFIGS]
        self._E_last: list[float] | FloatArray = np.eye(3)
        self._masks_last: list[tuple[bool, bool, bool]] = _STANDARD_MASKS
        self._h_cached = math.nan
        self._terms: list[tuple[float, float, float]] = []

    @property
    def last_meas_mask(self) -> BoolArray:
        """(4, 3) bool: the NED axes each configuration used in the last step."""
        return np.array(self._masks_last, dtype=bool)

    @property
    def e_last(self) -> FloatArray:
        """(3, 3) the E of the last step (identity before the first)."""
        return np.array(self._E_last, dtype=np.float64).reshape(3, 3)

    def set_gamma(self, config: str, gamma: float) -> None:
        """Change one configuration's gain γ (1/s; finite, > 0) from the next step on."""
        if not (math.isfinite(gamma) and gamma > 0.0):
            raise ValueError(f"gamma must be finite and > 0, got {gamma!r}")
        g = list(self.gamma_gain)
        g[_config_index(config)] = float(gamma)
        self.gamma_gain = tuple(g)
        self._gamma_arr = np.array(self.gamma_gain)
        self._h_cached = math.nan  # the φ-terms depend on γ

    # ------------------------------------------------------------------ state access
    @property
    def x_hat_body_mps(self) -> FloatArray:
        """(4, 3) body-frame (FRD) velocity estimates, m/s, CONFIGS order (a copy)."""
        return np.array(self._x)

    def x_hat_ned_mps(self) -> FloatArray:
        """(4, 3) NED velocity estimates E x̂ under the attitude of the last step (a copy)."""
        return np.array(self._x) @ self.e_last.T

    def set_state_body(self, config: str, v_body_mps: ArrayLike) -> None:
        """Overwrite one configuration's body-frame state (m/s)."""
        i = _config_index(config)
        v = _vec3("v_body_mps", v_body_mps)
        if not all(math.isfinite(c) for c in v):
            raise NonFiniteInputError(f"v_body_mps: NaN or infinite value in {v!r}")
        self._x[i] = v

    def set_state_ned(self, config: str, v_ned_mps: ArrayLike, euler_rad: ArrayLike) -> None:
        """Hand-over: start ``config`` from an earth-frame velocity at attitude ``euler_rad``.

        x̂ = E⁻¹ v_ned (= Eᵀ v_ned for the exact E) with this bank's E form.
        """
        i = _config_index(config)
        v = np.asarray(_vec3("v_ned_mps", v_ned_mps))
        eul = np.asarray(_vec3("euler_rad", euler_rad))
        if not (np.isfinite(v).all() and np.isfinite(eul).all()):
            raise NonFiniteInputError(f"set_state_ned: NaN or infinite in {v!r} or {eul!r}")
        E = e_matrix(eul, self.e_form)
        self._x[i] = np.linalg.solve(E, v).tolist()

    def reset(self, v_body_mps: ArrayLike | None = None) -> None:
        """Set every configuration to ``v_body_mps`` ((3,) or (4, 3), default zero)."""
        if v_body_mps is None:
            self._x = [[0.0, 0.0, 0.0] for _ in CONFIGS]
            return
        arr = np.asarray(v_body_mps, dtype=np.float64)
        if arr.shape not in ((3,), (4, 3)):
            raise ShapeError(f"v_body_mps: expected (3,) or (4, 3), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise NonFiniteInputError(f"v_body_mps: NaN or infinite value in {arr.tolist()!r}")
        self._x = np.broadcast_to(arr, (4, 3)).tolist()

    # ------------------------------------------------------------------ update
    def _masks(self, y: list[float], meas_mask: ArrayLike | None) -> list[tuple[bool, bool, bool]]:
        fin = [math.isfinite(c) for c in y]
        if meas_mask is None:
            if fin[0] and fin[1] and fin[2]:
                return _STANDARD_MASKS
            allowed = np.broadcast_to(np.array(fin), (4, 3))
        else:
            mm = np.asarray(meas_mask)
            if mm.dtype != np.bool_ or mm.shape not in ((3,), (4, 3)):
                raise ShapeError(
                    f"meas_mask: expected bool (3,) or (4, 3), got {mm.dtype} {mm.shape}"
                )
            allowed = np.broadcast_to(mm, (4, 3)) & np.array(fin)
        eff = CONFIG_MASKS & allowed
        return [(bool(r[0]), bool(r[1]), bool(r[2])) for r in eff.tolist()]

    def step(  # noqa: PLR0917 -- the inputs of one step, in the API order
        self,
        dt_s: float,
        euler_rad: ArrayLike,
        omega_body_radps: ArrayLike,
        f_body_mps2: ArrayLike,
        v_ned_meas_mps: ArrayLike,
        meas_mask: ArrayLike | None = None,
    ) -> None:
        """Advance all configurations by ``dt_s`` (s) with every input held.

        ``meas_mask``: None, (3,) or (4, 3) bool of NED axes allowed (e.g. an axis isolated
        as faulty is masked out); NaN axes of ``v_ned_meas_mps`` are never used. Raises
        :class:`ShapeError` / :class:`NonFiniteInputError` / ``ValueError`` (dt_s < 0)
        before any state changes.
        """
        h = float(dt_s)
        phi, th, psi = eul = _vec3("euler_rad", euler_rad)
        w = _vec3("omega_body_radps", omega_body_radps)
        f = _vec3("f_body_mps2", f_body_mps2)
        y = _vec3("v_ned_meas_mps", v_ned_meas_mps)
        if not math.isfinite(h + phi + th + psi + w[0] + w[1] + w[2] + f[0] + f[1] + f[2]):
            for name, vals in (("dt_s", [h]), ("euler_rad", eul), ("omega_body_radps", w),
                               ("f_body_mps2", f)):  # fmt: skip
                if not all(math.isfinite(c) for c in vals):
                    raise NonFiniteInputError(f"{name}: NaN or infinite value in {vals!r}")
            raise NonFiniteInputError("inputs overflow (sum of |values| is not finite)")
        if h < 0.0:
            raise ValueError(f"dt_s must be >= 0, got {h!r}")
        masks = self._masks(y, meas_mask)
        self._masks_last = masks
        if self.e_form == "exact" and all(m[0] + m[1] + m[2] >= 2 for m in masks):
            self._step_exact_fast(h, eul, w, f, y, masks)
        else:
            self._step_numpy(h, eul, w, f, y, masks)

    def _step_exact_fast(  # noqa: PLR0917 -- the inputs of one step, in the API order
        self,
        h: float,
        eul: list[float],
        w: list[float],
        f: list[float],
        y: list[float],
        masks: list[tuple[bool, bool, bool]],
    ) -> None:
        E = _e_exact_list(*eul)
        w0, w1, w2 = w
        f0, f1, f2 = f
        we = [
            E[0] * w0 + E[1] * w1 + E[2] * w2,
            E[3] * w0 + E[4] * w1 + E[5] * w2,
            E[6] * w0 + E[7] * w1 + E[8] * w2,
        ]  # ω_e = E ω
        # a = E Γ = E (f + Eᵀ g e_z) = E f + (0, 0, g): gravity in body axes (9) is Eᵀ (0, 0, g)
        a = [
            E[0] * f0 + E[1] * f1 + E[2] * f2,
            E[3] * f0 + E[4] * f1 + E[5] * f2,
            E[6] * f0 + E[7] * f1 + E[8] * f2 + self.g_mps2,
        ]
        if h != self._h_cached:  # φ-terms depend only on (γ, h): reuse them at a fixed rate
            self._terms = []
            for g in self.gamma_gain:
                xg = -g * h
                p1, p2 = phi1_phi2_scalar(xg)
                self._terms.append((math.exp(xg), h * p1, h * h * p2))
            self._h_cached = h
        if masks is _STANDARD_MASKS:
            new = _step_standard(self._x, E, we, a, y, self._terms, self.gamma_gain, h)
        else:
            yb = [c if math.isfinite(c) else 0.0 for c in y]
            new = []
            for x, m, g, (e, hp1, h2p2) in zip(
                self._x, masks, self.gamma_gain, self._terms, strict=True
            ):
                ym = [yb[0] if m[0] else 0.0, yb[1] if m[1] else 0.0, yb[2] if m[2] else 0.0]
                new.append(_update_one(x, E, we, a, ym, m, e, hp1, h2p2, g, h))
        self._x = new
        self._E_last = E

    def _step_numpy(  # noqa: PLR0917 -- the inputs of one step, in the API order
        self,
        h: float,
        eul: list[float],
        w: list[float],
        f: list[float],
        y: list[float],
        masks: list[tuple[bool, bool, bool]],
    ) -> None:
        E = e_matrix(np.array(eul), self.e_form)
        Gam = gamma_body_mps2(np.array(f), np.array(eul), self.g_mps2)
        x_new = zoh_step(
            np.array(self._x), np.array(w), Gam, E, np.array(y), np.array(masks),
            self._gamma_arr, h, orthogonal_e=self.e_form == "exact",
        )  # fmt: skip
        self._x = x_new.tolist()
        self._E_last = E


class BatchedBank:
    """``n`` vehicles × the four configurations, numpy-vectorised; same semantics as
    :class:`ObserverBank` with a leading vehicle dimension."""

    def __init__(
        self,
        n_vehicles: int,
        gamma_per_config: Mapping[str, float] | None = None,
        e_form: EForm = "exact",
        g_mps2: float = G_MPS2,
    ) -> None:
        if n_vehicles < 1:
            raise ValueError(f"n_vehicles must be >= 1, got {n_vehicles}")
        if e_form not in ("exact", "small_angle"):
            raise ValueError(f"e_form must be 'exact' or 'small_angle', got {e_form!r}")
        self.n_vehicles = int(n_vehicles)
        self.e_form: EForm = e_form
        self.g_mps2 = float(g_mps2)
        self.gamma_gain: tuple[float, ...] = _gammas(gamma_per_config)
        self._gamma_arr = np.array(self.gamma_gain)
        self._x: FloatArray = np.zeros((self.n_vehicles, 4, 3))
        self._E_last: FloatArray = np.broadcast_to(np.eye(3), (self.n_vehicles, 3, 3)).copy()
        self._h_cached = math.nan
        self._terms: tuple[FloatArray, FloatArray, FloatArray] = (np.ones(1),) * 3
        self.last_meas_mask: BoolArray = np.broadcast_to(CONFIG_MASKS, (self.n_vehicles, 4, 3))

    @property
    def x_hat_body_mps(self) -> FloatArray:
        """(n, 4, 3) body-frame velocity estimates, m/s (a copy)."""
        return self._x.copy()

    def x_hat_ned_mps(self) -> FloatArray:
        """(n, 4, 3) NED estimates under each vehicle's last attitude."""
        out: FloatArray = np.matmul(self._x, np.swapaxes(self._E_last, -1, -2))
        return out

    def reset(self, v_body_mps: ArrayLike | None = None) -> None:
        """Set the state to ``v_body_mps`` (broadcast to (n, 4, 3)), default zero."""
        if v_body_mps is None:
            self._x = np.zeros((self.n_vehicles, 4, 3))
            return
        arr = np.asarray(v_body_mps, dtype=np.float64)
        try:
            new = np.broadcast_to(arr, (self.n_vehicles, 4, 3)).copy()
        except ValueError as exc:
            raise ShapeError(f"v_body_mps: {arr.shape} does not broadcast to (n, 4, 3)") from exc
        if not np.isfinite(new).all():
            raise NonFiniteInputError("v_body_mps: NaN or infinite value")
        self._x = new

    def _arr(self, name: str, value: ArrayLike) -> FloatArray:
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != (self.n_vehicles, 3):
            raise ShapeError(f"{name}: expected ({self.n_vehicles}, 3), got {arr.shape}")
        return arr

    def step(  # noqa: PLR0917 -- the inputs of one step, in the API order
        self,
        dt_s: ArrayLike,
        euler_rad: ArrayLike,
        omega_body_radps: ArrayLike,
        f_body_mps2: ArrayLike,
        v_ned_meas_mps: ArrayLike,
        meas_mask: ArrayLike | None = None,
    ) -> None:
        """Advance every vehicle and configuration; inputs (n, 3), ``dt_s`` scalar or (n,),
        ``meas_mask`` None, (n, 3) or (n, 4, 3) bool. Validates before mutating; a
        non-finite input raises :class:`NonFiniteInputError` naming the vehicles."""
        n = self.n_vehicles
        h = np.asarray(dt_s, dtype=np.float64)
        if h.shape not in ((), (n,)):
            raise ShapeError(f"dt_s: expected scalar or ({n},), got {h.shape}")
        eul = self._arr("euler_rad", euler_rad)
        w = self._arr("omega_body_radps", omega_body_radps)
        f = self._arr("f_body_mps2", f_body_mps2)
        y = self._arr("v_ned_meas_mps", v_ned_meas_mps)
        bad = ~np.isfinite(np.concatenate((eul, w, f, np.broadcast_to(h, (n,))[:, None]), axis=1))
        if bad.any():
            rows = np.flatnonzero(bad.any(axis=1)).tolist()
            raise NonFiniteInputError(f"NaN or infinite euler/omega/f/dt for vehicle(s) {rows}")
        if (h < 0).any():
            raise ValueError("dt_s must be >= 0")
        y_finite = np.isfinite(y)
        masks: BoolArray
        if meas_mask is None and y_finite.all():
            masks = CONFIG_MASKS  # (4, 3) broadcasts against (n, 4, 3)
        elif meas_mask is None:
            masks = CONFIG_MASKS & y_finite[:, None, :]
        else:
            mm = np.asarray(meas_mask)
            if mm.dtype != np.bool_ or mm.shape not in ((n, 3), (n, 4, 3)):
                raise ShapeError(
                    f"meas_mask: expected bool ({n}, 3) or ({n}, 4, 3), got {mm.shape}"
                )
            masks = CONFIG_MASKS & y_finite[:, None, :] & (mm[:, None, :] if mm.ndim == 2 else mm)
        E = e_matrix(eul, self.e_form)
        hv = h[:, None] if h.ndim else h
        if self.e_form == "exact":
            Ev = E[:, None]  # (n, 1, 3, 3): shared by the four configurations
            # a = E Γ = E f + (0, 0, g): gravity in body axes (9) is Eᵀ (0, 0, g) for (13)
            a = rotate(E, f)
            a[:, 2] += self.g_mps2
            ybar = np.where(masks, y[:, None, :], 0.0)
            if h.ndim:
                terms = phi_terms(self._gamma_arr, hv)
            elif float(h) != self._h_cached:  # fixed rate: reuse the φ-terms
                self._terms = phi_terms(self._gamma_arr, hv)
                self._h_cached = float(h)
                terms = self._terms
            else:
                terms = self._terms
            z1 = zoh_earth(rotate(Ev, self._x), rotate(E, w)[:, None], a[:, None], ybar, masks,
                           self._gamma_arr, hv, terms)  # fmt: skip
            self._x = rotate_t(Ev, z1)
        else:
            Gam = gamma_body_mps2(f, eul, self.g_mps2)
            self._x = zoh_step(
                self._x, w[:, None, :], Gam[:, None, :], E[:, None], y[:, None, :], masks,
                self._gamma_arr, hv, orthogonal_e=False,
            )  # fmt: skip
        self._E_last = E
        self.last_meas_mask = np.broadcast_to(masks, (n, 4, 3))
