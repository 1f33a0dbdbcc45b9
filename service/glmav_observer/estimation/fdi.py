"""Fault detection and isolation (FDI) of the velocity measurement, one NED axis at a time.

Pure computation (no I/O): the vehicle estimator feeds it the earth-frame integrals of the
IMU and every velocity measurement; it returns, per axis, whether the sample may be used,
the residual and its test ratio, and isolation/recovery events. Docs: docs/design/observer-notes.md,
"Fault isolation".

The parts, one module each: the settings and vocabulary
(:mod:`~glmav_observer.estimation.fdi_types`), the reference the IMU gives and its fit
(:mod:`~glmav_observer.estimation.fdi_reference`), the tests of one axis
(:mod:`~glmav_observer.estimation.fdi_axis`) and the accelerometer-change classifier
(:mod:`~glmav_observer.estimation.fdi_change`). This module composes them:
:class:`FaultDetector` runs the three axis monitors on one shared reference fit and decides,
when an axis wants isolating, between a velocity fault and an IMU at fault.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from glmav_observer.estimation.fdi_axis import AxisMonitor
from glmav_observer.estimation.fdi_change import AccelChange, classify_change
from glmav_observer.estimation.fdi_reference import Integrals, ReferenceFit
from glmav_observer.estimation.fdi_types import (
    RESIDUAL_KINDS,
    AxisVerdict,
    FaultKind,
    FdiConfig,
)
from glmav_observer.records import NED_AXES, AxisName


@dataclass
class FaultDetector:
    """FDI of the three NED axes of one vehicle."""

    cfg: FdiConfig = field(default_factory=FdiConfig)
    fit: ReferenceFit = field(init=False)
    axes: tuple[AxisMonitor, AxisMonitor, AxisMonitor] = field(init=False)
    accel_changes: list[AccelChange] = field(default_factory=list)
    reference_drifts: int = 0
    #: residual isolations withdrawn on a ramping residual (``ramp_limit_mps2``)
    ramp_withdrawals: int = 0
    #: the vehicle's redundant IMUs are compared (``imu_monitor``): they tell an
    #: accelerometer fault themselves, so a common ramp of the residuals is the reference's
    imus_redundant: bool = False
    #: per axis: the autopilot's velocity is unaided (used, not tested: :meth:`set_unaided`)
    unaided: list[bool] = field(default_factory=lambda: [False, False, False])
    #: (t, axis, residual, B flat 9) of every axis over the last change_window_s
    _recent: deque[tuple[float, int, float, tuple[float, ...]]] = field(default_factory=deque)

    def __post_init__(self) -> None:
        self.fit = ReferenceFit(self.cfg)
        self.axes = (
            AxisMonitor("n", 0, self.cfg, self.fit),
            AxisMonitor("e", 1, self.cfg, self.fit),
            AxisMonitor("d", 2, self.cfg, self.fit),
        )

    def update(
        self,
        t_s: float,
        y_ned_mps: tuple[float, float, float],
        a_int_mps: list[float],
        ints: Integrals,
        imu_rate_hz: float = math.inf,
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """One velocity measurement; the verdict per NED axis.

        Below ``min_imu_rate_hz`` the IMU cannot predict the velocity: the residual tests
        are off and only dropout and freeze are tested.
        """
        fit = self.fit
        fit.imu_ok = imu_rate_hz >= self.cfg.min_imu_rate_hz
        a0, a1, a2 = self.axes
        a0.vet(t_s)
        a1.vet(t_s)
        a2.vet(t_s)
        fit.frozen_bias = a0.fault is not None or a1.fault is not None or a2.fault is not None
        fit.prune_and_fit(t_s)
        u = self.unaided
        if True in u:
            w = [
                AxisVerdict(True, math.nan, 0.0, ax.state)
                if u[j] and ax.fault is None and math.isfinite(y_ned_mps[j])
                else ax.update(t_s, y_ned_mps[j], a_int_mps[j], ints)
                for j, ax in enumerate(self.axes)
            ]
            v = (w[0], w[1], w[2])
        else:
            v = (
                a0.update(t_s, y_ned_mps[0], a_int_mps[0], ints),
                a1.update(t_s, y_ned_mps[1], a_int_mps[1], ints),
                a2.update(t_s, y_ned_mps[2], a_int_mps[2], ints),
            )
        recent = self._recent
        for j, vj in enumerate(v):
            if math.isfinite(vj.residual_mps) and self.axes[j].fault is None:
                recent.append((t_s, j, vj.residual_mps, ints[0]))
        t_min = t_s - self.cfg.change_window_s
        while recent and recent[0][0] < t_min:
            recent.popleft()
        return self._decide(t_s, v)

    def _decide(
        self, t_s: float, v: tuple[AxisVerdict, AxisVerdict, AxisVerdict]
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """Isolate the axes whose tests failed k times, unless an accelerometer change
        explains the residuals of all axes better (module docstring)."""
        for ax in self.axes:
            if ax.fault is not None and ax.fault.kind in RESIDUAL_KINDS and ax.ramping(t_s):
                # the IMU's path drifts, not the axis: withdraw, restart the reference
                self.ramp_withdrawals += 1
                return self._rebase(t_s, t_s, None, ax.axis, v)
        wants: list[tuple[int, FaultKind]] = []
        for j, ax in enumerate(self.axes):
            k = ax.wants_isolation()
            if k is not None:
                wants.append((j, k))
        if not wants:
            return v
        out = list(v)
        j0, k0 = wants[0]
        others = [a for a in self.axes if a.fault is not None and a.fault.kind in RESIDUAL_KINDS]
        if len(wants) >= 2 or others:
            # two velocity sensors failing at once is far less likely than one IMU or
            # attitude error seen on every axis: blame the IMU, withdraw the isolations
            _, db, t_c = classify_change(j0, list(self._recent), self._sigmas())
            # (the redundant IMUs tell accelerometer changes: none here, no event)
            db_or_none = None if self.imus_redundant else db
            t_rebase = t_s if math.isnan(t_c) else t_c
            return self._rebase(t_s, t_rebase, db_or_none, self.axes[j0].axis, v)
        if k0 is FaultKind.BIAS and self.fit.ref is not None and not self.fit.frozen_bias:
            kind, db, t_c = classify_change(j0, list(self._recent), self._sigmas())
            if kind == "undecided":
                return v  # the tests fail again on the next sample, with more history
            if kind == "accel" and self.imus_redundant:
                # the vehicle's redundant IMUs tell an accelerometer fault themselves
                # (imu_monitor): the residuals' common ramp is the reference's, restarted
                # without an accelerometer event
                kind = "offset"
            if kind == "offset":
                self.reference_drifts += 1
                return self._rebase(t_s, t_c, None, self.axes[j0].axis, v)
            if kind == "accel":
                return self._rebase(t_s, t_c, db, self.axes[j0].axis, v)
        for j, kind_j in wants:
            self.axes[j].isolate(t_s, kind_j)
            out[j] = AxisVerdict(False, v[j].residual_mps, v[j].test_ratio, self.axes[j].state)
        return (out[0], out[1], out[2])

    def restart_reference(self) -> None:
        """The estimator's IMU was corrected (its bias told by the redundant IMUs): the
        reference restarts from the samples after the correction, every axis warms up."""
        self.fit.drop_before(math.inf)
        for ax in self.axes:
            ax.rebase()
        self._recent.clear()

    def _sigmas(self) -> tuple[float, float, float]:
        return (self.axes[0].sigma_r_mps, self.axes[1].sigma_r_mps, self.axes[2].sigma_r_mps)

    def _rebase(
        self,
        t_s: float,
        t_c: float,
        db: tuple[float, float, float] | None,
        by: AxisName,
        v: tuple[AxisVerdict, AxisVerdict, AxisVerdict],
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """An accelerometer change (``db``) or a reference offset (None) at t_c: the
        reference restarts from the samples after it; no sample of this measurement is
        used (the verdicts ``v`` are returned with ``use`` off)."""
        if db is not None:
            self.accel_changes.append(AccelChange(t_s, t_c, db, by))
            self.fit.carried_prior = None  # the accelerometer changed: not its bias any more
        self.fit.drop_before(math.inf)
        for ax in self.axes:
            ax.rebase()
        self._recent.clear()
        a, b, c = (
            AxisVerdict(False, x.residual_mps, x.test_ratio, ax.state)
            for x, ax in zip(v, self.axes, strict=True)
        )
        return (a, b, c)

    def set_unaided(self, unaided: list[bool]) -> list[int]:
        """The axes whose velocity the autopilot dead-reckons (``drift.DriftAxes``): their
        measurement is still used (it is the autopilot's best estimate) but not tested,
        since an unaided estimate drifts with the IMU it shares with the reference. An axis
        aided again warms up on the new level (the autopilot's estimate snaps back to
        its sensor). Returns the axes aided again."""
        back = [j for j in range(3) if self.unaided[j] and not unaided[j]]
        for j in back:
            self.axes[j].restart_reference()
        self.unaided = list(unaided)
        return back

    def faulty_axes(self) -> list[int]:
        """Indices (0 n, 1 e, 2 d) of the axes currently isolated, in isolation order."""
        a0, a1, a2 = self.axes
        if a0.fault is None and a1.fault is None and a2.fault is None:
            return []  # the healthy vehicle: asked several times per sample
        idx = [i for i, a in enumerate(self.axes) if a.fault is not None]
        return sorted(idx, key=lambda i: self.axes[i]._t_isolated_s)

    def states(self) -> dict[str, str]:
        """Each axis's state; ``unaided`` while the autopilot dead-reckons it (untested)."""
        return {
            ax: "unaided" if self.unaided[j] and m.fault is None else m.state.value
            for j, (ax, m) in enumerate(zip(NED_AXES, self.axes, strict=True))
        }

    def armed(self) -> bool:
        """Residual tests are running on every healthy axis."""
        a0, a1, a2 = self.axes  # (asked at every measurement: no generator)
        return (
            (a0.fault is not None or a0.armed())
            and (a1.fault is not None or a1.armed())
            and (a2.fault is not None or a2.armed())
        )
