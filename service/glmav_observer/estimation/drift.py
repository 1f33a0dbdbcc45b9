"""Which measured axes rest on dead reckoning although no fault is isolated, and since when.

Two field failures leave a configuration's measured axes without an anchor while the
measurement itself looks healthy:

- **The autopilot's velocity is unaided** (GPS lost). ``LOCAL_POSITION_NED`` is the
  autopilot's own estimate: without GPS it keeps coming, smooth, dead-reckoned by the
  autopilot's EKF from its full-rate IMU. That is at least as good as anything this
  service can integrate from the decimated IMU it receives, so it stays fused (the
  published estimate follows it; the FDI stops testing it: :meth:`FaultDetector.set_unaided`)
  and the axes are *flagged*: dead-reckoned, σ growing from the first evidence.
  Evidence, earliest first: ``GPS_RAW_INT``'s fix dropping below 3D after a 3D fix
  (0.4-0.6 s after the loss on ArduPilot's SITL), then ``EKF_STATUS_REPORT``'s velocity
  flags (ArduPilot drops them only after its GPS timeout, about 7 s later). Either one
  flags the horizontal axes; EKF flags saying "aided" do not clear a lost fix (they say
  so for those 7 s), a 3D fix back does. The vertical axis follows the EKF's flag alone
  (a GPS says nothing about a baro-aided vertical velocity).
- **The measurement stream is silent** (a link that drops one message type, an autopilot
  that stops sending it). Every axis is dead-reckoned from the last measurement on, and
  flagged from the first missed period: 1.5 mean intervals after the last sample
  (``FdiConfig.overdue_intervals``: a sample later than half an interval is already
  unusual on a steady stream, and a lone late one costs a record or two of a σ that is
  still σ0).

σ of a flagged axis is the dead reckoning's (``fdi_reference.sigma_dead_reckoning_mps``)
since the flag's start: for a GPS loss the autopilot's estimate drifts like ours would.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from glmav_observer.estimation.fdi_reference import sigma_dead_reckoning_mps
from glmav_observer.estimation.fdi_types import FdiConfig


@dataclass
class DriftAxes:
    """Per NED axis: unaided by the autopilot's word (GPS fix, EKF flags), since when."""

    #: the EKF's flags say horizontal / vertical unaided
    ekf_unaided: list[bool] = field(default_factory=lambda: [False, False])
    #: the GPS had a 3D fix once, and has none now
    gps_had_fix: bool = False
    gps_lost: bool = False
    #: vehicle time each axis became unaided (None: aided)
    unaided_since_s: list[float | None] = field(default_factory=lambda: [None, None, None])

    def on_ekf(self, t_s: float, horizontal: bool | None, vertical: bool | None) -> None:
        """``EKF_STATUS_REPORT``: aided (True), unaided (False), no word (None)."""
        if horizontal is not None:
            self.ekf_unaided[0] = not horizontal
        if vertical is not None:
            self.ekf_unaided[1] = not vertical
        self._update(t_s)

    def on_gps(self, t_s: float, fix_3d: bool | None) -> None:
        """``GPS_RAW_INT``: a 3D fix or not. A GPS that never had one flags nothing (a
        vehicle flown without GPS, an ROV under water since boot)."""
        if fix_3d is None:
            return
        if fix_3d:
            self.gps_had_fix = True
            self.gps_lost = False
        elif self.gps_had_fix:
            self.gps_lost = True
        self._update(t_s)

    def _update(self, t_s: float) -> None:
        horiz = self.ekf_unaided[0] or self.gps_lost
        flags = (horiz, horiz, self.ekf_unaided[1])
        since = self.unaided_since_s
        for j, unaided in enumerate(flags):
            if not unaided:
                since[j] = None
            elif since[j] is None:
                since[j] = t_s

    def unaided(self) -> list[bool]:
        """Per NED axis: unaided now."""
        return [s is not None for s in self.unaided_since_s]


def drift_sigma_ned_mps(  # noqa: PLR0917 -- the state of the three axes, in order
    cfg: FdiConfig,
    t_s: float,
    unaided_since_s: list[float | None],
    t_last_measurement_s: float | None,
    measurement_interval_s: float,
    sigma_anchor_mps: Sequence[float] = (0.0, 0.0, 0.0),
) -> list[float | None]:
    """Per NED axis, the 1σ of its drift when it rests on dead reckoning without an
    isolated fault (module docstring), else None: unaided since ``unaided_since_s[j]``,
    or every axis once the measurement is overdue (its anchor the last measurement).
    At the anchor σ is the larger of σ0 and ``sigma_anchor_mps[j]`` (the axis's residual
    scale: an autopilot's velocity is noisier than σ0 on some vehicles)."""
    anchor: list[float | None] = list(unaided_since_s)
    if (
        t_last_measurement_s is not None
        and measurement_interval_s > 0.0
        and t_s - t_last_measurement_s > cfg.overdue_intervals * measurement_interval_s
    ):
        anchor = [t_last_measurement_s if a is None else min(a, t_last_measurement_s)
                  for a in anchor]  # fmt: skip
    s0_sq = cfg.sigma_handover_mps**2
    out: list[float | None] = []
    for a, s_a in zip(anchor, sigma_anchor_mps, strict=True):
        if a is None:
            out.append(None)
            continue
        s = sigma_dead_reckoning_mps(cfg, t_s - a)
        out.append(math.sqrt(s * s - s0_sq + s_a * s_a) if s_a * s_a > s0_sq else s)
    return out
