"""One vehicle's estimator: the observer bank, fault isolation, the active estimate, records.

Pure (no I/O, no clock but the vehicle's): :meth:`VehicleEstimator.on_sample` takes the
typed samples of one vehicle in vehicle-time order and returns the records to publish.

Step rule (zero-order hold). Every sample at a time t later than the bank's time first
advances the bank from its time to t with the inputs held since the previous samples
(:meth:`ObserverBank.step` solves (16) exactly over the interval), then updates the held
input it carries: attitude (ATTITUDE), specific force and gyro rates (IMU), the velocity
measurement (LOCAL_POSITION_NED, corrected at its own time stamp). Velocity records are
produced after each IMU-driven step; a health record every 1/``health_rate_hz`` s.

Held measurement. Between two velocity samples the measurement is held; a held y lags
the truth by about its age times |V̇|. With ``propagate_held_measurement`` it is carried
forward with the IMU instead, y(t) ≈ y(t_y) + ∫_{t_y}^{t} (E f + g e_d − b̂) dt (V̇ = E Γ,
equations.md), which removes that lag (docs/observer.md measures both).

Accelerometer bias and heading error. The FDI fits the body-frame accelerometer bias b̂
and the attitude's heading error δψ̂ from vetted samples
(:mod:`glmav_observer.estimation.fdi`). With ``compensate_accel_bias`` the bank is fed
f − b̂_obs, b̂_obs the components the fit has *observed* (|b̂_k| > 2σ_k; an unexcited one
stays at the prior's 0; ‖b̂‖ ≤ 2 m/s²), frozen at the hand-over while an axis is isolated:
a poorly observed fit cannot poison ``full``. The *active* estimate's dead-reckoned axis
also gets the observed heading term (C_j(t) − C_j(t_h)) δψ̂ since the hand-over.

IMU shocks. A single specific-force sample far from its neighbours (a shock, a corrupt
frame within the plausible range) is held out for one sample (:mod:`despike`); a real
step is accepted one sample late.

Missing stream. No velocity measurement for the timeout is not a fault of an axis: every
configuration dead-reckons (all axes unmeasured) until samples come back; no switch.

The autopilot's word. ``LOCAL_POSITION_NED`` from ArduPilot or PX4 is the autopilot's own
estimate; while ``EKF_STATUS_REPORT`` (or, from an autopilot without it, ``GPS_RAW_INT``) says it is not aided (GPS lost), the
axes concerned are isolated as ``unaided`` and re-admitted when it is aided again.

Active estimate and hand-over. ``full`` while every axis is healthy. When the FDI
isolates axis j, the configuration without j (n -> c2, e -> c3, d -> c1) is started
from the last good estimate: ``full``'s current NED velocity, which the FDI's gate kept
free of the faulty samples (if it differs from the FDI's dead reckoning from vetted data
by more than ``handover_contamination_mps``, the dead reckoning is used instead). Its
lost axis is reported as dead-reckoned with σ = √(σ0² + (σ_b t)² + q t), t since the
hand-over. When the axis recovers, ``full`` is restarted from the active estimate.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from glmav_observer.configurations import (
    CONFIG_WITHOUT_AXIS,
    CONFIGS,
    LOST_AXIS_OF_CONFIG,
    LOST_INDEX_OF_CONFIG,
    config_index,
)
from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.despike import Despiker
from glmav_observer.estimation.fdi import FaultDetector
from glmav_observer.estimation.fdi_reference import (
    LAG,
    LAG_WINDOW_S,
    Integrals,
    Reference,
    dead_reckoning_age_s,
    sigma_dead_reckoning_mps,
)
from glmav_observer.estimation.fdi_types import FdiConfig
from glmav_observer.estimation.observer import G_MPS2, EForm, gamma_full_optimal
from glmav_observer.estimation.streams import StreamTiming
from glmav_observer.frames import e_exact, rotate_flat, rotate_t_flat
from glmav_observer.ingest.samples import (
    AidingSample,
    AttitudeSample,
    ImuSample,
    Sample,
    TruthSample,
    VelocitySample,
)
from glmav_observer.records import (
    NED_AXES,
    FaultEvent,
    HealthRecord,
    MeasurementRecord,
    Record,
    ReferenceFitSummary,
    TruthRecord,
    VelocityRecord,
)

#: An ``accel_bias`` event stays in the health record's faults this long (vehicle s):
#: it isolates nothing, but subscribers and the Rerun view must see it.
ACCEL_EVENT_HOLD_S = 5.0
#: After a switch back to ``full``, its gain stays at ``gamma_full_min`` this long (s):
#: the dead reckoning's drift is corrected in ~1/γ_min = 0.25 s, not in one step.
RECOVERY_BLEND_S = 1.0
#: Measurements between two updates of the gain of ``full`` (~5 s at 25 Hz).
GAMMA_UPDATE_SAMPLES = 125
#: The oldest state (vehicle s between its estimates and the first sample it is applied
#: at) a vehicle taken over is continued from (:meth:`VehicleEstimator.seed`). The new
#: owner has none of the IMU between the two: a measured axis converges again at rate γ
#: anyway, but a dead-reckoned (isolated) axis keeps the velocity change of that interval
#: as its error, |∫ V̇ dt| ≤ max|V̇| · age (0.2 m/s at 0.1 m/s² in a hover); an older
#: state starts cold from the measurement.
SEED_MAX_AGE_S = 2.0

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class EstimatorSeed:
    """The last state another service published of a vehicle it estimated (its state
    queryable and health, docs/zenoh.md), to continue from on a ``serve --claim`` takeover."""

    t_boot_s: float  # vehicle time of the estimates
    #: NED velocity per configuration (``full``, ``c1``, ``c2``, ``c3``) and ``active``
    v_ned_mps: Mapping[str, Vec3]
    active_config: str
    #: 1σ of each dead-reckoned axis (per configuration and ``active``, where one is lost)
    sigma_lost_mps: Mapping[str, float] = field(default_factory=dict)
    #: the velocity axes isolated at ``t_boot_s`` (not ``accel_bias`` events)
    isolated: tuple[FaultEvent, ...] = ()
    #: the health record's residual per NED axis: an isolated axis's fault level
    residual_ned_mps: Vec3 = (0.0, 0.0, 0.0)
    reference_fit: ReferenceFitSummary | None = None


@dataclass(frozen=True, slots=True)
class EstimatorConfig:
    """Estimation settings (``[estimation]`` and ``[fdi]`` of ``configs/service.toml``)."""

    gamma: Mapping[str, float] | None = None
    e_form: EForm = "exact"
    g_mps2: float = G_MPS2
    health_rate_hz: float = 10.0
    propagate_held_measurement: bool = True
    compensate_accel_bias: bool = True
    compensate_lag: bool = True
    max_gap_s: float = 1.0
    handover_contamination_mps: float = 1.0
    metrics_skip_s: float = 3.0
    adapt_gamma_full: bool = True
    gamma_full_min: float = 4.0
    gamma_full_max: float = 20.0
    fdi: FdiConfig = field(default_factory=FdiConfig)


@dataclass(frozen=True, slots=True)
class SwitchEvent:
    """A change of the active configuration."""

    t_boot_s: float
    from_config: str
    to_config: str
    reason: str
    v_before_ned_mps: Vec3
    jump_mps: float | None = None  # |active after − active before| at the next record

    def to_dict(self) -> dict[str, Any]:
        return {
            "t_boot_s": self.t_boot_s,
            "from": self.from_config,
            "to": self.to_config,
            "reason": self.reason,
            "jump_mps": self.jump_mps,
        }


def merge_counters(*parts: Mapping[str, int]) -> dict[str, int]:
    """Counters of several components, summed by name, sorted by name."""
    out: dict[str, int] = {}
    for part in parts:
        for k, n in part.items():
            out[k] = out.get(k, 0) + n
    return dict(sorted(out.items()))


class VehicleEstimator:
    """Bank + FDI + active selection + records for one vehicle (see the module docstring)."""

    def __init__(
        self,
        sysid: int,
        config: EstimatorConfig,
        input_counters: Callable[[], Mapping[str, int]] | None = None,
        rates_fn: Callable[[float], dict[str, float]] | None = None,
    ) -> None:
        """``input_counters``: what the vehicle's input (ingest) counted, reported beside
        the estimator's own :attr:`counters` in health records; ``rates_fn``: its input
        rates at a vehicle time."""
        self.sysid = sysid
        self.cfg = config
        #: what the estimator counted (its own; the input's are reported by the input)
        self.counters: collections.Counter[str] = collections.Counter()
        self.input_counters = input_counters
        self.rates_fn = rates_fn
        self.faults: list[FaultEvent] = []
        self.switches: list[SwitchEvent] = []
        self._seq: collections.Counter[str] = collections.Counter()
        self._seed: EstimatorSeed | None = None
        #: vehicle s between a seed's state and the sample it was applied at (None: none)
        self.seed_age_s: float | None = None
        #: "continued", or why the seed was not used ("too old"), once it was considered
        self.seed_outcome: str | None = None
        self._restart()

    # ------------------------------------------------------------------ state
    def _restart(self) -> None:
        cfg = self.cfg
        self.bank = ObserverBank(cfg.gamma, cfg.e_form, cfg.g_mps2)
        self.fdi = FaultDetector(cfg.fdi)
        self.despike = Despiker()
        self._c_int: list[float] = [0.0, 0.0, 0.0]
        self._ints_handover: Integrals | None = None
        self._ref_handover: Reference | None = None
        self._aiding: dict[str, tuple[bool | None, bool | None]] = {}
        self._n_accel_changes = 0
        self._n_meas = 0
        self._bias_ref: Reference | None = None
        self._bias_obs: Vec3 = (0.0, 0.0, 0.0)
        self._gamma_saved: float | None = None
        self._t_gamma_restore_s = math.inf
        self.t_bank_s: float | None = None
        self.t_first_s: float | None = None
        self._euler: Vec3 | None = None
        self._omega_att: Vec3 = (0.0, 0.0, 0.0)
        self._omega_imu: Vec3 | None = None
        self._f: Vec3 | None = None
        self._E: list[float] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        self._y: list[float] = [math.nan] * 3
        self.streams = StreamTiming(cfg.max_gap_s, cfg.fdi.missing_timeout_s)
        self._a_int: list[float] = [0.0, 0.0, 0.0]
        #: (t, A n, A e, A d) of the last ~2 LAG_WINDOW_S: the lag regressor L (fdi)
        self._a_hist: collections.deque[tuple[float, float, float, float]] = collections.deque()
        self._a_int_at_y: list[float] = [0.0, 0.0, 0.0]
        self._b_int: list[float] = [0.0] * 9
        self._b_int_at_y: list[float] = [0.0] * 9
        self._use: list[bool] = [False, False, False]
        self._active = "full"
        self._lost_axis_idx: int | None = None
        self._t_handover_s = 0.0
        self._t_seed_s = [0.0] * 4
        self._pending_switch: SwitchEvent | None = None
        self._next_health_s: float | None = None
        self._last_residual: list[float] = [math.nan] * 3
        self._last_ratio: list[float] = [0.0, 0.0, 0.0]

    def restart(self, reason: str) -> None:
        """Start the bank afresh (clock reset, long gap); metrics and events are kept."""
        self.counters[f"estimator_restart_{reason}"] += 1
        self._restart()

    def seed(self, state: EstimatorSeed) -> None:
        """Continue from another service's last published state (a ``serve --claim``
        takeover): samples older than the state wait (the new owner may read its link
        later than the old owner published); at the first sample with attitude and IMU
        known, if the state is at most ``SEED_MAX_AGE_S`` older (vehicle time), every
        configuration starts from its last estimate instead of the measurement, isolated
        axes stay isolated (the hand-over configuration goes on dead-reckoning from the
        active estimate, its σ growing from where it was), and the reference fit starts
        from b̂, δψ̂, d̂ and their σ (as the fit's priors). Otherwise a cold start, with
        ``seed_outcome`` saying why."""
        if self.t_bank_s is not None:
            self.restart("seeded")
        self._seed = state
        self.seed_age_s = None
        self.seed_outcome = None

    def _seed_ahead(self, t: float) -> bool:
        """A sample at ``t`` before the seed's state: wait for the stream to reach it (the
        new owner may read its link later than the old one published) unless it is more
        than ``SEED_MAX_AGE_S`` ahead (the vehicle's clock was reset): then start cold.
        True if the seed was dropped."""
        assert self._seed is not None
        ahead = self._seed.t_boot_s - t
        if ahead <= SEED_MAX_AGE_S:
            self.counters["estimator_seed_wait_samples"] += 1
            return False
        self._seed = None
        self.seed_age_s = -ahead
        self.seed_outcome = f"{ahead:.3f} s ahead of the stream (the vehicle's clock was reset?)"
        self.counters["estimator_seed_rejected"] += 1
        return True

    def _start_from_seed(self, t: float) -> None:
        seed = self._seed
        if seed is None or self._euler is None or self._f is None:
            return
        self._seed = None
        age = t - seed.t_boot_s
        self.seed_age_s = age
        if age > SEED_MAX_AGE_S:  # (a sample before the state's time waits: on_sample)
            self.seed_outcome = f"too old ({age:.3f} s > {SEED_MAX_AGE_S:g} s)"
            self.counters["estimator_seed_rejected"] += 1
            return
        active_v = seed.v_ned_mps.get("active")
        if active_v is None or not all(math.isfinite(x) for x in active_v):
            self.seed_outcome = "without an active estimate"
            self.counters["estimator_seed_rejected"] += 1
            return
        euler = self._euler
        cfg = self.cfg
        isolated = sorted(seed.isolated, key=lambda f: f.t_detect_s)
        faulty = [NED_AXES.index(f.axis) for f in isolated]
        active = CONFIG_WITHOUT_AXIS[faulty[0]] if faulty else "full"
        for c in CONFIGS:
            v = active_v if c == active else seed.v_ned_mps.get(c, active_v)
            ok = all(math.isfinite(x) for x in v)
            self.bank.set_state_ned(c, v if ok else active_v, euler)
        self.bank.step(0.0, euler, self._omega(), self._f, [math.nan] * 3, None)
        self._E = self.bank.e_last.ravel().tolist()
        self.t_bank_s = self.t_first_s = self._next_health_s = t

        def t0_of(sigma: float | None, t_default: float) -> float:
            """The start of a dead reckoning whose σ was ``sigma`` at the seed's time."""
            if sigma is None or not math.isfinite(sigma):
                return t_default
            return seed.t_boot_s - dead_reckoning_age_s(cfg.fdi, sigma)

        self._t_seed_s = [t0_of(seed.sigma_lost_mps.get(c), t) for c in CONFIGS]
        fit = seed.reference_fit
        ref: Reference | None = None
        if fit is not None:
            theta = (
                *active_v,
                *fit.accel_bias_body_mps2,
                fit.heading_error_rad,
                fit.measurement_lag_s,
            )
            sig_v = cfg.fdi.sigma_handover_mps
            sig = (
                sig_v, sig_v, sig_v, *fit.accel_bias_sigma_mps2,
                fit.heading_error_sigma_rad, fit.measurement_lag_sigma_s,
            )  # fmt: skip
            b_int, c_int, _ = self._ints()
            cov = np.diag(np.square(np.maximum(np.asarray(sig, dtype=np.float64), 1e-6)))
            ref = Reference(
                tuple(float(x) for x in theta), cov, b_int, (c_int[0], c_int[1], c_int[2])
            )
            self.fdi.fit.ref = ref
            until = t + cfg.fdi.bias_window_s + cfg.fdi.vet_delay_s
            self.fdi.fit.carry_over(theta[3:], sig[3:], t, until)
        for f_ev, j in zip(isolated, faulty, strict=True):
            level = seed.residual_ned_mps[j]
            self.fdi.axes[j].continue_isolation(
                f_ev, None if ref is None else ref.held(), level if math.isfinite(level) else 0.0
            )
        if faulty:
            self._active = active
            self._lost_axis_idx = faulty[0]
            self._t_handover_s = t0_of(seed.sigma_lost_mps.get("active"), isolated[0].t_detect_s)
            self._ints_handover = self._ints()
            self._ref_handover = None if ref is None else ref.held()
        self.counters["estimator_seeded"] += 1
        self.seed_outcome = "continued"

    @property
    def active_config(self) -> str:
        return self._active

    def _seqn(self, key: str) -> int:
        self._seq[key] += 1
        return self._seq[key]

    # ------------------------------------------------------------------ samples
    def on_sample(self, s: Sample) -> list[Record]:
        """Consume one sample of this vehicle; return the records it produces."""
        out: list[Record] = []
        if isinstance(s, TruthSample):
            self._truth(s, out)
            return out
        if isinstance(s, AidingSample):
            self._aiding_sample(s)
            return out
        t = s.t_boot_s
        if self._seed is not None and t < self._seed.t_boot_s and not self._seed_ahead(t):
            return out  # older than the state it continues from: covered by that state
        if self.t_bank_s is not None and t > self.t_bank_s:
            if t - self.t_bank_s > self.cfg.max_gap_s:
                self.restart("gap")
            else:
                self._step_to(t)
        if t >= self._t_gamma_restore_s and self._gamma_saved is not None:
            self.bank.set_gamma("full", self._gamma_saved)
            self._gamma_saved = None
            self._t_gamma_restore_s = math.inf
        if isinstance(s, AttitudeSample):
            self._euler = s.euler_rad
            self._omega_att = s.omega_body_radps
            if self._seed is not None and self.t_bank_s is None:
                self._start_from_seed(t)
        elif isinstance(s, ImuSample):
            self.streams.imu(t)
            f_used = self.despike.filter(s.f_body_mps2)
            if f_used is None:
                self.counters["imu_spike_held"] += 1
                if self._f is None:
                    return out
                f_used = self._f
            self._f = f_used
            self._omega_imu = s.omega_body_radps
            if self._seed is not None and self.t_bank_s is None:
                self._start_from_seed(t)
            if self.t_bank_s is not None:
                self._check_missing(t)
                self._velocity_records(out)
                self._health(t, out)
        elif isinstance(s, VelocitySample):
            self._measurement(s, out)
        return out

    def _omega(self) -> Vec3:
        return self._omega_imu if self._omega_imu is not None else self._omega_att

    def _step_to(self, t: float) -> None:
        """Advance the bank and the IMU integral A from t_bank to t, inputs held (ZOH)."""
        assert self.t_bank_s is not None and self._euler is not None and self._f is not None
        dt = t - self.t_bank_s
        cfg = self.cfg
        b = self.fdi.fit.bias_body_mps2
        y = self._y
        if cfg.propagate_held_measurement:
            # y(t) ≈ y(t_y) + ∫ E (f − b̂) + g e_d  (V̇ = E Γ)
            dB = [self._b_int[k] - self._b_int_at_y[k] for k in range(9)]
            y = [
                y[i]
                + (self._a_int[i] - self._a_int_at_y[i])
                - (dB[3 * i] * b[0] + dB[3 * i + 1] * b[1] + dB[3 * i + 2] * b[2])
                for i in range(3)
            ]
        f = self._f
        mask = self._mask()
        b_obs = self._bank_bias()
        f_bank = f if b_obs is None else (f[0] - b_obs[0], f[1] - b_obs[1], f[2] - b_obs[2])
        self.bank.step(dt, self._euler, self._omega(), f_bank, y, mask)
        E = self.bank.e_last.ravel().tolist()
        self._E = E
        a = rotate_flat(E, f)  # earth-frame acceleration E Γ = E f + g e_d (V̇ = E Γ)
        a[2] += cfg.g_mps2
        ai = self._a_int
        for i in range(3):
            ai[i] += a[i] * dt
        hist = self._a_hist
        hist.append((t, ai[0], ai[1], ai[2]))
        while len(hist) > 2 and hist[1][0] <= t - LAG_WINDOW_S:
            hist.popleft()
        # C = ∫ (−a_e, a_n, 0) dt: the heading-error regressor (fdi module docstring)
        self._c_int[0] -= a[1] * dt
        self._c_int[1] += a[0] * dt
        bi = self._b_int
        for k in range(9):
            bi[k] += E[k] * dt  # B = ∫ E dt (fdi.BiasFit)
        self.t_bank_s = t

    def _mask(self) -> list[bool] | None:
        if all(self._use):
            return None
        return self._use

    def _init_from(self, s: VelocitySample) -> bool:
        """The first full velocity measurement with attitude and IMU known starts the bank."""
        if self._euler is None or self._f is None:
            self.counters["warmup_samples"] += 1
            return False
        y = s.v_ned_mps
        if not all(math.isfinite(c) for c in y):
            self.counters["warmup_samples"] += 1
            return False
        for c in CONFIGS:
            self.bank.set_state_ned(c, y, self._euler)
        self.bank.step(0.0, self._euler, self._omega(), self._f, y, None)
        self._E = self.bank.e_last.ravel().tolist()
        self.t_bank_s = s.t_boot_s
        self.t_first_s = s.t_boot_s
        self._t_seed_s = [s.t_boot_s] * 4
        self._next_health_s = s.t_boot_s
        return True

    # ------------------------------------------------------------------ measurement + FDI
    def _measurement(self, s: VelocitySample, out: list[Record]) -> None:
        t = s.t_boot_s
        out.append(
            MeasurementRecord(
                self.sysid,
                t,
                s.v_ned_mps,
                s.position_ned_m,
                self._seqn("measurement"),
                self._euler,
            )
        )
        if self.t_bank_s is None and (self._seed is not None or not self._init_from(s)):
            return  # (a seed starts the bank at the next attitude or IMU sample)
        faulty_before = set(self.fdi.faulty_axes())
        imu_hz = self.streams.imu_hz
        if 0.0 < imu_hz < self.cfg.fdi.min_imu_rate_hz:
            # the residual tests cannot arm: said in health (counter, axis_state "warmup")
            # and in the replay/serve summary
            self.counters["fdi_off_imu_too_slow"] += 1
        ints = self._ints()
        verdicts = self.fdi.update(t, s.v_ned_mps, self._a_int, ints, imu_hz)
        self.streams.measurement(t)
        self._y = self._lag_compensated(s.v_ned_mps, ints[2])
        self._a_int_at_y = list(self._a_int)
        self._b_int_at_y = list(self._b_int)
        self._use = [v.use for v in verdicts]
        self._last_residual = [v.residual_mps for v in verdicts]
        self._last_ratio = [v.test_ratio for v in verdicts]
        self._after_fdi(t, faulty_before)
        self._n_meas += 1
        if self.cfg.adapt_gamma_full and self._n_meas % GAMMA_UPDATE_SAMPLES == 0:
            self._adapt_gamma_full(imu_hz)

    def _lag_compensated(self, y_ned_mps: Vec3, l_now: tuple[float, float, float]) -> list[float]:
        """The measurement moved to the present by the fit's *observed* lag d̂ (|d̂| > 2σ,
        bounded to [0, max_lag_s]): v(t) ≈ y(t) + d̂ L(t) (fdi module docstring), with
        ``compensate_lag``; else y itself."""
        y = list(y_ned_mps)
        if not self.cfg.compensate_lag:
            return y
        ref = self._ref_handover if self.fdi.faulty_axes() else self.fdi.fit.ref
        if ref is None:
            return y
        lag_s = ref.observed(LAG)
        if lag_s <= 0.0:
            return y
        return [y[i] + lag_s * l_now[i] for i in range(3)]

    def _adapt_gamma_full(self, imu_hz: float) -> None:
        """γ of ``full`` from the noise this vehicle sends (observer.gamma_full_optimal):
        the measurement's white noise from successive residual differences, the IMU's
        from the despiker, the bias from the fit (at least 0.05 m/s²). Only while every
        axis is healthy and armed; a change is limited to ×/÷ 1.5 per update."""
        axes = self.fdi.axes
        if (
            self.fdi.faulty_axes()
            or not self.fdi.armed()
            or self.streams.y_interval_s <= 0.0
            or self._gamma_saved is not None
        ):
            return
        if imu_hz <= 0.0 or any(a.var_diff_mps2 <= 0.0 for a in axes):
            return
        q = self.despike.noise_var_mps2() / imu_hz
        # E[Δr²] = 2 σ_y² + q Δt_y (the IMU's white noise over one interval)
        y_interval_s = self.streams.y_interval_s
        var_y = max(min(a.var_diff_mps2 for a in axes) / 2.0 - q * y_interval_s / 2.0, 1e-8)
        b = max(math.sqrt(sum(x * x for x in self.fdi.fit.bias_body_mps2)), 0.05)
        cfg = self.cfg
        target = gamma_full_optimal(
            math.sqrt(var_y), 1.0 / y_interval_s, q, b, cfg.gamma_full_min, cfg.gamma_full_max
        )
        now = self.bank.gamma_gain[0]
        new = min(max(target, now / 1.5), now * 1.5)
        if abs(new - now) > 0.02 * now:
            self.bank.set_gamma("full", new)
            self.counters["gamma_full_updates"] += 1

    @property
    def gamma_full(self) -> float:
        return self.bank.gamma_gain[0]

    def _ints(self) -> Integrals:
        """(B, C, L): the integrals the FDI's regressors are built from; L the mean
        earth-frame acceleration over the last LAG_WINDOW_S (A's difference)."""
        c = self._c_int
        hist = self._a_hist
        ai = self._a_int
        l_now = (0.0, 0.0, 0.0)
        if len(hist) >= 2:
            t0, *a0 = hist[0]
            span = hist[-1][0] - t0
            if span > 0.0:
                l_now = ((ai[0] - a0[0]) / span, (ai[1] - a0[1]) / span, (ai[2] - a0[2]) / span)
        return tuple(self._b_int), (c[0], c[1], c[2]), l_now

    def _aiding_sample(self, s: AidingSample) -> None:
        """The autopilot's word on what its velocity rests on. Its estimator's own report
        (EKF_STATUS_REPORT) is the authority when it sends one: it knows what it fuses. An
        ArduSub ROV loses its GPS fix at every dive while its velocity stays aided by
        other sensors; ArduPilot's flags drop horizontal aiding ~7 s after a GPS loss,
        while the EKF still dead-reckons well. Without that report, GPS_RAW_INT's fix type
        decides the horizontal axes."""
        self._aiding[s.source] = (s.horizontal_aided, s.vertical_aided)
        if self.t_bank_s is None:
            return
        src = "EKF_STATUS_REPORT" if "EKF_STATUS_REPORT" in self._aiding else s.source
        if s.source != src:
            return
        horiz, vert = self._aiding[src]
        faulty_before = set(self.fdi.faulty_axes())
        self.fdi.set_unaided(s.t_boot_s, horiz, vert)
        if set(self.fdi.faulty_axes()) != faulty_before:
            self.counters[f"aiding_{s.reason or 'restored'}"] += 1
            self._after_fdi(s.t_boot_s, faulty_before)

    def _check_missing(self, t: float) -> None:
        """No velocity measurement for its timeout (streams.StreamTiming): every
        configuration dead-reckons until samples come back; no switch."""
        if not self.streams.check_missing(t):
            return
        self.counters["measurement_missing"] += 1
        self._use = [False, False, False]

    def _after_fdi(self, t: float, faulty_before: set[int]) -> None:
        if self.fdi.reference_drifts:  # re-anchorings on a reference offset (no event)
            self.counters["fdi_reference_offsets"] = self.fdi.reference_drifts
        if self.fdi.ramp_withdrawals:  # residual isolations withdrawn on a ramp (no event)
            self.counters["fdi_ramp_withdrawals"] = self.fdi.ramp_withdrawals
        changes = self.fdi.accel_changes
        while self._n_accel_changes < len(changes):
            ch = changes[self._n_accel_changes]
            self._n_accel_changes += 1
            self.faults.append(
                FaultEvent(
                    "body", "accel_bias", ch.t_detect_s, ch.t_change_s, ch.delta_bias_body_mps2
                )
            )
            self.counters["fault_accel_bias"] += 1
        faulty = self.fdi.faulty_axes()
        for j in faulty:
            if j not in faulty_before:
                ev = self.fdi.axes[j].fault
                assert ev is not None
                self.faults.append(ev)
                self.counters[f"fault_{ev.kind}_{ev.axis}"] += 1
        wanted = CONFIG_WITHOUT_AXIS[faulty[0]] if faulty else "full"
        if wanted != self._active:
            self._switch(t, wanted, faulty[0] if faulty else None)

    def _switch(self, t: float, to: str, lost_idx: int | None) -> None:
        before = self._active_ned(self.bank.x_hat_ned_mps().tolist())
        v0 = list(before)
        reason = "recovered"
        if lost_idx is not None:
            ax = self.fdi.axes[lost_idx]
            reason = f"{ax.fault.kind if ax.fault else 'fault'}_{NED_AXES[lost_idx]}"
            if self._active == "full":
                pred = ax.predict_mps(self._a_int[lost_idx], self._ints(), lagged=False)
                if (
                    math.isfinite(pred)
                    and abs(pred - v0[lost_idx]) > self.cfg.handover_contamination_mps
                ):
                    self.counters["handover_from_dead_reckoning"] += 1
                    v0[lost_idx] = pred
            self._t_handover_s = t
            self._ints_handover = self._ints()
            self._ref_handover = ax.reference()
        assert self._euler is not None
        self.bank.set_state_ned(to, v0, self._euler)
        if to == "full" and lost_idx is None:
            # back from a hand-over: `full` starts from the dead-reckoned estimate and
            # converges to the re-admitted measurement at the low gain for a while, so that
            # the dead reckoning's drift is corrected smoothly, not in one step
            if self._gamma_saved is None:
                self._gamma_saved = self.bank.gamma_gain[0]
            self.bank.set_gamma("full", min(self._gamma_saved, self.cfg.gamma_full_min))
            self._t_gamma_restore_s = t + RECOVERY_BLEND_S
        self._t_seed_s[config_index(to)] = t
        self.switches.append(
            SwitchEvent(t, self._active, to, reason, (before[0], before[1], before[2]))
        )
        self._pending_switch = self.switches[-1]
        self._active = to
        self._lost_axis_idx = lost_idx

    # ------------------------------------------------------------------ records
    def _velocity_records(self, out: list[Record]) -> None:
        t = self.t_bank_s
        assert t is not None
        body = self.bank.x_hat_body_mps.tolist()
        ned = self.bank.x_hat_ned_mps()
        ned_l = ned.tolist()
        n_faulty = len(self.fdi.faulty_axes())
        for i, c in enumerate(CONFIGS):
            lost = LOST_AXIS_OF_CONFIG[c]
            health = "ok" if c == "full" and n_faulty == 0 else "degraded"
            if lost is not None:
                health = "dead_reckoning"
            out.append(
                VelocityRecord(
                    self.sysid,
                    c,
                    t,
                    (body[i][0], body[i][1], body[i][2]),
                    (ned_l[i][0], ned_l[i][1], ned_l[i][2]),
                    lost,
                    health,
                    self._seqn(c),
                    None,
                    None
                    if lost is None
                    else sigma_dead_reckoning_mps(self.cfg.fdi, t - self._t_seed_s[i]),
                )
            )
        a = config_index(self._active)
        a_ned = self._active_ned(ned_l)
        lost_a = LOST_AXIS_OF_CONFIG[self._active]
        if n_faulty == 0:
            health_a = "ok"
        elif n_faulty == 1:
            health_a = "dead_reckoning"
        else:
            health_a = "degraded"
        out.append(
            VelocityRecord(
                self.sysid,
                "active",
                t,
                (body[a][0], body[a][1], body[a][2]),
                a_ned,
                lost_a,
                health_a,
                self._seqn("active"),
                self._active,
                None
                if lost_a is None
                else sigma_dead_reckoning_mps(self.cfg.fdi, t - self._t_handover_s),
            )
        )
        if self._pending_switch is not None:
            sw = self._pending_switch
            # the discontinuity: the new active against what the old one says at this same
            # time (not against its value at the switch: the vehicle moved meanwhile)
            jump = math.dist(self._active_ned(ned_l, sw.from_config), a_ned)
            self.switches[self.switches.index(sw)] = SwitchEvent(
                sw.t_boot_s, sw.from_config, sw.to_config, sw.reason, sw.v_before_ned_mps, jump
            )
            self._pending_switch = None

    def _active_ned(self, ned_l: list[list[float]], config: str | None = None) -> Vec3:
        """The active estimate if ``config`` (default: the active one) were active: its NED
        velocity, its dead-reckoned axis corrected by the fit (``compensate_accel_bias``)."""
        config = self._active if config is None else config
        v = ned_l[config_index(config)]
        j = LOST_INDEX_OF_CONFIG[config]
        if j is None or not self.cfg.compensate_accel_bias:
            return (v[0], v[1], v[2])
        out = [v[0], v[1], v[2]]
        out[j] += self._lost_axis_correction(j)
        return (out[0], out[1], out[2])

    def _bank_bias(self) -> Vec3 | None:
        """The accelerometer bias fed to the bank: the fit's *observed* components
        (|θ̂_k| > 2σ_k; the fit bounds ‖b̂‖), from the reference frozen at the hand-over while
        an axis is isolated; None without a fit or with ``compensate_accel_bias`` off."""
        if not self.cfg.compensate_accel_bias:
            return None
        ref = self._ref_handover if self.fdi.faulty_axes() else self.fdi.fit.ref
        if ref is None:
            return None
        if ref is not self._bias_ref:
            self._bias_ref = ref
            self._bias_obs = (ref.observed(3), ref.observed(4), ref.observed(5))
        return self._bias_obs

    def _lost_axis_correction(self, j: int) -> float:
        """The fit's heading correction of the dead-reckoned axis j since the hand-over
        (module docstring); only an observed heading error (|δψ̂| > 2σ) counts. (The bias
        is in the bank already: :meth:`_bank_bias`.)"""
        ref = self._ref_handover
        h = self._ints_handover
        if ref is None or h is None:
            return 0.0
        dpsi = ref.observed(6)
        if dpsi == 0.0:
            return 0.0
        return (self._c_int[j] - h[1][j]) * dpsi

    def _health(self, t: float, out: list[Record]) -> None:
        if self._next_health_s is None or t < self._next_health_s:
            return
        period = 1.0 / self.cfg.health_rate_hz
        while self._next_health_s <= t:
            self._next_health_s += period
        res = self._last_residual
        rat = self._last_ratio
        out.append(
            HealthRecord(
                self.sysid,
                t,
                self._seqn("health"),
                self._active,
                (res[0], res[1], res[2]),
                (rat[0], rat[1], rat[2]),
                self.fdi.states(),
                (
                    *(a.fault for a in self.fdi.axes if a.fault is not None),
                    *(
                        f
                        for f in self.faults
                        if f.kind == "accel_bias" and t - f.t_detect_s <= ACCEL_EVENT_HOLD_S
                    ),
                ),
                self.rates_fn(t) if self.rates_fn is not None else {},
                self.all_counters(),
                self.reference_fit_summary(),
            )
        )

    def all_counters(self) -> dict[str, int]:
        """The input's counters and the estimator's, summed by name, sorted."""
        return merge_counters(
            self.input_counters() if self.input_counters is not None else {}, self.counters
        )

    def reference_fit_summary(self) -> ReferenceFitSummary | None:
        ref = self.fdi.fit.ref
        if ref is None:
            return None
        th = ref.theta
        sd = [math.sqrt(max(float(ref.cov[k, k]), 0.0)) for k in range(len(th))]
        return ReferenceFitSummary(
            (th[3], th[4], th[5]), (sd[3], sd[4], sd[5]), th[6], sd[6], th[LAG], sd[LAG]
        )

    def _truth(self, s: TruthSample, out: list[Record]) -> None:
        # the numpy E, as the truth records have always used (frames.e_flat differs by an
        # ulp in 7 % of entries: the records would change in their last digit)
        E = e_exact(np.asarray(s.euler_rad)).ravel().tolist()
        v_body = rotate_t_flat(E, s.v_ned_mps)
        out.append(
            TruthRecord(
                self.sysid,
                s.t_boot_s,
                (v_body[0], v_body[1], v_body[2]),
                s.v_ned_mps,
                s.euler_rad,
                None,
                self._seqn("truth"),
            )
        )
        # scored against the estimates by the service (evaluation.TruthScorer), not here
