"""The active configuration of one vehicle and the hand-over between configurations.

``full`` is active while every axis is healthy. When the FDI isolates axis j, the
configuration without j (n -> c2, e -> c3, d -> c1, :mod:`glmav_observer.configurations`)
is started from the last good estimate: ``full``'s current NED velocity, which the FDI's
gate kept free of the faulty samples (if it differs from the FDI's dead reckoning from
vetted data by more than ``handover_contamination_mps``, the dead reckoning is used
instead). Its lost axis is dead-reckoned; its σ grows from the hand-over
(``fdi.sigma_dead_reckoning_mps``). When the axis recovers, ``full`` is restarted from the
active estimate.

The reference in force. While an axis is isolated, the FDI's reference fit (accelerometer
bias b̂, heading error δψ̂, lag d̂) is the one frozen at the hand-over: a fit that goes on
with one axis faulty cannot poison the dead reckoning. With ``compensate_accel_bias`` the
bank is fed f − b̂_obs, b̂_obs the components the fit has *observed* (|b̂_k| > 2σ_k; an
unexcited one stays at the prior's 0), and the active estimate's dead-reckoned axis gets
the observed heading term (C_j(t) − C_j(t_h)) δψ̂ since the hand-over.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from glmav_observer.configurations import (
    CONFIGS,
    LOST_INDEX_OF_CONFIG,
    config_index,
)
from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.fdi import FaultDetector
from glmav_observer.estimation.fdi_reference import Integrals, Reference
from glmav_observer.records import NED_AXES

Vec3 = tuple[float, float, float]


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


class ActiveSelection:
    """Which configuration is active, since when each dead-reckons, and the reference in
    force (module docstring)."""

    def __init__(self, compensate_accel_bias: bool, handover_contamination_mps: float) -> None:
        self.compensate_accel_bias = compensate_accel_bias
        self.handover_contamination_mps = handover_contamination_mps
        self.config = "full"
        self.lost_idx: int | None = None
        #: the start of the active estimate's dead reckoning
        self.t_handover_s = 0.0
        #: per configuration (CONFIGS order), the start of its lost axis's dead reckoning
        self.t_dr_start_s = [0.0] * len(CONFIGS)
        self.ints_handover: Integrals | None = None
        self.ref_handover: Reference | None = None
        #: the last switch, until the next record measures its jump
        self.pending: SwitchEvent | None = None
        #: the active estimate's lost-axis offset from its dead reckoning: the drag
        #: model's aiding (``aero_active``, :meth:`~glmav_observer.estimation.aiding.
        #: LostAxisAiding.active_offset`), set at each record; 0 without it. A switch
        #: starts the new configuration from the active estimate with it, and measures
        #: its jump against it (the offset at the switch, ``_pending_offset_mps``)
        self.aided_offset_mps = 0.0
        self._pending_offset_mps = 0.0
        self._bias_ref: Reference | None = None
        self._bias_obs: Vec3 = (0.0, 0.0, 0.0)

    def start(self, t: float) -> None:
        """Every configuration starts at ``t`` (the bank's first state)."""
        self.t_dr_start_s = [t] * len(CONFIGS)

    def reference(self, fdi: FaultDetector) -> Reference | None:
        """The reference fit in force: frozen at the hand-over while an axis is isolated."""
        return self.ref_handover if fdi.faulty_axes() else fdi.fit.ref

    def bank_bias(self, fdi: FaultDetector) -> Vec3 | None:
        """The accelerometer bias fed to the bank: the fit's *observed* components
        (|θ̂_k| > 2σ_k; the fit bounds ‖b̂‖) of the reference in force; None without a fit
        or with ``compensate_accel_bias`` off."""
        if not self.compensate_accel_bias:
            return None
        ref = self.reference(fdi)
        if ref is None:
            return None
        if ref is not self._bias_ref:
            self._bias_ref = ref
            self._bias_obs = (ref.observed(3), ref.observed(4), ref.observed(5))
        return self._bias_obs

    def continue_handover(
        self, config: str, lost_idx: int, t_handover_s: float, ints: Integrals,
        ref: Reference | None,
    ) -> None:  # fmt: skip
        """Resume a hand-over another service started (a takeover's seed)."""
        self.config = config
        self.lost_idx = lost_idx
        self.t_handover_s = t_handover_s
        self.ints_handover = ints
        self.ref_handover = ref

    def switch(  # noqa: PLR0917 -- the state a hand-over reads
        self,
        t: float,
        to: str,
        lost_idx: int | None,
        bank: ObserverBank,
        fdi: FaultDetector,
        a_int: list[float],
        ints: Integrals,
        euler_rad: Vec3,
    ) -> tuple[SwitchEvent, bool]:
        """Make ``to`` active at ``t`` (``lost_idx``: the axis isolated, None: recovered),
        started from the active estimate. Returns the event (also kept as :attr:`pending`)
        and whether the lost axis started from the FDI's dead reckoning instead."""
        c_int = ints[1]
        before = self.active_ned(bank.x_hat_ned_mps().tolist(), c_int, None, self.aided_offset_mps)
        self._pending_offset_mps = self.aided_offset_mps
        self.aided_offset_mps = 0.0
        v0 = list(before)
        reason = "recovered"
        from_dead_reckoning = False
        if lost_idx is not None:
            ax = fdi.axes[lost_idx]
            reason = f"{ax.fault.kind if ax.fault else 'fault'}_{NED_AXES[lost_idx]}"
            if self.config == "full":
                pred = ax.predict_mps(a_int[lost_idx], ints, lagged=False)
                if (
                    math.isfinite(pred)
                    and abs(pred - v0[lost_idx]) > self.handover_contamination_mps
                ):
                    from_dead_reckoning = True
                    v0[lost_idx] = pred
            self.t_handover_s = t
            self.ints_handover = ints
            self.ref_handover = ax.reference()
        bank.set_state_ned(to, v0, euler_rad)
        self.t_dr_start_s[config_index(to)] = t
        ev = SwitchEvent(t, self.config, to, reason, (before[0], before[1], before[2]))
        self.pending = ev
        self.config = to
        self.lost_idx = lost_idx
        return ev, from_dead_reckoning

    def settle_jump(
        self, ned_l: Sequence[Sequence[float]], c_int: Sequence[float]
    ) -> SwitchEvent | None:
        """The pending switch with its jump: the new active against what the old one says
        at this same time (not against its value at the switch: the vehicle moved)."""
        sw = self.pending
        if sw is None:
            return None
        self.pending = None
        jump = math.dist(
            self.active_ned(ned_l, c_int, sw.from_config, self._pending_offset_mps),
            self.active_ned(ned_l, c_int, None, self.aided_offset_mps),
        )
        return SwitchEvent(
            sw.t_boot_s, sw.from_config, sw.to_config, sw.reason, sw.v_before_ned_mps, jump
        )

    def active_ned(
        self,
        ned_l: Sequence[Sequence[float]],
        c_int: Sequence[float],
        config: str | None = None,
        offset_mps: float = 0.0,
    ) -> Vec3:
        """The active estimate if ``config`` (default: the active one) were active: its NED
        velocity, its dead-reckoned axis corrected by the fit (``compensate_accel_bias``)
        and moved by ``offset_mps`` (the aiding's, :attr:`aided_offset_mps`; default 0:
        the dead reckoning)."""
        config = self.config if config is None else config
        v = ned_l[config_index(config)]
        j = LOST_INDEX_OF_CONFIG[config]
        if j is None:
            return (v[0], v[1], v[2])
        out = [v[0], v[1], v[2]]
        if self.compensate_accel_bias:
            out[j] += self._lost_axis_correction(j, c_int)
        out[j] += offset_mps
        return (out[0], out[1], out[2])

    def _lost_axis_correction(self, j: int, c_int: Sequence[float]) -> float:
        """The fit's heading correction of the dead-reckoned axis j since the hand-over
        (module docstring); only an observed heading error (|δψ̂| > 2σ) counts. (The bias
        is in the bank already: :meth:`bank_bias`.)"""
        ref = self.ref_handover
        h = self.ints_handover
        if ref is None or h is None:
            return 0.0
        dpsi = ref.observed(6)
        if dpsi == 0.0:
            return 0.0
        return (c_int[j] - h[1][j]) * dpsi
