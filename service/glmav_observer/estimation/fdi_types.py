"""The FDI's settings and vocabulary: :class:`FdiConfig` (``[fdi]`` of
``configs/service.toml``), the state of an axis, the kinds of fault and the verdict on one
sample. Shared by the reference fit (:mod:`~glmav_observer.estimation.fdi_reference`), the
axis monitor (:mod:`~glmav_observer.estimation.fdi_axis`) and the detector
(:mod:`~glmav_observer.estimation.fdi`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple


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
class FdiConfig:
    """FDI settings (``[fdi]`` of ``configs/service.toml``; all documented there)."""

    sigma_meas_mps: float = 0.05
    sigma_floor_mps: float = 0.02
    scale_samples: int = 250
    vet_delay_s: float = 0.6
    bias_window_s: float = 4.0
    warmup_s: float = 1.5
    gate_sigma: float = 5.0
    dropout_samples: int = 2
    missing_timeout_s: float = 0.5
    freeze_repeats: int = 3
    #: the IMU-predicted change of an axis since its value was first seen beyond which a
    #: repeat of that value counts towards a freeze
    freeze_motion_mps: float = 0.1
    #: a stream that repeats its value less often than this (fraction of samples) seldom
    #: repeats: exact repeats alone are a freeze
    freeze_repeat_rate: float = 0.02
    bias_samples: int = 6
    bias_threshold_mps: float = 0.15
    bias_sigma: float = 5.0
    noise_samples: int = 12
    noise_ratio_threshold: float = 12.0
    k_isolate: int = 3
    recovery_s: float = 2.0
    sigma_handover_mps: float = 0.03
    #: 1σ of a GPS-aided autopilot velocity against truth, per axis: the anchor of an
    #: axis flagged dead-reckoned without a fault (``drift``: a silent stream, GPS lost).
    #: ArduPilot's EKF on the tuning flights: 0.027-0.038 m/s horizontal (a_quad_wind,
    #: f_coax_clean, g_heli_clean, h_quad_gps_glitch), rounded up
    sigma_velocity_mps: float = 0.04
    sigma_bias_mps2: float = 0.03
    accel_noise_density: float = 4e-3
    min_imu_rate_hz: float = 5.0
    prior_bias_mps2: float = 0.3
    prior_yaw_rad: float = 0.1
    #: σ of the measurement-lag prior (zero mean): a GPS velocity is 0.1-0.2 s late
    #: unless the autopilot compensates it (ArduPilot's and PX4's EKFs do)
    prior_lag_s: float = 0.1
    max_lag_s: float = 0.5
    #: rows of one axis per independent sample: an autopilot's velocity is filtered, its
    #: errors correlated over a few samples (P is inflated by this factor)
    correlation_samples: float = 5.0
    max_bias_mps2: float = 2.0
    change_window_s: float = 1.5


class AxisVerdict(NamedTuple):
    """What the FDI says about one axis after one measurement (a named tuple: three are
    made per measurement)."""

    use: bool  # feed this sample to the observers that measure the axis
    residual_mps: float  # NaN if not computable
    test_ratio: float  # max over the tests of statistic/threshold; > 1 fails
    state: AxisState
