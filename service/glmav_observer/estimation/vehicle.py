"""One vehicle's estimator: the pipeline from a sample to the records it produces.

(Over 500 lines for one reason: besides the pipeline it applies a takeover's seed, which
sets every part at once; the seed's pure parts are in :mod:`.seed`.)

Pure (no I/O, no clock but the vehicle's): :meth:`VehicleEstimator.on_sample` takes the
typed samples of one vehicle in vehicle-time order and returns the records to publish.
Each part has one job, in its own module:

==================  ===================================================================
``inputs``          the held inputs (zero-order hold) and the IMU integrals A, B, C
``streams``         the measured input intervals; a missing measurement stream
``despike``         a lone IMU shock held out for one sample
``bank``            the observer of every configuration, stepped exactly over each interval
``fdi``             fault detection and isolation per axis; the reference fit (b̂, δψ̂, d̂)
``selection``       the active configuration, the hand-over, the reference in force
``gain``            γ of ``full``: adapted to the noise, lowered after a recovery
``outputs``         the records, their sequence numbers and the health pacing
``seed``            the state a taken-over vehicle continues from
``aiding``          the lost axis aided by the learnt drag model (the ``aided`` estimate)
``gps_bridge``      after a GPS loss, the GPS's own velocity while the autopilot's is off
==================  ===================================================================

The step from a sample (:meth:`VehicleEstimator.on_sample`):

1. a sample later than the bank's time first advances the bank to it with the inputs
   held since the previous samples (:meth:`ObserverBank.step` solves (16) exactly over
   the interval, fed f − b̂_obs and the held or IMU-propagated measurement) and the IMU
   integrals with it;
2. the sample updates what it carries: attitude (ATTITUDE); specific force and gyro
   rates (IMU, despiked), after which the velocity records and, when due, a health
   record are produced; the velocity measurement (LOCAL_POSITION_NED), which the FDI
   tests per axis before the bank is corrected with it (lag-compensated, at its own
   time stamp) and which may change the active configuration.

Missing stream. No velocity measurement for the timeout is not a fault of an axis: every
configuration dead-reckons (all axes unmeasured) until samples come back; no switch.

The autopilot's word. ``LOCAL_POSITION_NED`` from ArduPilot or PX4 is the autopilot's own
estimate; while ``EKF_STATUS_REPORT`` (or, from an autopilot without it, ``GPS_RAW_INT``)
says it is not aided (GPS lost), the axes concerned are isolated as ``unaided`` and
re-admitted when it is aided again.
"""

from __future__ import annotations

import collections
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from glmav_observer.configurations import (
    CONFIG_WITHOUT_AXIS,
    CONFIGS,
    LOST_AXIS_OF_CONFIG,
    config_index,
)
from glmav_observer.estimation.aero import DragModelConfig
from glmav_observer.estimation.aero.control import ControlMapping
from glmav_observer.estimation.aiding import LostAxisAiding
from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.despike import Despiker
from glmav_observer.estimation.drift import DriftAxes, drift_sigma_ned_mps
from glmav_observer.estimation.fdi import FaultDetector
from glmav_observer.estimation.fdi_reference import LAG, sigma_dead_reckoning_mps
from glmav_observer.estimation.fdi_types import FdiConfig
from glmav_observer.estimation.gain import FullGain
from glmav_observer.estimation.gps_bridge import GpsBridge, GpsBridgeConfig
from glmav_observer.estimation.imu_filter import accel_filter_delay_s
from glmav_observer.estimation.imu_monitor import ImuConsistency, ImuEvent
from glmav_observer.estimation.inputs import HeldInputs
from glmav_observer.estimation.observer import G_MPS2, EForm
from glmav_observer.estimation.outputs import RecordBuilder, merge_counters
from glmav_observer.estimation.seed import (
    SEED_CHECK_S,
    SEED_GATE_SIGMA,
    SEED_MAX_AGE_S,
    EstimatorSeed,
    seed_disagreement,
    seed_reference,
)
from glmav_observer.estimation.selection import ActiveSelection, SwitchEvent
from glmav_observer.estimation.streams import StreamTiming
from glmav_observer.evaluation import TruthScorer
from glmav_observer.frames import rotate_flat
from glmav_observer.ingest.samples import (
    AidingSample,
    AttitudeSample,
    ControlSample,
    ImuSample,
    Sample,
    SecondaryImuSample,
    TruthSample,
    VelocitySample,
)
from glmav_observer.reads import READS_ALL, Reads
from glmav_observer.records import NED_AXES, FaultEvent, Record, ReferenceFitSummary

logger = logging.getLogger(__name__)

#: GPS velocities this far apart (vehicle s) tell which of two disagreeing IMUs is wrong:
#: 0.3 m/s² of bias moves the dead reckoning 0.3 m/s in 1 s, several σ of a GPS's
#: velocity (0.05-0.1 m/s) and of its lag's effect (0.1-0.2 s at ≤ 1 m/s² of change)
RESOLVE_S = 1.0
#: An ``accel_bias`` event stays in the health record's faults this long (vehicle s):
#: it isolates nothing, but subscribers and the Rerun view must see it.
ACCEL_EVENT_HOLD_S = 5.0

Vec3 = tuple[float, float, float]
_NONE3: list[float | None] = [None, None, None]
#: What the scorer scores at each step, in the order :meth:`_velocity_records` hands it.
_SCORED: tuple[str, ...] = (*CONFIGS, "active")
#: Per configuration (CONFIGS order): whether it has a lost (dead-reckoned) axis.
_HAS_LOST_AXIS: tuple[bool, ...] = tuple(LOST_AXIS_OF_CONFIG[c] is not None for c in CONFIGS)


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
    #: integrate the IMU with the trapezoid at its samples' own times (BankCore.centre_imu)
    #: instead of holding each sample until the next (Δt/2 of lag)
    trapezoid_imu: bool = True
    #: compare `full`'s measurement in the frame of the bank's step, which turns with the
    #: body from the held E (observer.frame_ramp_mps2)
    rotate_measurement: bool = True
    #: take the autopilot's accelerometer low-pass delay out of the IMU (:mod:`.imu_filter`)
    compensate_imu_filter: bool = True
    #: that low-pass's cutoff (Hz), e.g. ArduPilot's INS_ACCEL_FILTER; 0: the firmware's
    #: default, named by the vehicle's HEARTBEAT (ArduPilot 20 Hz, Rover 10; others none)
    imu_filter_hz: float = 0.0
    max_gap_s: float = 1.0
    #: while the autopilot says an axis is unaided (GPS lost), ``active`` follows its
    #: velocity there (``VehicleEstimator._follow_unaided``); False: filtered as usual
    follow_unaided: bool = True
    #: ... and for this long after it is aided again, s: its estimator snaps back to its
    #: sensor then (ArduPilot resets its velocity to the returned GPS's: 0.37 m/s in one
    #: sample on b_quad_gps_off), a step ``full``'s filter would smear over 1/γ (25-250
    #: ms); 1 s = 4/γ at the lowest γ (``gamma_full_min``), when any step present as the
    #: flags clear has decayed to 2 % in ``full`` too
    readmit_follow_s: float = 1.0
    handover_contamination_mps: float = 1.0
    metrics_skip_s: float = 3.0
    adapt_gamma_full: bool = True
    gamma_full_min: float = 4.0
    gamma_full_max: float = 40.0
    #: learn the drag model while healthy and publish the ``aided`` estimate of a lost axis
    aero_aiding: bool = True
    #: while the aiding runs, the ``active`` estimate's lost axis is the ``aided`` one
    #: (issue 13; its rules keep it from being worse than dead reckoning on the corpus:
    #: docs/design/observer-notes.md); False: ``active`` dead-reckons the lost axis, ``aided`` beside it
    aero_active: bool = True
    #: SERVO_OUTPUT_RAW's channel map for the cyclic regressors of the drag model
    #: (``[estimation.aero_control]``; None: SERVO_OUTPUT_RAW is ignored)
    aero_control: ControlMapping | None = None
    #: an informed prior on the drag model's linear drag k, 1/s (``DragModelConfig.prior_k``,
    #: from the vehicle file: 0.437 for glmav-sitl's default vehicle), and its σ; 0: off
    aero_prior_k_per_s: float = 0.0
    aero_prior_k_sigma_per_s: float = 0.03
    #: the vehicle's drag is the same along body x and y (a quad, hexa or octa):
    #: ``DragModelConfig.symmetric_xy``, a body row whose speed barely varied borrows the
    #: other row's k and q
    aero_symmetric_xy: bool = False
    #: no pseudo-measurement while a body row's learnt k is clearly negative
    #: (``DragModelConfig.refuse_negative_k``: the drag law does not hold there). A heli
    #: flown without the cyclic regressors may turn it off: its rotor's flapping under
    #: velocity control reads as a negative k on y while the x row still aids
    aero_refuse_negative_k: bool = True
    #: after a GPS loss, the GPS's own velocity while the autopilot's re-converges
    #: (:mod:`.gps_bridge`)
    gps_bridge: GpsBridgeConfig = field(default_factory=GpsBridgeConfig)
    fdi: FdiConfig = field(default_factory=FdiConfig)


def _drag_model_config(config: EstimatorConfig) -> DragModelConfig:
    """The drag model's settings from ``[estimation]`` (the rest at their defaults)."""
    prior_k = (
        (config.aero_prior_k_per_s, config.aero_prior_k_sigma_per_s)
        if config.aero_prior_k_per_s > 0.0
        else None
    )
    return DragModelConfig(
        prior_k=prior_k,
        symmetric_xy=config.aero_symmetric_xy,
        refuse_negative_k=config.aero_refuse_negative_k,
    )


class VehicleEstimator:
    """Bank + FDI + active selection + records for one vehicle (see the module docstring)."""

    def __init__(
        self,
        sysid: int,
        config: EstimatorConfig,
        input_counters: Callable[[], Mapping[str, int]] | None = None,
        rates_fn: Callable[[float], dict[str, float]] | None = None,
        reads: Reads = READS_ALL,
        *,
        score_truth: bool = False,
    ) -> None:
        """``input_counters``: what the vehicle's input (ingest) counted, reported beside
        the estimator's own :attr:`counters` in health records; ``rates_fn``: its input
        rates at a vehicle time; ``reads``: the records its outputs read (the rest is not
        built: :mod:`glmav_observer.reads`); ``score_truth``: once the vehicle sends truth
        (a simulator's SIM_STATE), every estimate is scored against it (:attr:`scorer`,
        the service's summary) without building a record for it."""
        self.sysid = sysid
        self.cfg = config
        #: what the estimator counted (its own; the input's are reported by the input)
        self.counters: collections.Counter[str] = collections.Counter()
        self.input_counters = input_counters
        self.rates_fn = rates_fn
        self.faults: list[FaultEvent] = []
        self.switches: list[SwitchEvent] = []
        self.out = RecordBuilder(sysid, config.health_rate_hz, reads)
        self.score_truth = score_truth
        #: every estimate of every configuration and ``active`` against truth, from the
        #: vehicle's first truth sample on (with ``score_truth``; a real vehicle has none)
        self.scorer: TruthScorer | None = None
        #: kept across restarts: what the vehicle's drag is does not change with a gap
        self.aiding = (
            LostAxisAiding(
                config.fdi.sigma_handover_mps,
                model_config=_drag_model_config(config),
                control=config.aero_control,
            )
            if config.aero_aiding
            else None
        )
        #: the autopilot's word on its velocity's aiding (a vehicle fact: kept across restarts)
        self.drift = DriftAxes()
        #: the vehicle's redundant IMUs compared (kept across restarts: sensor facts)
        self.imus = ImuConsistency(config.fdi.imu) if config.fdi.imu_monitor else None
        #: (t, GPS v n e, A n e) at the first GPS sample after a two-IMU fault's onset
        self._imu_anchor: tuple[float, tuple[float, float], tuple[float, float]] | None = None
        #: the GPS's velocity after a GPS loss (its lag learnt: a link fact, kept)
        self.bridge = GpsBridge(config.gps_bridge, self.counters)
        self._seed: EstimatorSeed | None = None
        #: vehicle s between a seed's state and the sample it was applied at (None: none)
        self.seed_age_s: float | None = None
        #: "continued", or why the seed was not used ("too old"), once it was considered
        self.seed_outcome: str | None = None
        #: a seed applied at this vehicle time is checked against the measurements until
        #: SEED_CHECK_S later (None: nothing to check)
        self._seed_check_t0_s: float | None = None  # (set by _restart)
        #: the accelerometer filter's delay taken out (a vehicle fact: kept across restarts;
        #: the configured cutoff's until the HEARTBEAT names the firmware: set_autopilot)
        self._imu_lead_s = self._imu_filter_delay_s(None, None)
        self._restart()
        if self._imu_lead_s > 0.0:  # configured: said from the start
            self.counters["imu_filter_delay_us"] = round(self._imu_lead_s * 1e6)

    # ------------------------------------------------------------------ state
    def _restart(self) -> None:
        """Every part afresh; the counters, events and sequence numbers are kept."""
        cfg = self.cfg
        self._seed_check_t0_s = None
        self.bank = ObserverBank(
            cfg.gamma, cfg.e_form, cfg.g_mps2, cfg.rotate_measurement, self._imu_lead_s
        )
        self.fdi = FaultDetector(cfg.fdi)
        spike = cfg.fdi.despike
        self.despike = Despiker(spike.floor_mps2, spike.k_sigma, spike.tau_samples)
        self.inputs = HeldInputs(cfg.g_mps2)
        self.streams = StreamTiming(cfg.max_gap_s, cfg.fdi.missing_timeout_s)
        self.sel = ActiveSelection(cfg.compensate_accel_bias, cfg.handover_contamination_mps)
        self.gain = FullGain(
            cfg.adapt_gamma_full, cfg.gamma_full_min, cfg.gamma_full_max,
            compensate_bias=cfg.compensate_accel_bias,
        )  # fmt: skip
        self.out.next_health_s = None
        if self.aiding is not None:
            self.aiding.restart()
        self._n_accel_changes = 0
        self.t_bank_s: float | None = None
        self.t_first_s: float | None = None
        self._t_imu_s: float | None = None  # the last IMU sample's time (trapezoid_imu)
        self._use: list[bool] = [False, False, False]
        self.bridge.restart()
        #: per NED axis, the vehicle time until which ``active`` still follows the
        #: autopilot's velocity after it was aided again (``readmit_follow_s``)
        self._follow_until_s: list[float] = [-math.inf] * 3
        self._follow_end_s = -math.inf  # the latest of them
        self._last_residual: list[float] = [math.nan] * 3
        self._last_ratio: list[float] = [0.0, 0.0, 0.0]

    def _imu_filter_delay_s(
        self, autopilot: int | None, mav_type: int | None, vehicle_hz: float | None = None
    ) -> float:
        cfg = self.cfg
        if not cfg.compensate_imu_filter:
            return 0.0
        return accel_filter_delay_s(cfg.imu_filter_hz, autopilot, mav_type, vehicle_hz)

    def set_autopilot(self, autopilot: int, mav_type: int) -> None:
        """The vehicle's HEARTBEAT named its firmware and type: take its accelerometer
        filter's delay out of the IMU from now on (:mod:`.imu_filter`)."""
        self._set_imu_lead(self._imu_filter_delay_s(autopilot, mav_type))

    def set_accel_filter_hz(self, vehicle_hz: float) -> None:
        """The vehicle's own accelerometer filter setting (a log's ``INS_ACCEL_FILTER``),
        unless ``[estimation] imu_filter_hz`` overrides it (:mod:`.imu_filter`)."""
        self._set_imu_lead(self._imu_filter_delay_s(None, None, vehicle_hz))

    def _set_imu_lead(self, lead_s: float) -> None:
        self._imu_lead_s = lead_s
        self.bank.imu_lead_s = lead_s
        self.counters["imu_filter_delay_us"] = round(lead_s * 1e6)

    def restart(self, reason: str) -> None:
        """Start the bank afresh (clock reset, long gap); metrics and events are kept."""
        self.counters[f"estimator_restart_{reason}"] += 1
        self._restart()

    @property
    def active_config(self) -> str:
        return self.sel.config

    @property
    def gamma_full(self) -> float:
        return self.bank.gamma_gain[0]

    # ------------------------------------------------------------------ samples
    def on_sample(self, s: Sample) -> list[Record]:
        """Consume one sample of this vehicle; return the records it produces."""
        out: list[Record] = []
        if isinstance(s, TruthSample):
            if self.score_truth:
                sc = self.scorer
                if sc is None:  # scored from now on: every estimate at every IMU sample
                    sc = self.scorer = TruthScorer(skip_s=self.cfg.metrics_skip_s)
                sc.add_truth(s.t_boot_s, s.v_ned_mps)
            self.out.truth(s, out)
            return out
        if isinstance(s, AidingSample):
            self._aiding_sample(s)
            return out
        if isinstance(s, SecondaryImuSample):
            if self.imus is not None:
                self.imus.secondary(s.instance, s.t_boot_s, s.f_body_mps2)
            return out
        if isinstance(s, ControlSample):
            if self.aiding is not None:
                self.aiding.hold_control(s.t_boot_s, s.servo_pwm_us)
            return out
        t = s.t_boot_s
        if self._seed is not None and t < self._seed.t_boot_s and not self._seed_ahead(t):
            return out  # older than the state it continues from: covered by that state
        if self.t_bank_s is not None and t > self.t_bank_s:
            if t - self.t_bank_s > self.cfg.max_gap_s:
                self.restart("gap")
            else:
                self._step_to(t)
        self.gain.restore_if_due(t, self.bank)
        inputs = self.inputs
        if isinstance(s, AttitudeSample):
            inputs.euler_rad = s.euler_rad
            inputs.omega_att_radps = s.omega_body_radps
            if self.t_bank_s is not None:
                # the bank stepped to t under the previous attitude: the records built
                # before its next step (an IMU sample stamped with the same time, as
                # SCALED_IMU's ms are) rotate to NED with this one, not one sample old
                self.bank.set_attitude(s.euler_rad)
            if self._seed is not None and self.t_bank_s is None:
                self._start_from_seed(t)
        elif isinstance(s, ImuSample):
            self.streams.imu(t)
            f_raw = s.f_body_mps2
            imus = self.imus
            if imus is not None and imus.instances > 1:
                corrected = imus.correction() is not None
                for ev in imus.primary(t, f_raw):
                    self._imu_event(ev)
                b1 = imus.correction()
                if b1 is not None and not corrected:
                    # the reference fit learnt part of the bias before it was told: start
                    # it again on the corrected IMU, once (not as a change at each step)
                    self.fdi.restart_reference()
                    self.counters["fdi_restart_imu_corrected"] += 1
                if b1 is not None:  # IMU 1 is the faulty one: its bias taken out
                    f_raw = (f_raw[0] - b1[0], f_raw[1] - b1[1], f_raw[2] - b1[2])
            f_used = self.despike.filter(f_raw)
            if f_used is None:
                self.counters["imu_spike_held"] += 1
                if inputs.f_body_mps2 is None:
                    return out
                f_used = inputs.f_body_mps2
            t_prev, self._t_imu_s = self._t_imu_s, t
            if self.cfg.trapezoid_imu and self.t_bank_s is not None and t_prev is not None:
                dt_imu = t - t_prev
                if dt_imu <= self.cfg.max_gap_s:
                    self.bank.centre_imu(inputs, f_used, dt_imu)
            inputs.f_body_mps2 = f_used
            inputs.omega_imu_radps = s.omega_body_radps
            if self._seed is not None and self.t_bank_s is None:
                self._start_from_seed(t)
            if self.t_bank_s is not None:
                self._check_missing(t)
                sel = self.sel
                aiding_runs = self.aiding is not None and sel.lost_idx is not None
                # the state the records' path moves at every step (a switch's jump, the
                # active estimate's aided offset), a record due or the estimates scored:
                # else nothing is built
                if (
                    self.out.velocity_due(t, aiding_runs)
                    or sel.pending is not None
                    or (aiding_runs and self.cfg.aero_active)
                    or self.scorer is not None
                ):
                    self._velocity_records(out)
                if self.out.health_due(t):
                    out.append(self._health_record(t))
        elif isinstance(s, VelocitySample):
            self._measurement(s, out)
        return out

    def _step_to(self, t: float) -> None:
        """Advance the bank and the IMU integrals from t_bank to t, inputs held (ZOH)."""
        inputs = self.inputs
        assert self.t_bank_s is not None and inputs.euler_rad is not None
        dt = t - self.t_bank_s
        bias = self.fdi.fit.bias_body_mps2
        propagate = self.cfg.propagate_held_measurement
        b_obs = self.sel.bank_bias(self.fdi)
        # the compiled per-sample step (bank and integrals in one call, f − b̂_obs formed
        # there); the numpy one where it declines (BankCore.advance)
        fallback = not self.bank.advance(t, dt, inputs, bias, propagate, b_obs, self._use)
        aiding = self.aiding is not None and self.aiding.lost_idx is not None
        if not (fallback or aiding):
            self.t_bank_s = t
            return
        f = inputs.f_body_mps2
        assert f is not None
        f_bank = f if b_obs is None else (f[0] - b_obs[0], f[1] - b_obs[1], f[2] - b_obs[2])
        if fallback:
            y = inputs.y_for_step(bias, propagate)
            mask = None if all(self._use) else self._use
            y_rate = inputs.y_rate(bias) if propagate else None  # the propagated y's ramp
            self.bank.step_floats(
                dt, inputs.euler_rad, inputs.omega_radps(), f_bank, y, mask, y_rate
            )
            inputs.integrate(t, dt, self.bank.e_last_flat())
        if aiding:
            assert self.aiding is not None
            e_flat = self.bank.e_last_flat()
            a_ned = rotate_flat(e_flat, f_bank)  # E (f − b̂_obs) + g e_d (V̇ = E Γ)
            a_ned[2] += self.cfg.g_mps2
            self.aiding.propagate(dt, a_ned)
        self.t_bank_s = t

    def _start_bank(self, t: float, y_ned_mps: Vec3 | list[float]) -> None:
        """The bank's first step (its states set) at ``t``: the clocks start."""
        inputs = self.inputs
        assert inputs.euler_rad is not None and inputs.f_body_mps2 is not None
        self.bank.step(
            0.0, inputs.euler_rad, inputs.omega_radps(), inputs.f_body_mps2, y_ned_mps, None
        )
        self.t_bank_s = self.t_first_s = self.out.next_health_s = t
        self.sel.start(t)
        self.fdi.set_unaided(self.drift.unaided())

    def _init_from(self, s: VelocitySample) -> bool:
        """The first full velocity measurement with attitude and IMU known starts the bank."""
        euler = self.inputs.euler_rad
        if euler is None or self.inputs.f_body_mps2 is None:
            self.counters["warmup_samples"] += 1
            return False
        y = s.v_ned_mps
        if not all(math.isfinite(c) for c in y):
            self.counters["warmup_samples"] += 1
            return False
        for c in CONFIGS:
            self.bank.set_state_ned(c, y, euler)
        self._start_bank(s.t_boot_s, y)
        return True

    # ------------------------------------------------------------------ seed
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

    def _reject_seed(self, why: str) -> None:
        self.seed_outcome = why
        self.counters["estimator_seed_rejected"] += 1

    def _start_from_seed(self, t: float) -> None:
        seed = self._seed
        euler = self.inputs.euler_rad
        if seed is None or not self.inputs.ready or euler is None:
            return
        self._seed = None
        age = t - seed.t_boot_s
        self.seed_age_s = age
        if age > SEED_MAX_AGE_S:  # (a sample before the state's time waits: on_sample)
            self._reject_seed(f"too old ({age:.3f} s > {SEED_MAX_AGE_S:g} s)")
            return
        active_v = seed.v_ned_mps.get("active")
        if active_v is None or not all(math.isfinite(x) for x in active_v):
            self._reject_seed("without an active estimate")
            return
        cfg = self.cfg
        isolated = sorted(seed.isolated, key=lambda f: f.t_detect_s)
        faulty = [NED_AXES.index(f.axis) for f in isolated]
        active = CONFIG_WITHOUT_AXIS[faulty[0]] if faulty else "full"
        for c in CONFIGS:
            v = active_v if c == active else seed.v_ned_mps.get(c, active_v)
            ok = all(math.isfinite(x) for x in v)
            self.bank.set_state_ned(c, v if ok else active_v, euler)
        self._start_bank(t, [math.nan] * 3)
        self.sel.t_dr_start_s = [seed.dead_reckoning_start_s(c, cfg.fdi, t) for c in CONFIGS]
        ref = None
        if seed.reference_fit is not None:
            ref, theta, sig = seed_reference(
                seed.reference_fit, active_v, self.inputs.ints(), cfg.fdi.sigma_handover_mps
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
            t_handover = seed.dead_reckoning_start_s("active", cfg.fdi, isolated[0].t_detect_s)
            self.sel.continue_handover(
                active, faulty[0], t_handover, self.inputs.ints(),
                None if ref is None else ref.held(),
            )  # fmt: skip
            if self.aiding is not None:
                self.aiding.start(t, faulty[0])
        self.counters["estimator_seeded"] += 1
        self.seed_outcome = "continued"
        self._seed_check_t0_s = t

    # ------------------------------------------------------------------ measurement + FDI
    def _check_seed(self, s: VelocitySample) -> None:
        """A measurement within SEED_CHECK_S of a seed's application: the seed is
        dropped (a cold start from this measurement, with a warning) when they disagree."""
        t0 = self._seed_check_t0_s
        assert t0 is not None
        if s.t_boot_s - t0 > SEED_CHECK_S:
            self._seed_check_t0_s = None  # the seed held for its first second
            return
        if not all(math.isfinite(c) for c in s.v_ned_mps):
            return
        _, ned_l = self.bank.estimates_lists()
        v_hat = self.sel.active_ned(ned_l, self.inputs.c_int)
        nu = (s.v_ned_mps[0] - v_hat[0], s.v_ned_mps[1] - v_hat[1], s.v_ned_mps[2] - v_hat[2])
        bad = seed_disagreement(nu, self.seed_age_s or 0.0, self.cfg.fdi)
        if bad is None:
            return
        j, size, gate = bad
        self._seed_check_t0_s = None
        self.seed_outcome = (
            f"disagreed with the vehicle's measurement ({NED_AXES[j]}: |ν| {size:.2f} m/s > "
            f"gate {gate:.2f} m/s): dropped, started afresh"
        )
        self.counters["estimator_seed_disagreed"] += 1
        logger.warning(
            "vehicle %d: the state it was continued from disagrees with its own velocity "
            "measurement %.3f s later (%s axis: |innovation| %.2f m/s > %.2f m/s = %g sigma): "
            "dropped, starting afresh from the measurement",
            self.sysid,
            s.t_boot_s - t0,
            NED_AXES[j],
            size,
            gate,
            SEED_GATE_SIGMA,
        )
        self.restart("seed_disagreed")

    def _measurement(self, s: VelocitySample, out: list[Record]) -> None:
        t = s.t_boot_s
        inputs = self.inputs
        if self._seed_check_t0_s is not None and self.t_bank_s is not None:
            self._check_seed(s)
        self.out.measurement(s, inputs.euler_rad, out)
        if self.t_bank_s is None and (self._seed is not None or not self._init_from(s)):
            return  # (a seed starts the bank at the next attitude or IMU sample)
        faulty_before = set(self.fdi.faulty_axes())
        imu_hz = self.streams.imu_hz
        if 0.0 < imu_hz < self.cfg.fdi.min_imu_rate_hz:
            # the residual tests cannot arm: said in health (counter, axis_state "warmup")
            # and in the replay/serve summary
            self.counters["fdi_off_imu_too_slow"] += 1
        ints = inputs.ints()
        imus = self.imus
        if imus is not None and imus.instances > 1:
            self.fdi.imus_redundant = imus.redundant()
        verdicts = self.fdi.update(t, s.v_ned_mps, inputs.a_int, ints, imu_hz)
        self.streams.measurement(t)
        f_mean = inputs.f_mean_since_measurement()
        y = self._lag_compensated(s.v_ned_mps, ints[2])
        bridge = self.bridge
        if bridge.cfg.enabled:
            bridge.note(t, inputs.a_int, ints[0], self.fdi.fit.bias_body_mps2)
        if bridge.active:
            bridging = bridge.bridging
            y_ne = bridge.measurement(t, (y[0], y[1]), not self.drift.unaided()[0])
            if y_ne is not None:
                y[0], y[1] = y_ne
            if bridging and not bridge.bridging:
                self._apply_unaided(t)  # the autopilot agrees again: its axes are tested
        inputs.hold_measurement(y)
        self._use = [v.use for v in verdicts]
        self._last_residual = [v.residual_mps for v in verdicts]
        self._last_ratio = [v.test_ratio for v in verdicts]
        self._after_fdi(t, faulty_before)
        if self.aiding is not None and f_mean is not None:
            self._aid(t, f_mean, s.v_ned_mps, inputs.a_int, ints[0])
        if self.gain.on_measurement(
            self.bank, self.fdi, self.despike, imu_hz, self.streams.y_interval_s
        ):
            self.counters["gamma_full_updates"] += 1

    def _aid(
        self, t: float, f_mean: Vec3, v_meas: Vec3, a_int: list[float], b_int: Sequence[float]
    ) -> None:
        """The drag model learns from a measurement while every axis is healthy and armed
        (and the dead reckoning's drift is measured with the integrals ``a_int``, ∫EΓ dt,
        and ``b_int``, ∫E dt); while an axis is lost, the aided offset is updated with it
        (:mod:`aiding`)."""
        aiding = self.aiding
        assert aiding is not None
        e_flat = self.bank.e_last_flat()
        if not self.fdi.faulty_axes():
            if self.fdi.armed():
                aiding.learn(t, f_mean, e_flat, v_meas, a_int_ned_mps=a_int, b_int_flat_s=b_int)
            return
        j = aiding.lost_idx
        if j is None or j != self.sel.lost_idx or len(self.fdi.faulty_axes()) != 1:
            return  # (a second isolated axis would feed the model a faulty measurement)
        _, ned_l = self.bank.estimates_lists()
        aiding.update(f_mean, e_flat, v_meas, self.sel.active_ned(ned_l, self.inputs.c_int)[j], t)

    def _lag_compensated(self, y_ned_mps: Vec3, l_now: tuple[float, float, float]) -> list[float]:
        """The measurement moved to the present by the fit's *observed* lag d̂ (|d̂| > 2σ,
        bounded to [0, max_lag_s]): v(t) ≈ y(t) + d̂ L(t) (fdi module docstring), with
        ``compensate_lag``; else y itself."""
        y = list(y_ned_mps)
        if not self.cfg.compensate_lag:
            return y
        ref = self.sel.reference(self.fdi)
        if ref is None:
            return y
        lag_s = ref.observed(LAG)
        if lag_s <= 0.0:
            return y
        return [y[i] + lag_s * l_now[i] for i in range(3)]

    def _aiding_sample(self, s: AidingSample) -> None:
        """The autopilot's word on what its velocity rests on (:mod:`.drift`): the GPS
        fix, the earliest evidence of a GPS loss, and its estimator's flags
        (EKF_STATUS_REPORT). Unaided axes stay fused and are flagged dead-reckoned, with
        σ; the FDI does not test them (an unaided estimate drifts with the IMU) and warms
        up again when they are aided."""
        drift = self.drift
        if s.gps_v_ne_mps is not None and self.imus is not None and self.t_bank_s is not None:
            self._resolve_imu(s.t_boot_s, s.gps_v_ne_mps)
        if s.source == "GPS_RAW_INT" and self.t_bank_s is not None and self.bridge.cfg.enabled:
            self._gps_bridge(s)
        if s.source == "EKF_STATUS_REPORT":
            drift.on_ekf(s.t_boot_s, s.horizontal_aided, s.vertical_aided)
        else:
            drift.on_gps(s.t_boot_s, s.horizontal_aided)
        self._apply_unaided(s.t_boot_s)

    def _gps_bridge(self, s: AidingSample) -> None:
        """The GPS's velocity for :mod:`.gps_bridge`, before the drift flags take this
        sample: it learns the GPS's lag while all is well (once per ``learn_interval_s``),
        and bridges the autopilot's re-convergence when the fix comes back after a loss."""
        bridge = self.bridge
        t = self.t_bank_s
        assert t is not None
        v = s.gps_v_ne_mps
        if v is None:
            bridge.gps_lost(t)
            return
        drift = self.drift
        use = bridge.active or drift.gps_lost
        learn = (
            not use
            and bridge.learn_due(t)
            and drift.unaided_since_s == _NONE3
            and not self.fdi.faulty_axes()
        )
        if not (use or learn):
            return
        inputs = self.inputs
        bridge.note(t, inputs.a_int, inputs.ints()[0], self.fdi.fit.bias_body_mps2)
        _, ned_l = self.bank.estimates_lists()
        est = ned_l[config_index("full")]
        if learn:
            bridge.learn(t, v, (est[0], est[1]))
            return
        since = drift.unaided_since_s[0]
        sigma_est = (
            self.cfg.fdi.sigma_handover_mps
            if since is None
            else sigma_dead_reckoning_mps(self.cfg.fdi, t - since)
        )
        bridge.on_gps(
            t, v, sigma_gps_mps=s.gps_v_sigma_mps, start=drift.gps_lost,
            v_est=(est[0], est[1]), sigma_est_mps=sigma_est,
        )  # fmt: skip

    def _resolve_imu(self, t: float, gps_v_ne_mps: tuple[float, float]) -> None:
        """Two IMUs disagree (difference D = f_2 − f_1): the GPS's own ground velocity
        (GPS_RAW_INT, which no IMU touched: the autopilot's velocity follows its IMU for
        seconds before its GPS corrects it) tells which one is wrong. If IMU 1 (the one
        integrated here) is, its dead reckoning drifts from the GPS by E D per second:
        r = Δv_gps − ΔA ≈ (E D) Δt on n and e; if IMU 2 is, r stays near 0. The nearer
        side (r's projection on (E D) Δt above or below 1/2) is taken after ``RESOLVE_S``;
        a bias seen only on the vertical (|E D| horizontal below the IMU floor) is not."""
        imus = self.imus
        assert imus is not None
        pending = imus.unresolved()
        if pending is None:
            self._imu_anchor = None
            return
        t_onset, d = pending
        a_int = self.inputs.a_int
        if self._imu_anchor is None or self._imu_anchor[0] < t_onset:
            self._imu_anchor = (t, gps_v_ne_mps, (a_int[0], a_int[1]))
            return
        t0, v0, a0 = self._imu_anchor
        dt = t - t0
        if dt < RESOLVE_S:
            return
        e_d = rotate_flat(self.bank.e_last_flat(), d)
        r = [(gps_v_ne_mps[k] - v0[k]) - (a_int[k] - a0[k]) for k in range(2)]
        h2 = e_d[0] ** 2 + e_d[1] ** 2
        if h2 < imus.cfg.floor_mps2**2 or not all(math.isfinite(x) for x in r):
            return
        proj = (r[0] * e_d[0] + r[1] * e_d[1]) / (dt * h2)
        imus.resolve(1 if proj > 0.5 else 2)
        self.counters[f"imu_fault_on_imu{1 if proj > 0.5 else 2}_by_gps"] += 1
        self._imu_anchor = None

    def _imu_event(self, ev: ImuEvent) -> None:
        """An accelerometer fault told by the redundant IMUs (:mod:`.imu_monitor`): one
        ``accel_bias`` event at its onset, one ``accel_bias_end`` at its end."""
        kind = "accel_bias" if ev.kind == "onset" else "accel_bias_end"
        self.faults.append(
            FaultEvent(
                "body", kind, ev.t_detect_s, ev.t_onset_s, ev.bias_body_mps2, ev.instance,
                ev.sigma_mps2,
            )
        )  # fmt: skip
        self.counters[f"imu_{kind}"] += 1
        self.out.decision()

    def _apply_unaided(self, t: float) -> None:
        """The FDI's untested axes: the autopilot's unaided ones (:mod:`.drift`), and n
        and e while the GPS bridge runs (the autopilot's velocity has not re-converged:
        a late reset would look like a bias fault to a reference that warmed up before
        it)."""
        unaided = self.drift.unaided()
        if self.bridge.bridging:
            unaided[0] = unaided[1] = True
        fdi = self.fdi
        if unaided == fdi.unaided:
            return
        for j in range(3):
            if unaided[j] and not fdi.unaided[j]:
                self.counters[f"unaided_{NED_AXES[j]}"] += 1
            elif fdi.unaided[j] and not unaided[j]:
                self._follow_until_s[j] = t + self.cfg.readmit_follow_s
                self._follow_end_s = max(self._follow_end_s, self._follow_until_s[j])
        fdi.set_unaided(unaided)
        self.out.decision()  # published at once, whatever the records' rates

    def _check_missing(self, t: float) -> None:
        """No velocity measurement for its timeout (streams.StreamTiming): every
        configuration dead-reckons until samples come back; no switch."""
        if not self.streams.check_missing(t):
            return
        self.counters["measurement_missing"] += 1
        self._use = [False, False, False]

    def _after_fdi(self, t: float, faulty_before: set[int]) -> None:
        """The FDI's new events recorded; the configuration without the first isolated
        axis made active (``full`` when none is)."""
        if self.fdi.reference_drifts:  # re-anchorings on a reference offset (no event)
            self.counters["fdi_reference_offsets"] = self.fdi.reference_drifts
        if self.fdi.ramp_withdrawals:  # residual isolations withdrawn on a ramp (no event)
            self.counters["fdi_ramp_withdrawals"] = self.fdi.ramp_withdrawals
        n_faults = len(self.faults)
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
        if len(self.faults) != n_faults or set(faulty) != faulty_before:
            self.out.decision()  # published at once, whatever the records' rates
        wanted = CONFIG_WITHOUT_AXIS[faulty[0]] if faulty else "full"
        if wanted == self.sel.config:
            return
        lost_idx = faulty[0] if faulty else None
        inputs = self.inputs
        assert inputs.euler_rad is not None
        switch, from_dr = self.sel.switch(
            t, wanted, lost_idx, self.bank, self.fdi, inputs.a_int, inputs.ints(), inputs.euler_rad
        )
        if from_dr:
            self.counters["handover_from_dead_reckoning"] += 1
        if wanted == "full" and lost_idx is None:
            self.gain.blend_after_recovery(t, self.bank)
        if self.aiding is not None:
            if lost_idx is None:
                self.aiding.stop()
            else:
                self.aiding.start(t, lost_idx)
        self.switches.append(switch)
        self.out.decision()

    # ------------------------------------------------------------------ records
    def _velocity_records(self, out: list[Record]) -> None:
        t = self.t_bank_s
        assert t is not None
        sel = self.sel
        c_int = self.inputs.c_int
        body, ned_l = self.bank.estimates_lists()
        fdi_cfg = self.cfg.fdi
        t_dr = sel.t_dr_start_s
        sigma = [
            sigma_dead_reckoning_mps(fdi_cfg, t - t_dr[i]) if has_lost else None
            for i, has_lost in enumerate(_HAS_LOST_AXIS)
        ]
        a_sigma = (
            None
            if LOST_AXIS_OF_CONFIG[sel.config] is None
            else sigma_dead_reckoning_mps(fdi_cfg, t - sel.t_handover_s)
        )
        a_dr = sel.active_ned(ned_l, c_int)  # the lost axis dead-reckoned
        n_faulty = len(self.fdi.faulty_axes())
        aiding = self.aiding
        j = sel.lost_idx
        st = None
        if aiding is not None and j is not None and aiding.lost_idx == j and n_faulty == 1:
            st = aiding.lost_axis(a_dr[j])
        a_ned = a_dr
        a_body: Vec3 | None = None
        a_health: str | None = None  # None: from the faulty axes (ok, dead_reckoning, ...)
        if self.cfg.aero_active and aiding is not None and j is not None:
            # the active estimate is the aided one while the aiding runs; what the filter
            # drops returns to the dead reckoning (aiding.RETURN_TIME_S), not at once
            f_off = None if st is None else st.v_mps - a_dr[j]  # exactly 0: DR itself
            off = aiding.active_offset(t, f_off)
            sel.aided_offset_mps = off
            a_ned = sel.active_ned(ned_l, c_int, None, off)
            if off != 0.0:
                # body = Eᵀ v: the offset on NED axis j moves it by off · (row j of E)
                e_flat = self.bank.e_last_flat()
                b = body[config_index(sel.config)]
                a_body = (
                    b[0] + off * e_flat[3 * j],
                    b[1] + off * e_flat[3 * j + 1],
                    b[2] + off * e_flat[3 * j + 2],
                )
            if st is not None and f_off and a_sigma is not None:
                # the filter's offset in use: its σ, and the part still returning in full
                a_sigma = st.sigma_mps + abs(off - f_off)
                # ... and the record says so while pseudo-measurements are being accepted
                a_health = "aided" if st.aided else None
            elif a_sigma is not None:
                # the dead reckoning (never aided, or set back): its σ, as without the
                # aiding (bit for bit when nothing returns), and the returning part
                a_sigma += abs(off)
        if self.cfg.follow_unaided and (True in self.fdi.unaided or t < self._follow_end_s):
            a_ned = self._follow_unaided(a_ned, j, t)
        self.out.velocity(
            t, body, ned_l, n_faulty, sigma, sel.config, a_ned, a_sigma, out, a_body, a_health,
            self._drift_sigma(t),
        )  # fmt: skip
        if self.scorer is not None:  # every configuration's estimate and active's
            self.scorer.add_estimates(t, _SCORED, (*ned_l, a_ned))
        if st is not None and j is not None:
            v_aided = [a_dr[0], a_dr[1], a_dr[2]]
            v_aided[j] = st.v_mps
            e_flat = self.bank.e_last_flat()
            self.out.aided(t, e_flat, v_aided, sel.config, st.sigma_mps, st.aided, out)
        settled = sel.settle_jump(ned_l, c_int)
        if settled is not None:
            self.switches[-1] = settled

    def _follow_unaided(self, a_ned: Vec3, lost_idx: int | None, t: float) -> Vec3:
        """While the autopilot's velocity is unaided on an axis (GPS lost), and for
        ``readmit_follow_s`` after it is aided again, ``active`` on it is the autopilot's
        velocity carried to now by the IMU (the held measurement, propagated:
        ``HeldInputs.y_for_step``; after a GPS loss the GPS's own velocity where
        :mod:`.gps_bridge` runs): the autopilot dead-reckons from its full-rate IMU, and
        filtering it with the decimated IMU here only adds lag (on ``b_quad_gps_off``
        east during the loss: 0.0482 m/s filtered, 0.0411 followed, the autopilot's
        0.0407). An axis the active configuration has lost keeps its own."""
        y = self.inputs.y_for_step(self.fdi.fit.bias_body_mps2, True)
        un = self.fdi.unaided
        until = self._follow_until_s
        v = [a_ned[0], a_ned[1], a_ned[2]]
        for k in range(3):
            if (un[k] or t < until[k]) and k != lost_idx and math.isfinite(y[k]):
                v[k] = y[k]
        return (v[0], v[1], v[2])

    def _drift_sigma(self, t: float) -> list[float | None] | None:
        """Per NED axis, the σ of an axis every configuration dead-reckons now (None:
        measured), or None when there is none: the isolated axes beyond the active
        configuration's lost one (σ since their isolation), the unaided axes and a silent
        measurement stream (:mod:`.drift`). A healthy vehicle (nothing unaided or isolated,
        the stream on time) returns at the first test: this runs at every record built."""
        streams = self.streams
        if (
            self.drift.unaided_since_s == _NONE3
            and not self.fdi.faulty_axes()
            and t - streams.t_y_s <= self.cfg.fdi.overdue_intervals * streams.y_interval_s
        ):
            return None
        sig = drift_sigma_ned_mps(
            self.cfg.fdi, t, self.drift.unaided_since_s, streams.t_y_s or None,
            streams.y_interval_s,
            [max(ax.sigma_r_mps, self.cfg.fdi.sigma_velocity_mps) for ax in self.fdi.axes],
        )  # fmt: skip
        faulty = self.fdi.faulty_axes()
        for j in faulty:  # every configuration masks them (the active one: its lost axis)
            ax = self.fdi.axes[j]
            s_iso = sigma_dead_reckoning_mps(self.cfg.fdi, t - ax._t_isolated_s)
            sig[j] = s_iso if sig[j] is None else max(sig[j] or 0.0, s_iso)
        return None if sig == [None, None, None] else sig

    def _health_record(self, t: float) -> Record:
        faults = (
            *(a.fault for a in self.fdi.axes if a.fault is not None),
            *(
                f
                for f in self.faults
                if f.kind == "accel_bias" and t - f.t_detect_s <= ACCEL_EVENT_HOLD_S
            ),
        )
        return self.out.health(
            t,
            self.sel.config,
            self._last_residual,
            self._last_ratio,
            self.fdi.states(),
            faults,
            self.rates_fn(t) if self.rates_fn is not None else {},
            self.all_counters(),
            self.reference_fit_summary(),
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
