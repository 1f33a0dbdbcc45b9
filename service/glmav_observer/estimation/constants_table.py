"""Every tuning constant of the estimation, with its reason: the rows of
docs/reference/constants.md (``scripts/gen_config_reference.py`` renders them).

The constants are

- the fields of the configuration classes in :data:`CLASSES`; a field made by
  :func:`~glmav_observer.estimation.reasons.const` carries its own
  :class:`~glmav_observer.estimation.reasons.Reason`; the classes whose modules are shared
  with other work (``EstimatorConfig``, ``DragModelConfig``, ``AidedAxisConfig``) have
  theirs here, in :data:`CLASS_REASONS`, keyed by field;
- the named module constants of :data:`MODULE_CONSTANTS` (read from their module, so the
  table shows the value the code uses).

:func:`constant_rows` raises if a field has no reason or a reason names a field that is
gone: a new constant cannot be added without one (tests/unit/scripts/
test_gen_config_reference.py renders the table).
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any, NamedTuple

from glmav_observer.estimation.reasons import Reason, reason_of

_PKG = "glmav_observer.estimation"

#: (class name, its module): the configuration classes whose fields are constants.
CLASSES: tuple[tuple[str, str], ...] = (
    ("FdiConfig", f"{_PKG}.fdi_types"),
    ("FdiTuning", f"{_PKG}.fdi_types"),
    ("ImuMonitorConfig", f"{_PKG}.imu_monitor"),
    ("DespikeConfig", f"{_PKG}.fdi_types"),
    ("GainConfig", f"{_PKG}.gain"),
    ("EstimatorConfig", f"{_PKG}.vehicle"),
    ("DragModelConfig", f"{_PKG}.aero.model"),
    ("AidedAxisConfig", f"{_PKG}.aero.aided"),
    ("DriftRateConfig", f"{_PKG}.aero.drift_rate"),
    ("GpsBridgeConfig", f"{_PKG}.gps_bridge"),
)


def _r(unit: str, source: Any, reason: str, sensitivity: bool = False) -> Reason:
    return Reason(unit, source, reason, sensitivity)


#: Reasons of the fields of the classes whose modules others edit (see the docstring).
CLASS_REASONS: dict[str, dict[str, Reason]] = {
    "EstimatorConfig": {
        "gamma": _r("1/s", "physics", "the observer gain per configuration (None: each "
                    "configuration's default_gamma_per_s: c1-c3 the paper's (49), full the "
                    "minimiser of (b/γ)² + γσ_y²/(2f) at b = 0.2 m/s², σ_y = 0.05 m/s, "
                    "f = 30 Hz: γ ≈ 12.4; configurations.py)"),
        "e_form": _r("", "requirement", "the exact E (13); the paper's small-angle E (15) "
                     "for reproducing it"),
        "g_mps2": _r("m/s²", "physics", "standard gravity (9.80665) rounded as the paper's "
                     "observer uses it"),
        "health_rate_hz": _r("Hz", "requirement", "health records per second of vehicle "
                             "time: a GCS's 10 Hz display rate"),
        "propagate_held_measurement": _r("", "physics", "carry the held velocity forward "
                                         "with the IMU between samples (a 5 Hz GPS is 0.2 s "
                                         "old at its next sample)"),
        "compensate_accel_bias": _r("", "physics", "feed the fit's observed accelerometer "
                                    "bias to the bank (it integrates otherwise)"),
        "compensate_lag": _r("", "physics", "move the measurement to the present by the "
                             "fit's observed lag (v = y + d·a)"),
        "trapezoid_imu": _r("", "physics", "integrate the IMU with the trapezoid at its "
                            "samples' times: a held sample lags by half the IMU's interval "
                            "(20 ms at 25 Hz)"),
        "rotate_measurement": _r("", "physics", "compare `full`'s measurement in the frame "
                                 "of the bank's step: the held E leaves (ω_e × v)·τ in its "
                                 "correction, down a pitch rate × horizontal speed "
                                 "(observer.frame_ramp_mps2)"),
        "compensate_imu_filter": _r("", "physics", "the autopilot sends its accelerometer "
                                    "after a two-pole low-pass whose group delay, √2/(2π f_c), "
                                    "an integrated velocity inherits (11.25 ms at ArduPilot's "
                                    "20 Hz; estimation.imu_filter)"),
        "imu_filter_hz": _r("Hz", "requirement", "the vehicle's own setting (ArduPilot "
                            "INS_ACCEL_FILTER); 0 takes the firmware's default "
                            "(DEFAULT_ACCEL_FILTER in ArduPilot's AP_InertialSensor.cpp)"),
        "max_gap_s": _r("s", "physics", "a longer silence restarts the bank: 1 s of dead "
                        "reckoning at 0.3 m/s² bias is already 0.3 m/s"),
        "follow_unaided": _r("", "measured", "while the autopilot says an axis is unaided, "
                             "`active` follows its velocity: measured on b_quad_gps_off "
                             "(east during the loss: 0.0482 m/s filtered, 0.0411 followed; "
                             "VehicleEstimator._follow_unaided) and by the argument that the "
                             "autopilot dead-reckons from its full-rate IMU"),
        "readmit_follow_s": _r("s", "physics", "`active` still follows the autopilot's "
                               "velocity this long after it is aided again: its estimator "
                               "snaps back to its sensor then (ArduPilot: 0.37 m/s in one "
                               "sample on b_quad_gps_off), a step `full`'s filter smears over "
                               "1/γ; 1 s = 4/γ at gamma_full_min"),
        "handover_contamination_mps": _r("m/s", "statistic", "at hand-over the FDI's dead "
                                         "reckoning replaces `full` if they differ by more: "
                                         "20σ of the hand-over (0.05 m/s), so only a "
                                         "contaminated `full` is replaced"),
        "metrics_skip_s": _r("s", "requirement", "RMSE against SIM_STATE starts this long "
                             "after the first estimate (the observers' convergence, 1/γ)"),
        "adapt_gamma_full": _r("", "requirement", "adapt γ of `full` to the measured noise "
                               "(gain.py)"),
        "gamma_full_min": _r("1/s", "physics", "the smallest γ of `full`: a 0.25 s time "
                             "constant, the recovery blend's (gain.py)"),
        "gamma_full_max": _r("1/s", "measured", "the largest γ of `full`. On an "
                             "autopilot's velocity (an EKF's output: its errors are not "
                             "white) the optimum of J(γ) (gain.py) is above any cap. On the "
                             "8 tuning flights of the corpus, `full`/autopilot, worst "
                             "n/e/d: 1.043/1.113/1.086 at 20, 1.031/1.111/1.048 at 40, "
                             "1.026/1.111/1.049 at 100; a noise fault's samples inside the "
                             "gate move `full` more "
                             "before isolation: lost axis 1 s after the onset, mean of the "
                             "120 cases, 0.044/0.047/0.050 m/s, largest jump 0.024/0.025/"
                             "0.033 m/s. A switch back is blended at gamma_full_min, so it "
                             "is not the jump that set 20 before", sensitivity=True),
        "aero_aiding": _r("", "requirement", "learn the drag model while healthy and publish "
                          "the `aided` estimate of a lost axis (issue 13)"),
        "aero_active": _r("", "requirement", "`active`'s lost axis is the aided one while the "
                          "aiding runs (issue 13; its rules keep it from being worse than "
                          "dead reckoning on the corpus)"),
        "aero_control": _r("", "requirement", "SERVO_OUTPUT_RAW's channel map for the "
                           "cyclic regressors (None: ignored); [estimation.aero_control]"),
        "aero_prior_k_per_s": _r("1/s", "physics", "an informed prior on the linear drag k "
                                 "(0: off); 0.437 for glmav-sitl's default vehicle, "
                                 "equations.md eqs. 7-8 linearised in the downwash"),
        "aero_prior_k_sigma_per_s": _r("1/s", "physics", "its σ: the vehicle file's "
                                       "parameters' uncertainty (~7 % of k)"),
        "aero_symmetric_xy": _r("", "physics", "one drag along body x and y (rotors "
                                "symmetric about z: quad, hexa, octa; ArduPilot's SIM_Frame "
                                "has one coefficient for both): a row whose speed barely "
                                "varied borrows the other row's k, q "
                                "(estimation/aero/symmetry.py)"),
        "aero_refuse_negative_k": _r("", "physics", "no pseudo-measurement while a row's k "
                                     "is clearly negative: drag dissipates, so the law "
                                     "does not hold there (DragModelConfig."
                                     "refuse_negative_k); off for a heli without the "
                                     "cyclic regressors"),
    },
    "DragModelConfig": {
        "tau_s": _r("s", "physics", "forgetting time constant: slow against gusts, fast "
                    "against a wind change over minutes (issue 13: ~60-120 s)"),
        "prior_sigma_theta": _r("(m/s², 1/s, m/s², m/s², 1/m)", "measured", "prior σ of "
                                "θ = (c, k, k·w_n, k·w_e, q) around 0: k, k·w, q several "
                                "times any plausible value (uninformed); c 0.5 m/s², a MEMS "
                                "accelerometer's bias after calibration plus a trim force. "
                                "Measured on f_coax_clean: an uninformed c gave a 1.4 m/s "
                                "phantom wind and 2 m/s errors after the next turn (the "
                                "sensitivity varies c, the first element)",
                                sensitivity=True),
        "sigma_f_initial_mps2": _r("m/s²", "physics", "σ_f before 10 effective samples: "
                                   "large, untrusted until data says otherwise"),
        "sigma_f_floor_mps2": _r("m/s²", "physics", "floor of σ_f: a MEMS accelerometer's "
                                 "noise over 40 ms plus vibration (a simulator's can fit to "
                                 "0.003)"),
        "n_eff_min": _r("samples", "statistic", "effective samples before the model may be "
                        "trusted (≈ 10 s at 10 Hz; 5 parameters per row)"),
        "speed_spread_min_mps": _r("m/s", "statistic", "minimum std of the body-frame speed "
                                   "per axis: k is not identifiable without it"),
        "k_z_min": _r("σ", "statistic", "k_j / σ(k_j) at least this: k clearly > 0"),
        "sigma_f_max_mps2": _r("m/s²", "physics", "a model explaining less is refused: at "
                               "k ≈ 0.25 1/s, σ_f = 0.15 m/s² is already 0.6 m/s per row"),
        "outlier_sigma": _r("σ", "statistic", "a sample beyond this many σ is not learnt (a "
                            "GPS glitch): 6e-7 of a fitting model's samples"),
        "outlier_run_max": _r("samples", "statistic", "...unless this many come in a row "
                              "(the vehicle changed): 2.5 s at 10 Hz"),
        "changing_outliers": _r("samples", "measured", "the model is changing while the "
                                "weighted outlier count over changing_window_s exceeds this: "
                                "a fitting model sees a 5σ outlier in 6e-7 of its samples. "
                                "Measured on a_quad_wind: its 4 m/s wind switched on at "
                                "63.7 s gave 51 then 90 outliers in the next two 5 s spans, "
                                "the clean coax none", sensitivity=True),
        "changing_window_s": _r("s", "measured", "window of that count (a_quad_wind, as "
                                "changing_outliers)", sensitivity=True),
        "prior_every": _r("samples", "statistic", "the prior's share of the forgetting is put "
                          "back every this many samples (its cost amortised)"),
        "validate_every": _r("samples", "statistic", "one validation every this many learnt "
                             "samples: validations ~0.5 s apart are nearly independent"),
        "sigma_v_meas_mps": _r("m/s", "physics", "noise of the measured value a validation "
                               "compares with: a GPS velocity's 1σ"),
        "nees_n_min": _r("validations", "statistic", "effective validations per axis before "
                         "it may be aided: a NEES mean from 10 has ~45 % relative σ"),
        "nees_max": _r("", "statistic", "NEES above this refuses the axis: 3σ above a "
                       "consistent model's mean NEES (χ²_n/n, σ √(2/n)) over the "
                       "nees_n_min validations, correlated to n ≈ 10/3, is 3.3; was 25, "
                       "whose inflated models were worse than dead reckoning in wind"),
        "aided_axes": _r("", "measured", "NED axes that may be aided: d is off, forced on it "
                         "made d worse than dead reckoning in 5 of 40 ArduPilot SITL cases "
                         "(worst 60 s RMS 1.68 vs 0.16 m/s), better in none "
                         "(docs/benchmarks/aero.md)"),
        "row_consistency_sigma": _r("σ", "statistic", "both rows' values of the lost axis "
                                    "must agree within this many σ (3σ: 0.3 %)"),
        "inconsistency_max": _r("", "statistic", "more than this fraction of recent two-row "
                                "pseudo-measurements inconsistent and the model is broken "
                                "(70× the 3σ rate)"),
        "inconsistency_window": _r("calls", "statistic", "window of that fraction "
                                   "(exponential, at least 10 calls)"),
        "max_gap_s": _r("s", "physics", "a longer gap forgets at most this (clipped)"),
        "quadratic": _r("", "physics", "fit the quadratic drag term (A2): on "
                        "h_quad_gps_glitch a linear-only fit leaves 0.16 m/s² on x"),
        "control": _r("", "requirement", "the swash-plate cyclic regressor (C1), for a "
                      "coaxial GLMAV that sends its servo outputs"),
        "prior_sigma_control": _r("m/s² per unit ρ", "physics", "prior σ of its gain: "
                                  "uninformed (the default GLMAV's is 1.1)"),
        "prior_k": _r("(1/s, 1/s)", "physics", "an informed prior on k (None: uninformed); "
                      "set from [estimation] aero_prior_k_per_s"),
    },
    "AidedAxisConfig": {
        "accel_noise_mps2_rthz": _r("m/s²/√Hz", "physics", "white noise of the earth-frame "
                                    "acceleration: a small MEMS IMU with vibration (~0.05)"),
        "accel_bias_h_mps2": _r("m/s²", "physics", "constant error of the horizontal "
                                "acceleration: bias after calibration (~0.02) plus g·sin of "
                                "a 0.2° attitude error (0.035)"),
        "accel_bias_v_mps2": _r("m/s²", "physics", "vertical: the attitude error enters at "
                                "second order, the bias alone"),
        "gate_sigma": _r("σ", "statistic", "an update beyond this many σ of its innovation "
                         "is rejected (6e-7 for a Gaussian)"),
        "corr_time_s": _r("s", "physics", "correlation time of the pseudo-measurement's "
                          "white part (turbulence, manoeuvres): R inflated by τ_c/Δt"),
        "model_corr_time_s": _r("s", "physics", "correlation time of its model part (changes "
                                "only as the attitude does)"),
        "max_rejections": _r("updates", "statistic", "this many rejections in a row and the "
                             "aiding stops (5 s at 10 Hz)"),
        "sigma_v_meas_mps": _r("m/s", "measured", "rule 1: noise of the measured axes "
                               "against a 1 s IMU prediction: the innovation reaches "
                               "0.19 m/s on the ArduPilot corpus, 0.53 on glmav-sitl's "
                               "autopilot profile; 0.2 (gate 1.06 m/s)", sensitivity=True),
        "meas_track_time_s": _r("s", "physics", "rule 1: time constant of the measured "
                                "axes' IMU-propagated prediction"),
        "meas_gate_sigma": _r("σ", "statistic", "rule 1: gate on that innovation (6e-7 for a "
                              "Gaussian; none of the benchmark's 60 000)"),
        "meas_holdoff_s": _r("s", "physics", "rule 1: suspect this long after the last "
                             "failed gate (one track time)"),
        "meas_resync_s": _r("s", "physics", "rule 1: after this long suspect, the "
                            "prediction is re-synchronised"),
        "stale_window_s": _r("s", "statistic", "rule 2: window of the z² average"),
        "stale_nees_max": _r("", "measured", "rule 2: the average z² above this and the "
                             "model is stale (a consistent pair stays below 1; measured "
                             "≤ 0.54 on the corpus where the model holds)", sensitivity=True),
        "stale_gap_z2": _r("", "statistic", "rule 2: after a gap the first "
                           "pseudo-measurement decides alone above this z² (3σ)"),
        "scatter_trend_s": _r("s", "physics", "rule 4: time constant of the local trend "
                              "(many white correlation times, one model correlation time)"),
        "scatter_window_s": _r("s", "statistic", "rule 4: window of the mean normalised "
                               "scatter: ~10 correlation times (χ²₁₀/10 > 2 with ~3 %)"),
        "scatter_max": _r("", "measured", "rule 4: mean normalised scatter above this and "
                          "the model's σ is not believed: χ²₁₀/10 > 2 with ~3 %; measured "
                          "0.04-0.5 median (largest 1.6) on the corpus coax and heli, "
                          "1.5-17 on the quad whose model is biased", sensitivity=True),
        "scatter_trend_min_s": _r("s", "physics", "rule 4: the trend extrapolates at least "
                                  "one white correlation time of its own data"),
    },
}  # fmt: skip

#: (module, name, Reason): the named module constants that tune the estimation.
MODULE_CONSTANTS: tuple[tuple[str, str, Reason], ...] = (
    (f"{_PKG}.fdi_axis", "CHI2_1_MEDIAN", _r("", "statistic", "median of χ²₁: the nominal "
     "level of a squared Gaussian difference in the noise test")),
    (f"{_PKG}.fdi_reference", "LAG_WINDOW_S", _r("s", "physics", "window of the lag "
     "regressor L (the IMU's mean acceleration over it): 0.1 s, shorter than the lags it "
     "measures (0.1-0.2 s), longer than an IMU period")),
    (f"{_PKG}.fdi_reference", "_V0_PRECISION", _r("1/(m/s)²", "physics", "precision of the "
     "free V0 prior: 1/(100 m/s)², far wider than any velocity")),
    (f"{_PKG}.fdi_reference", "OBSERVED_SIGMA", _r("σ", "statistic", "a fitted parameter is "
     "used (not its prior's 0) beyond 2σ of its own")),
    (f"{_PKG}.fdi_change", "MIN_PRE_SAMPLES", _r("samples", "statistic", "a step needs a "
     "before: samples of the axis before a candidate change time")),
    (f"{_PKG}.fdi_change", "STEP_FILTER_TAUS_S", _r("s", "physics", "time constants of the "
     "low-pass a velocity step may come through (an autopilot's estimator smooths it: "
     "0-0.4 s)")),
    (f"{_PKG}.streams", "IMU_INTERVAL_GAIN", _r("", "statistic", "running-mean gain of the "
     "IMU interval: 1/50 samples")),
    (f"{_PKG}.streams", "MEASUREMENT_INTERVAL_GAIN", _r("", "statistic", "running-mean gain "
     "of the measurement interval: 1/20 (real vehicles send it at 1-5 Hz, unevenly)")),
    (f"{_PKG}.streams", "MISSING_INTERVALS", _r("intervals", "statistic", "a measurement is "
     "missing after max(missing_timeout_s, this many mean intervals): a lone late sample "
     "is not a stopped stream")),
    (f"{_PKG}.seed", "SEED_MAX_AGE_S", _r("s", "physics", "the oldest state a taken-over "
     "vehicle continues from: |∫V̇ dt| ≤ max|V̇|·age, 0.2 m/s at 0.1 m/s² in a hover")),
    (f"{_PKG}.seed", "SEED_CHECK_S", _r("s", "requirement", "measurements this long after a "
     "seed are checked against it (issue 31 D1)")),
    (f"{_PKG}.seed", "SEED_GATE_SIGMA", _r("σ", "statistic", "the seed check's gate: 6e-7 "
     "for a Gaussian axis")),
    (f"{_PKG}.seed", "SEED_CHECK_ACCEL_MPS2", _r("m/s²", "physics", "1σ of the unseen mean "
     "acceleration over the seed's age and lag (3σ: a brisk manoeuvre)")),
    (f"{_PKG}.vehicle", "RESOLVE_S", _r("s", "physics", "GPS velocities this far apart tell "
     "which of two IMUs is wrong: 0.3 m/s² moves the dead reckoning 0.3 m/s in 1 s, "
     "several σ of a GPS velocity")),
    (f"{_PKG}.vehicle", "ACCEL_EVENT_HOLD_S", _r("s", "requirement", "an accel_bias event "
     "stays in the health record's faults this long (subscribers must see it)")),
    (f"{_PKG}.aiding", "RETURN_TIME_S", _r("s", "measured", "time constant of the active "
     "estimate's return to the dead reckoning when the aided offset is dropped: the largest "
     "offset on the corpus (0.9 m/s, f_coax_clean n at 65.2 s) then moves the estimate "
     "≤ 0.02 m/s per record at 50 Hz, inside the 0.05 m/s jump bound", sensitivity=True)),
)  # fmt: skip


class ConstantRow(NamedTuple):
    """One row of docs/reference/constants.md: ``name`` is ``Class.field`` or
    ``module.NAME`` (module relative to glmav_observer.estimation)."""

    name: str
    value: Any
    reason: Reason


def _class(cls_name: str, module: str) -> Any:
    return getattr(importlib.import_module(module), cls_name)


def constant_rows() -> list[ConstantRow]:
    """Every constant (module docstring); ``ValueError`` naming a field without a reason
    or a reason without a field."""
    rows: list[ConstantRow] = []
    errors: list[str] = []
    for cls_name, module in CLASSES:
        cls = _class(cls_name, module)
        default = cls()
        external = CLASS_REASONS.get(cls_name, {})
        names = set()
        for f in dataclasses.fields(cls):
            value = getattr(default, f.name)
            if dataclasses.is_dataclass(value):
                continue  # a nested section: its own class in CLASSES
            names.add(f.name)
            reason = reason_of(f) or external.get(f.name)
            if reason is None:
                errors.append(f"{cls_name}.{f.name} has no reason")
                continue
            rows.append(ConstantRow(f"{cls_name}.{f.name}", value, reason))
        errors += [f"{cls_name}.{n}: a reason for no field" for n in set(external) - names]
    for module, name, reason in MODULE_CONSTANTS:
        mod = importlib.import_module(module)
        if not hasattr(mod, name):
            errors.append(f"{module}.{name}: a reason for no constant")
            continue
        rows.append(
            ConstantRow(f"{module.removeprefix(_PKG + '.')}.{name}", getattr(mod, name), reason)
        )
    if errors:
        raise ValueError("constants without reasons: " + "; ".join(errors))
    return rows
