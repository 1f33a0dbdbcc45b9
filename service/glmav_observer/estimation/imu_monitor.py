"""Accelerometer faults told apart by the vehicle's own redundant IMUs.

Autopilots carry two or three IMUs and send them all: ArduPilot ``RAW_IMU`` (IMU 1),
``SCALED_IMU2`` and ``SCALED_IMU3``. Rigidly mounted on one airframe, they measure the
same specific force up to a constant calibration offset, the lever arm's rotational terms
and their noise. A bias that appears on one of them shows as a step in its difference from
the others, seen directly and at once, where the velocity residuals (the FDI's
single-IMU test, :mod:`.fdi_change`) see it only as a slow ramp, blurred by the reference
fit and by anything else that moves the residuals (vibration, a noisy GPS).

Per IMU instance k the monitor keeps the difference d_k = f_k − f_1 (body FRD, m/s²) to the
estimator's IMU (instance 1), at the instance's latest sample, over a window of
``window_s``. Its deviation from the pair's **baseline** (the slow mean of d_k while every
IMU agrees: a calibration offset is no fault) is tested per axis against

    threshold = max(floor_mps2, k_sigma · σ_d / √n)        (σ_d: the difference's spread)

With three or more IMUs the faulty one is the one that deviates from the **median** of all
(IMU 1 included: the median of its own zero and the others' deviations); with two, the
pair says a bias appeared but not on which IMU: the event names no instance and the
estimator keeps its IMU. When IMU 1 is the faulty one, its estimated bias is subtracted
from its samples (:meth:`ImuConsistency.correction`), which is estimating from the healthy
IMUs without their timing: the FDI then sees no ramp and stays armed.

Events: one **onset** per fault, published when the window lies wholly after the onset
(its estimate the window's mean, its σ the mean's) and, with two IMUs, once the GPS has
told which one is wrong (or after ``resolve_timeout_s``, naming none); one **end** when
the deviation has stayed below half the threshold for a whole window. ``bias_body_mps2``
is the named IMU's bias (f_k − f_true), or f_2 − f_1 when none is named.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

from glmav_observer.estimation.imu_window import PairWindow, deviation_test
from glmav_observer.estimation.reasons import const

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class ImuMonitorConfig:
    """Settings of the redundant-IMU monitor (``[fdi.imu]`` of ``configs/service.toml``)."""

    window_s: float = const(
        0.5, unit="s", source="physics",
        reason="the window of the differences' means: 25 samples at ArduPilot's 50 Hz "
        "streams; the onset is published a window after the fault, well inside the "
        "dead reckoning's 0.3 m/s per s at a 0.3 m/s² bias",
    )  # fmt: skip
    floor_mps2: float = const(
        0.15, unit="m/s²", source="measured",
        reason="the smallest bias reported: above the 1 s mean differences of healthy IMUs "
        "on one airframe (lever arm, vibration: 0.001-0.005 m/s² on ArduPilot's SITL "
        "corpus) with a margin for real sensors, below the 0.3-0.5 m/s² biases that "
        "matter for velocity (0.3 m/s² dead-reckons 0.3 m/s in 1 s)",
        sensitivity=True,
    )  # fmt: skip
    k_sigma: float = const(
        5.0, unit="σ", source="statistic",
        reason="the deviation of a window's mean, in its own σ, that is a change (a false "
        "alarm in ~1e-6 windows per axis for Gaussian noise)",
    )  # fmt: skip
    baseline_tau_s: float = const(
        60.0, unit="s", source="physics",
        reason="the baseline's time constant: slow against a fault (a step), fast against "
        "temperature drift of a calibration offset (minutes)",
    )  # fmt: skip
    max_age_s: float = const(
        0.1, unit="s", source="physics",
        reason="a secondary sample older than this is not compared (a stream that "
        "stopped): 5 periods at 50 Hz",
    )  # fmt: skip
    resolve_timeout_s: float = const(
        3.0, unit="s", source="requirement",
        reason="two IMUs: the onset event waits this long for the GPS to tell which one "
        "is wrong (VehicleEstimator._resolve_imu takes 1 s of GPS velocity, RESOLVE_S), "
        "then is published naming no IMU",
    )  # fmt: skip
    min_samples: int = const(
        5, unit="samples", source="statistic",
        reason="a window's mean and σ need at least this many differences (σ/√n from "
        "fewer is itself too uncertain for a 5σ test)",
    )  # fmt: skip
    min_fill: float = const(
        0.8, unit="", source="statistic",
        reason="a window is tested once it spans this fraction of window_s (after a start "
        "or a gap a half-filled window's σ/√n is too small a sample)",
    )  # fmt: skip
    end_fraction: float = const(
        0.5, unit="", source="statistic",
        reason="a fault ends when every deviation stays below this fraction of the "
        "threshold for a whole window: a hysteresis of half the threshold",
    )  # fmt: skip


@dataclass(frozen=True, slots=True)
class ImuEvent:
    """An accelerometer fault on one IMU (``instance``; None: two IMUs disagree and
    neither can be blamed): its onset or its end."""

    kind: str  # "onset" | "end"
    instance: int | None
    t_detect_s: float
    t_onset_s: float
    bias_body_mps2: Vec3
    sigma_mps2: Vec3


@dataclass
class _Fault:
    instance: int | None
    t_onset_s: float
    t_detect_s: float
    published: bool = False
    quiet_since_s: float | None = None
    bias: Vec3 = (0.0, 0.0, 0.0)
    sigma: Vec3 = (0.0, 0.0, 0.0)
    #: two IMUs: the one blamed by the velocity measurement (None: not yet)
    resolved: int | None = None


class ImuConsistency:
    """The redundant IMUs of one vehicle compared (module docstring)."""

    def __init__(self, cfg: ImuMonitorConfig | None = None) -> None:
        self.cfg = cfg or ImuMonitorConfig()
        #: per secondary instance, its differences to IMU 1 (compiled: imu_window)
        self._pairs: dict[int, PairWindow] = {}
        self._fault: _Fault | None = None
        self.events: list[ImuEvent] = []
        #: IMU 1's estimated bias while it is the faulty one (subtracted from its samples)
        self._correction: Vec3 | None = None

    @property
    def instances(self) -> int:
        """How many IMUs are compared (1: only the estimator's)."""
        return 1 + len(self._pairs)

    def secondary(self, instance: int, t_s: float, f_body_mps2: Vec3) -> None:
        """A sample of another IMU (``SCALED_IMU2``, ``SCALED_IMU3``). Exact zeros on three
        axes are an IMU that is not there (ArduPilot sends them for a missing IMU 3; an
        accelerometer reads gravity)."""
        if f_body_mps2 == (0.0, 0.0, 0.0):
            return
        p = self._pairs.get(instance)
        if p is None:
            p = self._pairs[instance] = PairWindow()
        p.note(t_s, f_body_mps2)

    def correction(self) -> Vec3 | None:
        """IMU 1's bias to subtract from its samples, or None."""
        return self._correction

    def redundant(self) -> bool:
        """More than one IMU is compared: accelerometer faults are told here."""
        return bool(self._pairs)

    def unresolved(self) -> tuple[float, Vec3] | None:
        """A fault between two IMUs not yet blamed on one: (onset, f_2 − f_1 now)."""
        f = self._fault
        if f is None or f.resolved is not None or len(self._pairs) != 1:
            return None
        return f.t_onset_s, f.bias

    def resolve(self, instance: int) -> None:
        """Blame the pending two-IMU fault on ``instance`` (1 or 2), told by the velocity
        measurement (``VehicleEstimator._resolve_imu``)."""
        if self._fault is not None:
            self._fault.resolved = instance

    def primary(self, t_s: float, f_body_mps2: Vec3) -> list[ImuEvent]:
        """A sample of IMU 1 (the raw one, before any correction): compare; the events."""
        if not self._pairs:
            return []
        cfg = self.cfg
        dev: dict[int, tuple[list[float], list[float]]] = {}
        for k, p in self._pairs.items():
            # None: a stale secondary (its window emptied) or a window half filled (after
            # a start or a gap)
            r = p.step(t_s, f_body_mps2, cfg.window_s, cfg.max_age_s, cfg.min_samples, cfg.min_fill)
            if r is not None:
                dev[k] = r
        if not dev:
            return []
        blamed, bias, sigma, exceeds, quiet = self._blame(dev)
        if self._fault is None:
            self._learn_baselines(dev)
        return self._track(t_s, blamed=blamed, bias=bias, sigma=sigma, exceeds=exceeds, quiet=quiet)

    def _blame(
        self, dev: dict[int, tuple[list[float], list[float]]]
    ) -> tuple[int | None, Vec3, Vec3, bool, bool]:
        """(instance blamed, its bias, σ, a deviation exceeds the threshold, every
        deviation below half of it). The deviation of IMU k from IMU 1 is dev[k]; of IMU
        j from the median of all, dev[j] − median (IMU 1's own: 0 − median). The
        threshold and its tests are compiled (:func:`.imu_window.deviation_test`)."""
        cfg = self.cfg
        thr, exceeds, quiet, sig = deviation_test(
            list(dev.values()), cfg.floor_mps2, cfg.k_sigma, cfg.end_fraction
        )
        if len(dev) == 1:
            (m, _) = next(iter(dev.values()))
            return None, (m[0], m[1], m[2]), (sig[0], sig[1], sig[2]), exceeds, quiet
        axes = range(3)
        ids = [1, *dev]
        rel = {1: [0.0, 0.0, 0.0], **{k: v[0] for k, v in dev.items()}}
        med = [statistics.median(rel[i][a] for i in ids) for a in axes]
        off = {i: [rel[i][a] - med[a] for a in axes] for i in ids}
        worst = max(ids, key=lambda i: max(abs(x) / t for x, t in zip(off[i], thr, strict=True)))
        o = off[worst]
        # IMU 1's bias is minus its difference to the others: f_1 = f_true + b_1
        return worst, (o[0], o[1], o[2]), (sig[0], sig[1], sig[2]), exceeds, quiet

    def _learn_baselines(self, dev: dict[int, tuple[list[float], list[float]]]) -> None:
        """The pairs' baselines follow their means while every IMU agrees (τ
        ``baseline_tau_s``, one step per sample)."""
        for k, (m, _) in dev.items():
            self._pairs[k].learn_baseline(m, self.cfg.baseline_tau_s)

    def _track(
        self,
        t_s: float,
        *,
        blamed: int | None,
        bias: Vec3,
        sigma: Vec3,
        exceeds: bool,
        quiet: bool,
    ) -> list[ImuEvent]:
        cfg = self.cfg
        out: list[ImuEvent] = []
        f = self._fault
        if f is None:
            if exceeds:
                # the onset: the window's first sample whose difference left the baseline
                self._fault = _Fault(blamed, self._onset(t_s), t_s)
            return out
        if f.resolved is not None:  # two IMUs: bias = f_2 − f_1; IMU 1's own is minus it
            blamed = f.resolved
            if blamed == 1:
                bias = (-bias[0], -bias[1], -bias[2])
        if not f.published:
            f.instance = blamed
            f.bias, f.sigma = bias, sigma
            if f.instance == 1:
                self._correction = bias
            age = t_s - f.t_onset_s
            if age >= cfg.window_s and (blamed is not None or age >= cfg.resolve_timeout_s):
                f.published = True
                ev = ImuEvent("onset", f.instance, t_s, f.t_onset_s, bias, sigma)
                self.events.append(ev)
                out.append(ev)
            return out
        if blamed == 1 and not quiet:
            f.instance = 1
            self._correction = bias  # (a bias that drifts is followed)
        if quiet:
            if f.quiet_since_s is None:
                f.quiet_since_s = t_s
            if t_s - f.quiet_since_s >= cfg.window_s:
                ev = ImuEvent("end", f.instance, t_s, f.t_onset_s, f.bias, f.sigma)
                self.events.append(ev)
                out.append(ev)
                self._fault = None
                self._correction = None
            return out
        f.quiet_since_s = None
        return out

    def _onset(self, t_s: float) -> float:
        """The first sample of the window whose difference is beyond the floor from the
        baseline, on any pair and axis (the window's start if none)."""
        t0 = t_s
        for p in self._pairs.values():
            t0 = min(t0, p.onset(self.cfg.floor_mps2))
        return t0
