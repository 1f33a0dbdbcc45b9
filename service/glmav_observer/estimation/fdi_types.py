"""The FDI's settings and vocabulary: :class:`FdiConfig` (``[fdi]`` of
``configs/service.toml``), the state of an axis, the kinds of fault and the verdict on one
sample. Shared by the reference fit (:mod:`~glmav_observer.estimation.fdi_reference`), the
axis monitor (:mod:`~glmav_observer.estimation.fdi_axis`) and the detector
(:mod:`~glmav_observer.estimation.fdi`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple

from glmav_observer.estimation.imu_monitor import ImuMonitorConfig
from glmav_observer.estimation.reasons import const


class AxisState(Enum):
    """Health of one velocity axis (HealthRecord ``axis_state``)."""

    WARMUP = "warmup"  # no vetted reference yet: only dropout and freeze are tested
    OK = "ok"
    SUSPECT = "suspect"  # a test fails, not yet k samples in a row
    FAULTY = "faulty"  # isolated
    RECOVERING = "recovering"  # isolated, healthy again for less than recovery_s


#: Fault kinds decided by comparing the measurement with the IMU (revisable when the IMU
#: itself is found at fault); dropout, freeze and unaided are seen in the measurement alone.
RESIDUAL_KINDS = frozenset({"bias", "noise"})


class FaultKind(Enum):
    DROPOUT = "dropout"
    FREEZE = "freeze"
    BIAS = "bias"
    NOISE = "noise"
    UNAIDED = "unaided"  # the autopilot says this velocity is not aided (GPS lost)


@dataclass(frozen=True, slots=True)
class DespikeConfig:
    """The IMU spike threshold (``[fdi.despike]`` of ``configs/service.toml``) of
    :class:`~glmav_observer.estimation.despike.Despiker`."""

    floor_mps2: float = const(
        40.0, unit="m/s²", source="physics",
        reason="the smallest ‖Δf‖ between successive IMU samples held out as a spike: "
        "4 g, beyond a multirotor's manoeuvre between two samples (< 1 g at 50 Hz) and "
        "below a shock's or a corrupt value's (hundreds of m/s²); raise it for a vehicle "
        "whose IMU sees larger steps (a launch)",
    )  # fmt: skip
    k_sigma: float = const(
        8.0, unit="σ", source="statistic",
        reason="or this many RMS of ‖Δf‖ between accepted samples, if larger: a vibrating "
        "IMU raises its own bar (ArduPilot SITL SIM_ACC1_RND = 5: ‖Δf‖ RMS ≈ 12 m/s²); "
        "white noise exceeds 8 RMS practically never (‖Δf‖²/2σ² ~ χ²₃ > 192: 2e-41)",
    )  # fmt: skip
    tau_samples: int = const(
        100, unit="samples", source="physics",
        reason="memory of the running ‖Δf‖ RMS: 2 s at 50 Hz, fast against a change of "
        "vibration (throttle), slow against one spike",
    )  # fmt: skip


@dataclass(frozen=True, slots=True)
class FdiTuning:
    """The FDI's inner constants (not read from ``service.toml``: none depends on the
    vehicle; each is a multiple of a measured scale, a statistic or a window whose reason
    is given). docs/reference/constants.md lists them."""

    scale_winsor_sigma: float = const(
        4.0, unit="σ", source="statistic",
        reason="a residual is winsorised at this many σ_r before it enters the running "
        "spread (and the running means of successive and second differences): one outlier "
        "moves the mean by at most 16σ²/scale_samples, a Gaussian residual is cut in 6e-5 "
        "of the samples (the `16.0 *` caps of fdi_axis.py, 4² = 16)",
    )  # fmt: skip
    arm_min_rows: int = const(
        10, unit="samples", source="statistic",
        reason="vetted rows of an axis before its residual tests arm: more than the 8 "
        "parameters of the shared fit, so the axis's V0 is not fitted from one or two rows",
    )  # fmt: skip
    rearm_rows: int = const(
        20, unit="samples", source="statistic",
        reason="vetted rows of a recovered axis before its prediction comes from the live "
        "fit again (not the frozen one): twice arm_min_rows, the fit has the axis's new level",
    )  # fmt: skip
    ramp_limit_mps2: float = const(
        0.5, unit="m/s²", source="physics",
        reason="a residual isolation is withdrawn when the residual ramps faster than this "
        "(beyond 3σ of the slope): above any accelerometer bias the fit leaves (prior "
        "prior_bias_mps2 = 0.3 m/s²); a velocity sensor's fault is an offset or noise, a "
        "ramp is the IMU's path drifting (an attitude estimator lost in a ballistic climb)",
    )  # fmt: skip
    ramp_window_s: float = const(
        1.0, unit="s", source="physics",
        reason="window of the ramp test: a ramp of ramp_limit_mps2 over it is 0.5 m/s, "
        "10σ of a 0.05 m/s measurement; 10-50 samples at 10-50 Hz",
    )  # fmt: skip
    ramp_min_samples: int = const(
        8, unit="samples", source="statistic",
        reason="a slope and its σ from fewer points (n − 2 degrees of freedom) is too "
        "uncertain to withdraw an isolation on",
    )  # fmt: skip
    ramp_slope_sigma: float = const(
        3.0, unit="σ", source="statistic",
        reason="the slope must exceed ramp_limit_mps2 by this many of its own σ "
        "(one-sided 3σ: 1.3e-3 false withdrawals per test)",
    )  # fmt: skip
    noise_spread_sigma: float = const(
        3.0, unit="σ", source="statistic",
        reason="a failing window whose robust spread (1.4826 MAD) exceeds this many σ_r is "
        "noise, not a bias step (a step keeps the spread of each cluster at σ_r; a "
        "Gaussian window exceeds 3σ_r rarely)",
    )  # fmt: skip
    recovery_dr_sigma: float = const(
        3.0, unit="σ", source="statistic",
        reason="recovery of a dropout/freeze/noise isolation: the residual against the "
        "frozen dead reckoning may exceed the bias threshold by this many σ of the dead "
        "reckoning's drift (3σ: 0.3 % of healthy samples fail)",
    )  # fmt: skip
    recovery_meas_sigma: float = const(
        2.0, unit="σ", source="statistic",
        reason="... plus this many σ_r of the measurement's own noise on one sample",
    )  # fmt: skip
    bias_step_back_fraction: float = const(
        0.5, unit="", source="statistic",
        reason="a bias fault ends when the median residual steps back by more than this "
        "fraction of the fault's size between two bias_samples windows: half way is the "
        "decision boundary between 'still biased' and 'back'",
    )  # fmt: skip
    bias_hold_sigma: float = const(
        3.0, unit="σ", source="statistic",
        reason="after the step back the level must hold within max(bias_threshold_mps, "
        "this many σ_r) for recovery_s",
    )  # fmt: skip
    bias_return_fraction: float = const(
        0.5, unit="", source="statistic",
        reason="or the residual comes back within max(bias_threshold_mps, this fraction of "
        "the fault): nearer to no fault than to the fault",
    )  # fmt: skip
    bias_recovery_history: int = const(
        24, unit="samples", source="statistic",
        reason="residuals kept during a bias isolation: two bias_samples windows (the "
        "step-back test) twice over",
    )  # fmt: skip
    own_noise_history: int = const(
        64, unit="samples", source="statistic",
        reason="second differences of the measurement kept: the ramp test reads up to "
        "ramp_window_s of them (≤ 50 at 50 Hz), the own-noise test noise_samples",
    )  # fmt: skip
    freeze_prior_rate: float = const(
        0.5, unit="", source="statistic",
        reason="prior of a stream's repeat rate: 'unknown' (between never and always), so "
        "until the stream has shown its rate an exact repeat needs the IMU's word",
    )  # fmt: skip
    freeze_prior_samples: float = const(
        2.0, unit="samples", source="statistic",
        reason="weight of that prior: 2 samples, so the running rate is the stream's own "
        "after a few samples",
    )  # fmt: skip
    refit_rows: int = const(
        15, unit="samples", source="requirement",
        reason="the reference is refitted after this many new vetted rows (5 measurements "
        "of 3 axes: 0.2 s at 25 Hz, 1 s at 5 Hz): the fit is the FDI's largest cost "
        "(benchmarks/bench_observer.py), and its rows enter only vet_delay_s = 0.6 s late, "
        "so a refit at every row would add no information sooner than the vetting delay",
    )  # fmt: skip
    fit_min_rows: int = const(
        12, unit="samples", source="statistic",
        reason="rows before the first fit: more than the 8 parameters",
    )  # fmt: skip
    fit_min_span_s: float = const(
        1.0, unit="s", source="physics",
        reason="span of the rows before the first fit: b and δψ need the attitude to move "
        "(the same 1 s as warmup_s's lower bound)",
    )  # fmt: skip
    lag_memory_s: float = const(
        120.0, unit="s", source="physics",
        reason="time constant of the lag memory: a link's lag is a property of the "
        "autopilot, constant over minutes, learnt over many bias_window_s windows",
    )  # fmt: skip
    lag_sigma_min_s: float = const(
        0.02, unit="s", source="physics",
        reason="the lag prior's σ is never below this (a lag can change: a GPS's own lag "
        "moves by a fraction of its 0.1-0.2 s)",
    )  # fmt: skip
    lag_keep_sigma: float = const(
        2.0, unit="σ", source="statistic",
        reason="a window whose lag is within this many σ of the known lag keeps the known "
        "one (its own estimate times a vibrating IMU's acceleration would add noise)",
    )  # fmt: skip


@dataclass(frozen=True, slots=True)
class FdiConfig:
    """FDI settings (``[fdi]`` of ``configs/service.toml``; all documented there).

    Every field carries its reason (:func:`~glmav_observer.estimation.reasons.const`);
    ``imu`` is ``[fdi.imu]``, ``despike`` ``[fdi.despike]``; ``tuning`` is not read."""

    sigma_meas_mps: float = const(
        0.05, unit="m/s", source="physics",
        reason="residual spread assumed before any is measured: a GPS velocity's 1σ "
        "(u-blox: 0.05 m/s); replaced by the measured σ_r within ~scale_samples",
    )  # fmt: skip
    sigma_floor_mps: float = const(
        0.02, unit="m/s", source="physics",
        reason="the measured spread is never below this: a simulator's noise-free stream "
        "would make every threshold vanish; 0.02 is below any real GPS's velocity noise",
    )  # fmt: skip
    scale_samples: int = const(
        250, unit="samples", source="statistic",
        reason="memory of the running spread: ~10 s at 25 Hz; the σ of an estimated σ from "
        "n samples is σ/√(2n) = 4.5 %",
    )  # fmt: skip
    vet_delay_s: float = const(
        0.6, unit="s", source="requirement",
        reason="samples enter the reference only this old: longer than the 0.5 s isolation "
        "bound, so a fault is isolated before its samples could teach the reference",
    )  # fmt: skip
    bias_window_s: float = const(
        4.0, unit="s", source="physics",
        reason="window of the reference fit: long enough for the attitude to excite b and "
        "δψ, short against the drift of an accelerometer bias and of the heading error",
    )  # fmt: skip
    warmup_s: float = const(
        1.5, unit="s", source="physics",
        reason="vetted span before the residual tests arm (≥ 1 s: the fit needs the "
        "attitude to move); 1.5 s of a 4 s window",
    )  # fmt: skip
    gate_sigma: float = const(
        5.0, unit="σ", source="statistic",
        reason="a residual beyond this many s_j keeps the sample out of `full`: a Gaussian "
        "residual exceeds 5σ in 5.7e-7 of the samples (one per ~20 flight hours per axis "
        "at 25 Hz)",
    )  # fmt: skip
    dropout_samples: int = const(
        2, unit="samples", source="requirement",
        reason="consecutive NaN samples that isolate a dropout: one NaN is a lost value "
        "(held), two are a stopped axis; 2 samples at ≥ 5 Hz meet the 0.5 s bound",
    )  # fmt: skip
    missing_timeout_s: float = const(
        0.5, unit="s", source="requirement",
        reason="no measurement for max(this, 3.5 mean intervals) and every configuration "
        "dead-reckons: the 0.5 s isolation bound",
    )  # fmt: skip
    freeze_repeats: int = const(
        3, unit="samples", source="statistic",
        reason="exact repeats that isolate a freeze: an EKF's float output repeats by "
        "chance with probability < freeze_repeat_rate per sample, 3 in a row < 1e-5",
    )  # fmt: skip
    freeze_motion_mps: float = const(
        0.1, unit="m/s", source="statistic",
        reason="the IMU-predicted change beyond which a repeat counts: 2σ of a GPS "
        "velocity (0.05 m/s) — a stream that repeats in a hover is not frozen",
    )  # fmt: skip
    freeze_repeat_rate: float = const(
        0.02, unit="", source="statistic",
        reason="a stream repeating less often than this fraction seldom repeats: exact "
        "repeats alone are a freeze (a noise-free SITL GPS repeats ~70 %, a float EKF "
        "output ~0 %: the threshold separates them by decades)",
    )  # fmt: skip
    bias_samples: int = const(
        6, unit="samples", source="requirement",
        reason="residuals in the bias test's median: 3 outliers cannot move it; with "
        "k_isolate = 3 a step is isolated after ~6 samples (0.24 s at 25 Hz), within 0.5 s",
    )  # fmt: skip
    bias_threshold_mps: float = const(
        0.15, unit="m/s", source="requirement",
        reason="the bias test's absolute floor: 3σ of a GPS velocity (0.05 m/s); the "
        "smallest injected bias (0.5 m/s) is 3× above it",
    )  # fmt: skip
    bias_sigma: float = const(
        5.0, unit="σ", source="statistic",
        reason="bias threshold in s_j (median of 6: its σ is ~1.25σ/√6, so 5σ of a sample "
        "is ~10σ of the median: no false isolation from noise)",
    )  # fmt: skip
    noise_samples: int = const(
        12, unit="samples", source="statistic",
        reason="successive differences in the noise test's median: for white residuals the "
        "ratio (median over its nominal) has a 95 % range of 0.21-3.4 with 12 (simulated, "
        "2e5 windows); fewer widen it, more delay the isolation beyond 0.5 s at 25 Hz",
    )  # fmt: skip
    noise_ratio_threshold: float = const(
        12.0, unit="", source="statistic",
        reason="the median squared difference over its nominal (2σ_r²·0.4549) beyond this "
        "fails: for white residuals the ratio's 99.999th percentile is 9.3 (simulated, 2e5 "
        "windows of 12), so a healthy axis does not fail; it fails once the noise σ has "
        "grown ~3.4×; the injected noise (σ 0.5 m/s on σ_r ≈ 0.03) is ×280",
    )  # fmt: skip
    k_isolate: int = const(
        3, unit="samples", source="requirement",
        reason="consecutive failing samples that isolate a bias or noise fault: one or two "
        "fail on a lone outlier; 3 at ≥ 10 Hz stay within the 0.5 s bound",
    )  # fmt: skip
    recovery_s: float = const(
        2.0, unit="s", source="requirement",
        reason="an isolated axis passes every test this long before it is used again: "
        "many noise_samples windows, so an intermittent fault does not flap",
    )  # fmt: skip
    sigma_handover_mps: float = const(
        0.03, unit="m/s", source="physics",
        reason="1σ of the hand-over estimate: the vetted measurement filtered by `full` "
        "(σ_meas 0.05 reduced by the observer's averaging)",
    )  # fmt: skip
    sigma_velocity_mps: float = const(
        0.04, unit="m/s", source="measured",
        reason="1σ of a GPS-aided autopilot velocity against truth, per axis: the anchor "
        "of an axis flagged dead-reckoned without a fault (GPS lost, a silent stream). "
        "Measured: ArduPilot's EKF on the tuning flights a_quad_wind, f_coax_clean, "
        "g_heli_clean, h_quad_gps_glitch: 0.027-0.038 m/s horizontal, rounded up",
        sensitivity=True,
    )  # fmt: skip
    imu_monitor: bool = const(
        True, unit="", source="requirement",
        reason="compare the vehicle's redundant IMUs (SCALED_IMU2/3) with its own",
    )  # fmt: skip
    sigma_bias_mps2: float = const(
        0.03, unit="m/s²", source="physics",
        reason="1σ of the accelerometer bias left after the fit (dead reckoning grows σ_b·t): "
        "a MEMS accelerometer's bias instability plus g·sin of a 0.1° attitude error",
    )  # fmt: skip
    accel_noise_density: float = const(
        4e-3, unit="m/s²/√Hz", source="physics",
        reason="random-walk growth of the dead reckoning: a MEMS accelerometer's noise "
        "density (MPU-6000: 400 µg/√Hz ≈ 4e-3 m/s²/√Hz)",
    )  # fmt: skip
    min_imu_rate_hz: float = const(
        5.0, unit="Hz", source="physics",
        reason="below this IMU rate the dead reckoning between samples (a 0.2 s hold) is "
        "no prediction: residual tests off, dropout and freeze only",
    )  # fmt: skip
    prior_bias_mps2: float = const(
        0.3, unit="m/s²", source="physics",
        reason="prior 1σ of the body accelerometer bias: ~30 mg, a MEMS accelerometer's "
        "bias before an in-flight calibration",
    )  # fmt: skip
    prior_yaw_rad: float = const(
        0.1, unit="rad", source="physics",
        reason="prior 1σ of the heading error: a magnetometer heading's ~6°",
    )  # fmt: skip
    prior_lag_s: float = const(
        0.1, unit="s", source="physics",
        reason="σ of the measurement-lag prior (zero mean): a GPS velocity is 0.1-0.2 s "
        "late unless the autopilot compensates it (ArduPilot's and PX4's EKFs do)",
    )  # fmt: skip
    max_lag_s: float = const(
        0.5, unit="s", source="physics",
        reason="the fitted lag is bounded to [0, this]: no autopilot's velocity is later",
    )  # fmt: skip
    correlation_samples: float = const(
        5.0, unit="samples", source="physics",
        reason="rows of one axis per independent sample: an autopilot's velocity is "
        "filtered (EKF time constants of ~0.2 s at 25 Hz), its errors correlated over a "
        "few samples; the fit's P is inflated by this factor",
    )  # fmt: skip
    max_bias_mps2: float = const(
        2.0, unit="m/s²", source="physics",
        reason="a fitted bias is bounded to this norm: beyond any accelerometer's "
        "(±2 m/s² ≈ 200 mg)",
    )  # fmt: skip
    change_window_s: float = const(
        1.5, unit="s", source="requirement",
        reason="residuals of all axes compared by the velocity-step / accelerometer-step "
        "test: the 0.5 s isolation bound plus a second of history before the change",
    )  # fmt: skip
    overdue_intervals: float = const(
        1.5, unit="intervals", source="statistic",
        reason="a measurement is overdue (its axes flagged dead-reckoned) this many mean "
        "intervals after the last one: a sample later than half an interval is already "
        "unusual on a steady stream, and a lone late one costs a record or two of a σ "
        "that is still σ0",
    )  # fmt: skip
    imu: ImuMonitorConfig = field(default_factory=ImuMonitorConfig)
    despike: DespikeConfig = field(default_factory=DespikeConfig)
    tuning: FdiTuning = field(default_factory=FdiTuning)


class AxisVerdict(NamedTuple):
    """What the FDI says about one axis after one measurement (a named tuple: three are
    made per measurement)."""

    use: bool  # feed this sample to the observers that measure the axis
    residual_mps: float  # NaN if not computable
    test_ratio: float  # max over the tests of statistic/threshold; > 1 fails
    state: AxisState
