"""The bank (one vehicle) and the batched bank (many) against the pure zoh_step."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from glmav_observer.configurations import CONFIG_MASKS, CONFIGS, DEFAULT_GAMMA
from glmav_observer.estimation.bank import BatchedBank, ObserverBank
from glmav_observer.estimation.observer import (
    NonFiniteInputError,
    e_matrix,
    frame_ramp_mps2,
    gamma_body_mps2,
    zoh_step,
)
from glmav_observer.frames import ShapeError, e_exact

GAMMAS = np.array([DEFAULT_GAMMA[c] for c in CONFIGS])


def _random_inputs(
    rng: np.random.Generator, n: int, max_angle_rad: float = np.pi
) -> dict[str, np.ndarray]:
    """Random step inputs; ``max_angle_rad`` keeps the small-angle E (15) near its domain
    (at ±π its entries reach ~30 and amplify rounding by as much)."""
    y = rng.normal(scale=5.0, size=(n, 3))
    y[rng.random(size=(n, 3)) < 0.1] = np.nan  # some axes missing
    return {
        "dt": rng.uniform(0.0, 0.2, size=n),
        "euler": rng.uniform(-max_angle_rad, max_angle_rad, size=(n, 3)),
        "omega": rng.normal(scale=1.0, size=(n, 3)),
        "f": rng.normal(scale=3.0, size=(n, 3)) + np.array([0.0, 0.0, -9.81]),
        "y": y,
        "mask": rng.random(size=(n, 4, 3)) < 0.85,
    }


@pytest.mark.parametrize("e_form", ["exact", "small_angle"])
@pytest.mark.parametrize("mask_kind", ["none", "axis", "per_config"])
def test_bank_equals_pure_function(e_form: str, mask_kind: str) -> None:
    """Bank step == zoh_step with the bank's masks, for 300 random steps (NaN axes included).
    The exact-E bank runs plain-float code, the pure function numpy: same closed form,
    different rounding: agreement to 1e-12."""
    rng = np.random.default_rng(11)
    n = 300
    inp = _random_inputs(rng, n, np.pi if e_form == "exact" else 0.3)
    bank = ObserverBank(e_form=e_form)  # type: ignore[arg-type]
    x = rng.normal(size=(4, 3))
    bank.reset(x)
    worst = 0.0
    for k in range(n):
        if mask_kind == "none":
            allowed = None
            allowed_arr = np.ones((4, 3), bool)
        elif mask_kind == "axis":
            allowed_arr = np.broadcast_to(inp["mask"][k, 0], (4, 3))
            allowed = inp["mask"][k, 0]
        else:
            allowed = allowed_arr = inp["mask"][k]
        bank.step(inp["dt"][k], inp["euler"][k], inp["omega"][k], inp["f"][k], inp["y"][k], allowed)
        masks = CONFIG_MASKS & allowed_arr & np.isfinite(inp["y"][k])
        np.testing.assert_array_equal(bank.last_meas_mask, masks)
        E = e_matrix(inp["euler"][k], e_form)  # type: ignore[arg-type]
        G = gamma_body_mps2(inp["f"][k], inp["euler"][k])
        x = zoh_step(x, inp["omega"][k], G, E, inp["y"][k], masks, GAMMAS, inp["dt"][k],
                     orthogonal_e=e_form == "exact")  # fmt: skip
        worst = max(worst, float(np.abs(bank.x_hat_body_mps - x).max() / (1 + np.abs(x).max())))
    assert worst <= 1e-12
    np.testing.assert_allclose(bank.x_hat_ned_mps(), x @ E.T, atol=1e-12 * (1 + np.abs(x).max()))


def _worst_against_zoh_step(
    rng: np.random.Generator,
    e_form: str,
    *,
    with_ramp: bool = True,
    frame: bool = False,
) -> float:
    """300 chained steps of the bank (``step_floats``) and of the pure ``zoh_step`` from
    the same random state and inputs (per-configuration masks, NaN axes), with the
    measurement's ramp (``with_ramp``) and `full`'s frame term (``frame``:
    ``ObserverBank(rotate_measurement=True)`` against ``frame_ramp_mps2(E ω, y)`` added to
    `full`'s ramp when it measures every axis); the worst relative difference."""
    n = 300
    inp = _random_inputs(rng, n, np.pi if e_form == "exact" else 0.3)
    rates = rng.normal(scale=4.0, size=(n, 3))
    bank = ObserverBank(e_form=e_form, rotate_measurement=frame)  # type: ignore[arg-type]
    x = rng.normal(size=(4, 3))
    bank.reset(x)
    worst = 0.0
    for k in range(n):
        allowed = inp["mask"][k]
        y = inp["y"][k]
        rate = rates[k] if with_ramp else None
        bank.step_floats(
            float(inp["dt"][k]), inp["euler"][k].tolist(), inp["omega"][k].tolist(),
            inp["f"][k].tolist(), y.tolist(), allowed, None if rate is None else rate.tolist(),
        )  # fmt: skip
        masks = CONFIG_MASKS & allowed & np.isfinite(y)
        E = e_matrix(inp["euler"][k], e_form)  # type: ignore[arg-type]
        G = gamma_body_mps2(inp["f"][k], inp["euler"][k])
        per_config: np.ndarray | None = rate
        if frame:
            per_config = np.zeros((4, 3)) if rate is None else np.tile(rate, (4, 1))
            if masks[0].all():
                per_config[0] += frame_ramp_mps2(E @ inp["omega"][k], y)
        x = zoh_step(x, inp["omega"][k], G, E, y, masks, GAMMAS, inp["dt"][k],
                     orthogonal_e=e_form == "exact", y_rate_ned_mps2=per_config)  # fmt: skip
        worst = max(worst, float(np.abs(bank.x_hat_body_mps - x).max() / (1 + np.abs(x).max())))
    return worst


@pytest.mark.parametrize("e_form", ["exact", "small_angle"])
def test_bank_ramp_equals_pure_function(e_form: str) -> None:
    """With the measurement's ramp (y_rate_ned_mps2: the held y carried forward with the
    IMU over the step) the bank's compiled step == zoh_step, per-configuration masks and NaN
    axes included, 300 chained steps: the same closed form, other rounding: 1e-12."""
    assert _worst_against_zoh_step(np.random.default_rng(12), e_form) <= 1e-12


@pytest.mark.parametrize("with_ramp", [True, False])
def test_bank_frame_ramp_equals_pure_function(with_ramp: bool) -> None:
    """rotate_measurement: the compiled step == zoh_step whose `full` ramp takes
    frame_ramp_mps2(E ω, y) when `full` measures every axis (the other
    configurations' ramps unchanged), per-configuration masks and NaN axes included (the
    numpy path then), 300 chained steps: the same closed form, other rounding: 1e-12."""
    worst = _worst_against_zoh_step(
        np.random.default_rng(29), "exact", with_ramp=with_ramp, frame=True
    )
    assert worst <= 1e-12


@pytest.mark.parametrize(
    ("axis", "rate_axis", "v_ned_mps", "held_error_mps"),
    [
        # level north at 6 m/s pitching nose-up at 0.5 rad/s: (ω_e × v)_d = −q v_n = −3 m/s²
        (2, 1, (6.0, 0.0, 0.0), 0.03),
        # descending at 2 m/s, rolling at 0.5 rad/s: (ω_e × v)_e = −p v_d = −1 m/s²
        (1, 0, (0.0, 0.0, 2.0), 0.01),
    ],
)
def test_frame_ramp_removes_the_held_attitudes_error(
    axis: int, rate_axis: int, v_ned_mps: tuple[float, float, float], held_error_mps: float
) -> None:
    """The NED velocity constant and measured exactly (so f = Eᵀ (0, 0, −g)), the body
    turning at 0.5 rad/s from level, 50 Hz steps with the attitude of each step's start
    held, the published estimate E(t) x̂ at the step's end. The held frame leaves
    (ω_e × v)·τ in the correction: without the frame term `full`'s error on the axis
    settles near |ω × v| times about half a step (3 m/s² → 30 mm/s down; 1 m/s² → 10 mm/s
    east); with it, what is left is second order in ω Δt."""
    from glmav_observer.estimation.observer import G_MPS2

    rate, h, n = 0.5, 0.02, 50
    v = np.array(v_ned_mps)
    errors = {}
    for rotate in (False, True):
        bank = ObserverBank(rotate_measurement=rotate)
        bank.reset(v)  # level at t = 0: body = NED
        for k in range(n):
            eul0, eul1, w = np.zeros(3), np.zeros(3), np.zeros(3)
            eul0[rate_axis], eul1[rate_axis], w[rate_axis] = rate * k * h, rate * (k + 1) * h, rate
            f = e_exact(eul0).T @ np.array([0.0, 0.0, -G_MPS2])
            bank.step_floats(h, eul0.tolist(), w.tolist(), f.tolist(), v.tolist())
        errors[rotate] = float((e_exact(eul1) @ bank.x_hat_body_mps[0])[axis] - v[axis])
    # held frame: |ω × v| over about half a 20 ms step (measured −0.0312 and −0.0104 m/s);
    # two thirds of it leave a third for another rounding of the step
    assert abs(errors[False]) > 2 / 3 * held_error_mps
    # with the term the first order is gone; the second-order term left out,
    # |ω|²|v|Δt²/2 (3e-4 m/s at 6 m/s, 1e-4 at 2 m/s; measured 3e-7 and 9e-8), bounds
    # what may be left
    assert abs(errors[True]) < rate**2 * float(np.linalg.norm(v)) * h * h / 2


def test_frame_ramp_is_minus_omega_cross_y() -> None:
    # ω_e = (0.5, 0.25, 1) rad/s, y = (6, 2, 1) m/s: ω × y = (0.25·1 − 1·2, 1·6 − 0.5·1,
    # 0.5·2 − 0.25·6) = (−1.75, 5.5, −0.5), so −ω × y = (1.75, −5.5, 0.5) m/s² (exact:
    # products of small integers, halves and quarters)
    out = frame_ramp_mps2(np.array([0.5, 0.25, 1.0]), np.array([6.0, 2.0, 1.0]))
    assert out.tolist() == [1.75, -5.5, 0.5]
    batch = frame_ramp_mps2(np.zeros((4, 3)), np.ones(3))
    assert batch.shape == (4, 3) and not batch.any()


@pytest.mark.parametrize(("centred", "lead_s"), [(True, 0.0), (False, 0.0), (True, 0.01125)])
def test_centre_imu_makes_the_integrals_trapezoidal(centred: bool, lead_s: float) -> None:
    """A specific force that grows linearly, f(t) = f0 + s t, sampled every 40 ms (a 25 Hz
    IMU), level attitude: with BankCore.centre_imu at each sample, A = ∫ a dt and every
    state's dead-reckoned axis equal the exact integral at the samples (the trapezoid is
    exact for a linear f) up to rounding; held (ZOH), both trail it by s T t / 2. With the
    accelerometer filter's delay τ taken out (``imu_lead_s``) each change counts τ
    earlier: the integral leads by τ (f(t) − f0) = τ s t."""
    from glmav_observer.estimation.inputs import HeldInputs
    from glmav_observer.estimation.observer import G_MPS2

    g = G_MPS2  # the bank's default
    f0, s, T, n = np.array([0.5, -0.3, -g]), np.array([0.2, 0.4, -0.1]), 0.04, 50
    inputs = HeldInputs(g)
    inputs.euler_rad = (0.0, 0.0, 0.0)
    inputs.omega_att_radps = (0.0, 0.0, 0.0)
    inputs.f_body_mps2 = tuple(f0.tolist())
    inputs.hold_measurement([0.0, 0.0, 0.0])
    bank = ObserverBank(imu_lead_s=lead_s)
    no_use = [False, False, False]  # no axis measured: the states dead-reckon
    for k in range(1, n + 1):
        t = k * T
        assert not bank.advance(t, T, inputs, [0.0] * 3, False, None, no_use)  # numpy path
        y = [math.nan] * 3
        bank.step_floats(T, [0.0] * 3, [0.0] * 3, list(inputs.f_body_mps2), y)
        inputs.integrate(t, T, bank.e_last_flat())
        f_k = (f0 + s * t).tolist()
        if centred:
            bank.centre_imu(inputs, f_k, T)
        inputs.f_body_mps2 = tuple(f_k)
    t_end = n * T
    exact = (f0 + np.array([0.0, 0.0, g])) * t_end + s * t_end**2 / 2
    offset = 0.0 if centred else 1.0
    want = exact - offset * s * T * t_end / 2 + lead_s * s * t_end
    np.testing.assert_allclose(inputs.a_int, want, atol=1e-12)
    np.testing.assert_allclose(bank.x_hat_ned_mps(), np.broadcast_to(want, (4, 3)), atol=1e-12)


def test_bank_standard_fast_path_equals_generic_path() -> None:
    """A healthy step (every axis measured: the table's masks, taken as they are) == the
    same step with an all-True mask passed explicitly (masks built per step) to the last
    bit: both run the one compiled step (BankCore.step). Over 200 chained steps any path
    that diverged would show."""
    rng = np.random.default_rng(5)
    a, b = ObserverBank(), ObserverBank()
    x0 = rng.normal(size=(4, 3))
    a.reset(x0)
    b.reset(x0)
    for _ in range(200):
        args = (rng.uniform(0, 0.1), rng.normal(size=3), rng.normal(size=3),
                rng.normal(size=3), rng.normal(size=3))  # fmt: skip
        a.step(*args)
        b.step(*args, meas_mask=np.ones(3, bool))
        np.testing.assert_array_equal(a.x_hat_body_mps, b.x_hat_body_mps)


@pytest.mark.parametrize("e_form", ["exact", "small_angle"])
def test_batched_equals_loop_of_banks(e_form: str) -> None:
    rng = np.random.default_rng(7)
    nv, steps = 6, 60
    batched = BatchedBank(nv, e_form=e_form)  # type: ignore[arg-type]
    banks = [ObserverBank(e_form=e_form) for _ in range(nv)]  # type: ignore[arg-type]
    x0 = rng.normal(size=(nv, 4, 3))
    batched.reset(x0)
    for i in range(nv):
        banks[i].reset(x0[i])
    for k in range(steps):
        inp = _random_inputs(rng, nv, np.pi if e_form == "exact" else 0.3)
        mask = inp["mask"] if k % 2 else inp["mask"][:, 0, :]  # (n,4,3) and (n,3) forms
        batched.step(inp["dt"], inp["euler"], inp["omega"], inp["f"], inp["y"], mask)
        for i in range(nv):
            banks[i].step(inp["dt"][i], inp["euler"][i], inp["omega"][i], inp["f"][i],
                          inp["y"][i], mask[i])  # fmt: skip
    loop = np.stack([b.x_hat_body_mps for b in banks])
    scale = 1 + np.abs(loop).max()
    assert np.abs(batched.x_hat_body_mps - loop).max() <= 1e-12 * scale
    loop_ned = np.stack([b.x_hat_ned_mps() for b in banks])
    assert np.abs(batched.x_hat_ned_mps() - loop_ned).max() <= 1e-12 * scale


def test_batched_scalar_dt_and_no_mask() -> None:
    rng = np.random.default_rng(8)
    batched = BatchedBank(3)
    bank = ObserverBank()
    inp = _random_inputs(rng, 3)
    inp["y"] = np.nan_to_num(inp["y"])
    batched.step(0.01, inp["euler"], inp["omega"], inp["f"], inp["y"])
    bank.step(0.01, inp["euler"][2], inp["omega"][2], inp["f"][2], inp["y"][2])
    np.testing.assert_allclose(batched.x_hat_body_mps[2], bank.x_hat_body_mps, atol=1e-13)


@settings(max_examples=50, deadline=None)
@given(
    arrays(np.float64, 3, elements=st.floats(-np.pi, np.pi)),
    arrays(np.float64, 3, elements=st.floats(-3.0, 3.0)),
    arrays(np.float64, 3, elements=st.floats(-10.0, 10.0)),
    st.floats(1e-4, 0.5),
)
def test_bank_keeps_a_consistent_estimate_at_rest_in_steady_flight(
    euler: np.ndarray, omega: np.ndarray, v_ned: np.ndarray, dt: float
) -> None:
    """Constant NED velocity, no rotation, at rest in an inertial sense (Γ = 0): an estimate
    that equals the truth stays equal, any attitude, any step (exact, to rounding)."""
    E = e_exact(euler)
    f_body = -(E.T @ [0.0, 0.0, 9.81])  # specific force of unaccelerated flight
    bank = ObserverBank()
    bank.reset(E.T @ v_ned)
    for _ in range(5):
        bank.step(dt, euler, np.zeros(3), f_body, v_ned)
    assert np.abs(bank.x_hat_ned_mps() - v_ned).max() <= 1e-12 * (1 + np.abs(v_ned).max())
    # and with rotation the earth estimate moves only through the hold (≤ |ω||V|Δt per step)
    bank.step(dt, euler, omega, f_body, v_ned)
    assert np.isfinite(bank.x_hat_body_mps).all()


def test_bad_input_is_rejected_and_state_kept() -> None:
    bank = ObserverBank()
    bank.reset([1.0, 2.0, 3.0])
    before = bank.x_hat_body_mps
    good = np.zeros(3)
    cases = [
        ((0.01, [np.nan, 0, 0], good, good, good), NonFiniteInputError, "euler_rad"),
        ((0.01, good, [0, np.inf, 0], good, good), NonFiniteInputError, "omega_body_radps"),
        ((0.01, good, good, [0, 0, -np.inf], good), NonFiniteInputError, "f_body_mps2"),
        ((np.nan, good, good, good, good), NonFiniteInputError, "dt_s"),
        ((-0.01, good, good, good, good), ValueError, "dt_s must be >= 0"),
        ((0.01, np.zeros(4), good, good, good), ShapeError, r"euler_rad: expected shape \(3,\)"),
        ((0.01, good, good, good, np.zeros((1, 3))), ShapeError, "v_ned_meas_mps"),
    ]
    for args, exc, msg in cases:
        with pytest.raises(exc, match=msg):
            bank.step(*args)
        np.testing.assert_array_equal(bank.x_hat_body_mps, before)
    with pytest.raises(ShapeError, match="meas_mask"):
        bank.step(0.01, good, good, good, good, np.ones(3))  # not bool
    with pytest.raises(ShapeError, match="meas_mask"):
        bank.step(0.01, good, good, good, good, np.ones((2, 3), bool))
    np.testing.assert_array_equal(bank.x_hat_body_mps, before)
    # NaN / inf measurement axes are flagged (not used), the state stays finite
    bank.step(0.01, good, good, [0, 0, -9.81], [np.nan, np.inf, 1.0])
    assert np.isfinite(bank.x_hat_body_mps).all()
    np.testing.assert_array_equal(bank.last_meas_mask[0], [False, False, True])
    # an all-NaN measurement: every configuration dead-reckons (generic exact path)
    bank.step(0.01, good, good, [0, 0, -9.81], [np.nan] * 3)
    assert np.isfinite(bank.x_hat_body_mps).all()
    assert not bank.last_meas_mask.any()


def test_batched_bad_input_names_vehicles() -> None:
    bb = BatchedBank(4)
    z = np.zeros((4, 3))
    eul = z.copy()
    eul[2, 1] = np.nan
    with pytest.raises(NonFiniteInputError, match=r"vehicle\(s\) \[2\]"):
        bb.step(0.01, eul, z, z, z)
    with pytest.raises(ShapeError, match="expected"):
        bb.step(0.01, np.zeros((3, 3)), z, z, z)
    with pytest.raises(ShapeError, match="dt_s"):
        bb.step(np.zeros(3), z, z, z, z)
    assert (bb.x_hat_body_mps == 0).all()


def test_state_setters_and_handover() -> None:
    bank = ObserverBank()
    euler = np.array([0.3, -0.2, 1.0])
    v_ned = np.array([4.0, -1.0, 0.5])
    bank.set_state_ned("c1", v_ned, euler)
    np.testing.assert_allclose(e_exact(euler) @ bank.x_hat_body_mps[1], v_ned, atol=1e-14)
    bank.set_state_body("c2", [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(bank.x_hat_body_mps[2], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="unknown configuration"):
        bank.set_state_body("c9", [0, 0, 0])
    with pytest.raises(NonFiniteInputError):
        bank.set_state_body("c2", [np.nan, 0, 0])
    bank.reset()
    assert (bank.x_hat_body_mps == 0).all()
    sa = ObserverBank(e_form="small_angle")
    sa.set_state_ned("c3", v_ned, [0.1, 0.05, -0.1])
    # small-angle E is not orthogonal: x̂ = E⁻¹ v_ned, not Eᵀ v_ned
    np.testing.assert_allclose(
        e_matrix([0.1, 0.05, -0.1], "small_angle") @ sa.x_hat_body_mps[3], v_ned, atol=1e-13
    )
    with pytest.raises(ValueError, match="gamma_per_config"):
        ObserverBank({"c1": -1.0})
    with pytest.raises(ValueError, match="unknown configuration"):
        ObserverBank({"c7": 1.0})


def test_default_full_gamma_beats_the_papers_gamma_under_design_noise() -> None:
    """γ_full = 12: the minimiser of (b/γ)² + γσ_y²/(2f) with the design's accelerometer bias
    b = 0.2 m/s², velocity noise σ_y = 0.05 m/s at f = 30 Hz (held), IMU at 250 Hz.
    Hovering level, 30 s after a 5 s transient; 3 axes × ~7500 samples per γ.
    """
    rng = np.random.default_rng(0)
    f_imu, f_y, duration = 250, 30, 35.0
    n = int(duration * f_imu)
    y_samples = rng.normal(scale=0.05, size=(int(duration * f_y) + 2, 3))
    f_body = np.array([0.2, -0.2, 0.2]) + np.array([0.0, 0.0, -9.81])  # biased accelerometer
    rms = {}
    for g in (3.0, DEFAULT_GAMMA["full"], 90.0):
        bank = ObserverBank({"full": g})
        errs = []
        for k in range(n):
            t = k / f_imu
            bank.step(1 / f_imu, np.zeros(3), np.zeros(3), f_body, y_samples[int(t * f_y)])
            if t > 5.0:
                errs.append(bank.x_hat_body_mps[0])
        rms[g] = float(np.sqrt(np.mean(np.square(errs))))
    predicted = np.sqrt((0.2 / 12.0) ** 2 + 12.0 * 0.05**2 / (2 * 30))  # 0.0279 m/s
    # 22 500 correlated samples (correlation time 1/γ ≈ 0.08 s → ~370 independent per axis):
    # the RMS estimate scatters by ~1/√(2·1100) ≈ 2 %; the continuous formula ignores the
    # 30 Hz hold (observed 6 % below it); 15 % covers both
    assert abs(rms[12.0] / predicted - 1) < 0.15
    assert rms[12.0] < 0.8 * rms[3.0]  # observed 0.026 vs 0.067 (bias-dominated)
    assert rms[12.0] < 0.8 * rms[90.0]  # observed 0.026 vs 0.041 (noise-dominated)


def test_plain_float_estimates_equal_the_arrays() -> None:
    """bank.estimates_lists (the records' per-step path) == x_hat_body_mps exactly and
    x_hat_ned_mps to rounding: the same three products summed, numpy's matmul may pair
    them differently (one ulp: |v| ≤ 20 m/s here, 2⁻⁵² · 20 · 3 ≈ 1.3e-14)."""
    rng = np.random.default_rng(8)
    bank = ObserverBank()
    bank.reset(rng.normal(scale=5.0, size=(4, 3)))
    for _ in range(50):
        bank.step(0.004, rng.uniform(-3, 3, 3), rng.normal(size=3), rng.normal(size=3),
                  rng.normal(scale=5.0, size=3))  # fmt: skip
        body, ned = bank.estimates_lists()
        np.testing.assert_array_equal(np.array(body), bank.x_hat_body_mps)
        np.testing.assert_allclose(np.array(ned), bank.x_hat_ned_mps(), rtol=0, atol=1.3e-14)
        assert bank.e_last_flat() == bank.e_last.ravel().tolist()


def test_phi_terms_cache_equals_recomputing_every_step() -> None:
    """The φ-terms kept per step length (bank_core's ``TERMS_CACHE``, 16): a bank that reuses them
    equals, bit for bit, one that recomputes them at every step, over jittered step
    lengths (more distinct lengths than the cache holds) and a γ changed midway."""
    rng = np.random.default_rng(4)
    cached, fresh = ObserverBank(), ObserverBank()
    lengths = [0.004 + k * 1e-17 for k in range(40)]  # 40 round-offs of one length
    short = [0.004, 0.002, 0.001, 0.003]
    for i in range(300):
        if i == 204:  # the short lengths are kept by now: their terms must not be reused
            for b in (cached, fresh):
                b.set_gamma("full", 7.5)
        h = lengths[int(rng.integers(len(lengths)))] if i < 200 else short[i % 4]
        eul = rng.uniform(-0.5, 0.5, 3).tolist()
        w = rng.uniform(-1.0, 1.0, 3).tolist()
        f = (rng.uniform(-2.0, 2.0, 3) + np.array([0.0, 0.0, -9.8])).tolist()
        y = rng.uniform(-5.0, 5.0, 3).tolist()
        fresh._core.set_gammas(fresh.gamma_gain)  # drops every φ-term kept
        for b in (cached, fresh):
            b.step(h, eul, w, f, y)
        assert cached.estimates_lists() == fresh.estimates_lists()


def test_held_inputs_y_rate_is_the_propagated_measurements_derivative() -> None:
    """HeldInputs.y_rate (the ramp the compiled step and the numpy fallback both use) is the
    time derivative of y_for_step's propagation: integrating 1 ms at the held inputs moves
    y_for_step by y_rate·dt. Both are sums of the same products in a different order, so
    they agree to rounding: 1e-12 m/s² on rates of ~10 m/s²."""
    from glmav_observer.estimation.inputs import HeldInputs
    from glmav_observer.estimation.observer import G_MPS2
    from glmav_observer.frames import e_exact

    rng = np.random.default_rng(5)
    for _ in range(20):
        inputs = HeldInputs(G_MPS2)
        euler = rng.uniform(-1.2, 1.2, 3)
        f = rng.normal(scale=3.0, size=3) + np.array([0.0, 0.0, -G_MPS2])
        bias = rng.normal(scale=0.2, size=3)
        inputs.euler_rad = tuple(euler.tolist())
        inputs.f_body_mps2 = tuple(f.tolist())
        inputs.hold_measurement([1.0, -2.0, 0.5])
        dt = 1e-3
        y0 = np.array(inputs.y_for_step(bias.tolist(), True))
        E = e_exact(euler)
        inputs.integrate(0.0, dt, E.ravel().tolist())
        y1 = np.array(inputs.y_for_step(bias.tolist(), True))
        rate = np.array(inputs.y_rate(bias.tolist()))
        expected = E @ (f - bias) + np.array([0.0, 0.0, G_MPS2])
        assert np.abs(rate - expected).max() <= 1e-12
        # the held inputs over dt move the propagated y by exactly rate·dt (ZOH: linear)
        assert np.abs((y1 - y0) / dt - rate).max() <= 1e-9  # 1e-12 of y over 1e-3 s
