"""The observer bank: the four configurations (full, c1, c2, c3) of one vehicle, or of many.

(The one update written two ways that tests pin to each other: the compiled per-sample
step and the batched numpy form across vehicles.)

:class:`ObserverBank` holds one vehicle's state and advances all configurations with the
exact zero-order-hold update of (16) (:func:`~glmav_observer.estimation.observer.zoh_step`).
For the exact E and two or three measured axes per configuration it runs the closed form
compiled (:class:`~glmav_observer.estimation.bank_core.BankCore`, which holds the state);
tests check it against the numpy form to 1e-12. :class:`BatchedBank` does the same for ``n`` vehicles with numpy, vectorised over
vehicles and configurations. The configurations (names, masks, default γ) come from
:mod:`glmav_observer.configurations`, E from :mod:`glmav_observer.frames`.

Frames and units: ``euler_rad`` ZYX (φ, θ, ψ), ``omega_body_radps`` FRD, ``f_body_mps2`` the
accelerometer's specific force in FRD (reads (0, 0, −g) at rest and level),
``v_ned_meas_mps`` the measured NED velocity (NaN on an axis = not measured).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from glmav_observer.configurations import (
    CONFIG_MASKS,
    CONFIGS,
    CONFIGURATIONS,
    DEFAULT_GAMMA,
    config_index,
)
from glmav_observer.estimation.bank_core import BankCore
from glmav_observer.estimation.inputs import HeldInputs
from glmav_observer.estimation.observer import (
    G_MPS2,
    BoolArray,
    EForm,
    FloatArray,
    NonFiniteInputError,
    e_matrix,
    frame_ramp_mps2,
    gamma_body_mps2,
    phi_terms,
    zoh_earth,
    zoh_step,
)
from glmav_observer.frames import ShapeError, rotate, rotate_t

#: The masks of a step where every measured axis is valid and allowed (identity-checked).
_STANDARD_MASKS: list[tuple[bool, bool, bool]] = [
    (bool(r[0]), bool(r[1]), bool(r[2])) for r in CONFIG_MASKS.tolist()
]


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


def _vec3(name: str, value: ArrayLike) -> list[float]:
    if isinstance(value, (tuple, list)) and len(value) == 3:
        # the estimator's inputs: three Python floats, returned as they are (what
        # np.asarray(...).tolist() returns too, after two conversions)
        v0, v1, v2 = value
        if type(v0) is float and type(v1) is float and type(v2) is float:
            return [v0, v1, v2]
    elif type(value) is np.ndarray and value.shape == (3,) and value.dtype == np.float64:
        fast: list[float] = value.tolist()  # ~0.1 µs
        return fast
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise ShapeError(f"{name}: expected shape (3,), got {arr.shape}")
    out: list[float] = arr.tolist()
    return out


def _lost_index(m: tuple[bool, bool, bool]) -> int:
    """The one unmeasured axis of a mask with two or three measured axes; −1 for none."""
    return -1 if m[0] and m[1] and m[2] else (0 if not m[0] else (1 if not m[1] else 2))


#: The lost axis of each configuration in bank order (−1: none), from the table.
_STANDARD_LOST: tuple[int, ...] = tuple(
    -1 if c.lost_index is None else c.lost_index for c in CONFIGURATIONS
)


class ObserverBank:
    """All four configurations of one vehicle (CONFIGS order: full, c1, c2, c3).

    ``step`` advances every configuration by ``dt_s`` with the inputs held (exact ZOH of
    (16)); inputs are validated before any state changes. A NaN axis of the measured
    velocity is treated as not measured (``last_meas_mask`` shows what was used). The
    state and the last E live in the compiled :class:`BankCore`.
    """

    def __init__(
        self,
        gamma_per_config: Mapping[str, float] | None = None,
        e_form: EForm = "exact",
        g_mps2: float = G_MPS2,
        rotate_measurement: bool = False,
        imu_lead_s: float = 0.0,
    ) -> None:
        if e_form not in ("exact", "small_angle"):
            raise ValueError(f"e_form must be 'exact' or 'small_angle', got {e_form!r}")
        self.e_form: EForm = e_form
        self.g_mps2 = float(g_mps2)
        self.gamma_gain: tuple[float, ...] = _gammas(gamma_per_config)
        self._gamma_arr = np.array(self.gamma_gain)
        #: `full`'s measurement compared in the step's frame
        #: (observer.frame_ramp_mps2; EstimatorConfig.rotate_measurement)
        self.rotate_measurement = bool(rotate_measurement)
        self._core = BankCore(
            self.gamma_gain, self.g_mps2, _STANDARD_LOST, self.rotate_measurement, imu_lead_s
        )
        #: the masks of the last step (None: the last step was :meth:`advance`'s, whose
        #: masks the core's lost axes tell)
        self._masks_last: list[tuple[bool, bool, bool]] | None = _STANDARD_MASKS

    @property
    def last_meas_mask(self) -> BoolArray:
        """(4, 3) bool: the NED axes each configuration used in the last step."""
        if self._masks_last is None:
            return np.array([[k != lost for k in range(3)] for lost in self._core.lost()])
        return np.array(self._masks_last, dtype=bool)

    @property
    def e_last(self) -> FloatArray:
        """(3, 3) the E of the last step (identity before the first)."""
        return np.array(self._core.e_list(), dtype=np.float64).reshape(3, 3)

    def set_gamma(self, config: str, gamma: float) -> None:
        """Change one configuration's gain γ (1/s; finite, > 0) from the next step on."""
        if not (math.isfinite(gamma) and gamma > 0.0):
            raise ValueError(f"gamma must be finite and > 0, got {gamma!r}")
        g = list(self.gamma_gain)
        g[config_index(config)] = float(gamma)
        self.gamma_gain = tuple(g)
        self._gamma_arr = np.array(self.gamma_gain)
        self._core.set_gammas(self.gamma_gain)  # (drops the φ-terms: they depend on γ)

    # ------------------------------------------------------------------ state access
    @property
    def x_hat_body_mps(self) -> FloatArray:
        """(4, 3) body-frame (FRD) velocity estimates, m/s, CONFIGS order (a copy)."""
        return np.array(self._core.rows())

    def x_hat_ned_mps(self) -> FloatArray:
        """(4, 3) NED velocity estimates E x̂ under the attitude of the last step (a copy)."""
        return np.array(self._core.rows()) @ self.e_last.T

    def e_last_flat(self) -> list[float]:
        """:attr:`e_last` as a row-major list of 9 floats (a new list)."""
        return self._core.e_list()

    def estimates_lists(self) -> tuple[list[list[float]], list[tuple[float, float, float]]]:
        """(body, NED) estimates, 4 rows of 3 floats each: :attr:`x_hat_body_mps` and
        :meth:`x_hat_ned_mps` without numpy, for the per-step records (the NED one summed
        in matmul's order; test_bank asserts both equal the arrays). New lists."""
        return self._core.rows(), self._core.ned_rows()

    def set_state_body(self, config: str, v_body_mps: ArrayLike) -> None:
        """Overwrite one configuration's body-frame state (m/s)."""
        i = config_index(config)
        v = _vec3("v_body_mps", v_body_mps)
        if not all(math.isfinite(c) for c in v):
            raise NonFiniteInputError(f"v_body_mps: NaN or infinite value in {v!r}")
        self._core.set_row(i, v)

    def set_state_ned(self, config: str, v_ned_mps: ArrayLike, euler_rad: ArrayLike) -> None:
        """Hand-over: start ``config`` from an earth-frame velocity at attitude ``euler_rad``.

        x̂ = E⁻¹ v_ned (= Eᵀ v_ned for the exact E) with this bank's E form.
        """
        i = config_index(config)
        v = np.asarray(_vec3("v_ned_mps", v_ned_mps))
        eul = np.asarray(_vec3("euler_rad", euler_rad))
        if not (np.isfinite(v).all() and np.isfinite(eul).all()):
            raise NonFiniteInputError(f"set_state_ned: NaN or infinite in {v!r} or {eul!r}")
        E = e_matrix(eul, self.e_form)
        self._core.set_row(i, np.linalg.solve(E, v).tolist())

    def set_attitude(self, euler_rad: Sequence[float]) -> None:
        """The attitude now (a new ATTITUDE at the bank's time): the E the estimates are
        rotated to NED with until the next step. The state (body frame) is unchanged;
        the next step computes its own E from its inputs."""
        if self.e_form == "exact":
            self._core.set_attitude(euler_rad[0], euler_rad[1], euler_rad[2])
        else:
            self._core.set_e_list(e_matrix(np.array(euler_rad), self.e_form).ravel().tolist())

    def centre_imu(self, inputs: HeldInputs, f_new_body_mps2: Sequence[float], dt_s: float) -> None:
        """The trapezoid's correction at a new IMU sample, with the accelerometer filter's
        delay :attr:`imu_lead_s` taken out (``BankCore.centre_imu``)."""
        self._core.centre_imu(inputs, f_new_body_mps2, dt_s)

    @property
    def imu_lead_s(self) -> float:
        """The accelerometer filter's delay taken out at each IMU sample, s
        (:mod:`.imu_filter`)."""
        return self._core.imu_lead_s

    @imu_lead_s.setter
    def imu_lead_s(self, value: float) -> None:
        self._core.imu_lead_s = float(value)

    def reset(self, v_body_mps: ArrayLike | None = None) -> None:
        """Set every configuration to ``v_body_mps`` ((3,) or (4, 3), default zero)."""
        if v_body_mps is None:
            self._core.set_rows([[0.0, 0.0, 0.0] for _ in CONFIGS])
            return
        arr = np.asarray(v_body_mps, dtype=np.float64)
        if arr.shape not in ((3,), (4, 3)):
            raise ShapeError(f"v_body_mps: expected (3,) or (4, 3), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise NonFiniteInputError(f"v_body_mps: NaN or infinite value in {arr.tolist()!r}")
        self._core.set_rows(np.broadcast_to(arr, (4, 3)).tolist())

    # ------------------------------------------------------------------ update
    def _masks(
        self, y: Sequence[float], meas_mask: ArrayLike | None
    ) -> list[tuple[bool, bool, bool]]:
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
        self.step_floats(
            float(dt_s),
            _vec3("euler_rad", euler_rad),
            _vec3("omega_body_radps", omega_body_radps),
            _vec3("f_body_mps2", f_body_mps2),
            _vec3("v_ned_meas_mps", v_ned_meas_mps),
            meas_mask,
        )

    def step_floats(  # noqa: PLR0917 -- the inputs of one step, in the API order
        self,
        h: float,
        eul: Sequence[float],
        w: Sequence[float],
        f: Sequence[float],
        y: Sequence[float],
        meas_mask: ArrayLike | None = None,
        y_rate: Sequence[float] | None = None,
    ) -> None:
        """:meth:`step` for inputs that are already three Python floats each (a vehicle's
        samples): no conversion, the same checks of values (NaN, dt_s < 0). ``y_rate``:
        the measurement's ramp over the step (NED, m/s²; ``observer.zoh_step``)."""
        phi, th, psi = eul
        if not math.isfinite(h + phi + th + psi + w[0] + w[1] + w[2] + f[0] + f[1] + f[2]):
            for name, vals in (("dt_s", [h]), ("euler_rad", eul), ("omega_body_radps", w),
                               ("f_body_mps2", f)):  # fmt: skip
                if not all(math.isfinite(c) for c in vals):
                    raise NonFiniteInputError(f"{name}: NaN or infinite value in {vals!r}")
            raise NonFiniteInputError("inputs overflow (sum of |values| is not finite)")
        if h < 0.0:
            raise ValueError(f"dt_s must be >= 0, got {h!r}")
        if meas_mask is None and math.isfinite(y[0] + y[1] + y[2]):
            masks = _STANDARD_MASKS  # (a finite sum: every axis finite)
        else:
            masks = self._masks(y, meas_mask)
        self._masks_last = masks
        if masks is _STANDARD_MASKS and self.e_form == "exact":
            self._core.step(h, eul, w, f, y, _STANDARD_LOST, y_rate)
        elif self.e_form == "exact" and all(m[0] + m[1] + m[2] >= 2 for m in masks):
            self._core.step(h, eul, w, f, y, [_lost_index(m) for m in masks], y_rate)
        else:
            self._step_numpy(h, eul, w, f, y, masks, y_rate)

    def advance(  # noqa: PLR0917 -- the held inputs and what the supervisor decided
        self,
        t: float,
        dt: float,
        inputs: HeldInputs,
        bias_body_mps2: Sequence[float],
        propagate: bool,
        b_obs: Sequence[float] | None,
        use: Sequence[bool],
    ) -> bool:
        """The per-sample step in one compiled call (:meth:`BankCore.advance`): every
        configuration over ``dt`` from the held inputs, then their IMU integrals. False
        (nothing changed) where :meth:`step_floats` must step instead (the small-angle
        E, a configuration with fewer than two measured axes, a non-finite input)."""
        if self.e_form != "exact":
            return False
        if self._core.advance(t, dt, inputs, bias_body_mps2, propagate, b_obs, use):
            self._masks_last = None
            return True
        return False

    def _step_numpy(  # noqa: PLR0917 -- the inputs of one step, in the API order
        self,
        h: float,
        eul: Sequence[float],
        w: Sequence[float],
        f: Sequence[float],
        y: Sequence[float],
        masks: list[tuple[bool, bool, bool]],
        y_rate: Sequence[float] | None = None,
    ) -> None:
        """One or no measured axis in a configuration, or the small-angle E: the numpy
        form (:func:`~glmav_observer.estimation.observer.zoh_step`)."""
        E = e_matrix(np.array(eul), self.e_form)
        Gam = gamma_body_mps2(np.array(f), np.array(eul), self.g_mps2)
        rate: FloatArray | Sequence[float] | None = y_rate
        if self.rotate_measurement and all(masks[0]):  # `full` measures every axis
            # as BankCore.step_c: its ramp takes the frame term (frame_ramp_mps2)
            rates = np.zeros((4, 3)) if y_rate is None else np.tile(np.asarray(y_rate), (4, 1))
            rates[0] += frame_ramp_mps2(E @ np.asarray(w, dtype=np.float64), np.array(y))
            rate = rates
        x_new = zoh_step(
            np.array(self._core.rows()), np.array(w), Gam, E, np.array(y), np.array(masks),
            self._gamma_arr, h, orthogonal_e=self.e_form == "exact", y_rate_ned_mps2=rate,
        )  # fmt: skip
        self._core.set_rows(x_new.tolist())
        self._core.set_e_list(E.ravel().tolist())


class BatchedBank:
    """``n`` vehicles × the four configurations, numpy-vectorised; same semantics as
    :class:`ObserverBank` with a leading vehicle dimension.

    The service does not use it yet: each vehicle's estimator steps its own
    :class:`ObserverBank` when that vehicle's samples arrive. It stays as the fleet-scale
    path: with many vehicles stepped together it is the cheaper form per configuration
    update (``python -m benchmarks.bench_observer``: 0.48 µs at 100 vehicles against 1.6 µs
    in :class:`ObserverBank`, docs/benchmarks/bench_observer.md), and
    tests/unit/glmav_observer/estimation/test_bank.py keeps it equal to a loop of banks.
    """

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
