"""What a run of the service produced, per vehicle and overall (:class:`ServiceSummary`,
returned by :meth:`glmav_observer.app.Service.summary`), and its text for ``replay``,
``serve`` and the demo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from glmav_observer.records import CONFIGS

#: Messages that carry the velocity measurement (``rx_<NAME>`` counters of a vehicle).
VELOCITY_MESSAGES = ("LOCAL_POSITION_NED",)


@dataclass
class VehicleSummary:
    """What one vehicle's estimation produced (for the demo table and replay's summary)."""

    sysid: int
    rmse_ned_mps: dict[str, tuple[float, float, float] | None]
    max_abs_error_ned_mps: dict[str, tuple[float, float, float] | None]
    truth_samples: int
    faults: list[dict[str, Any]]
    switches: list[dict[str, Any]]
    counters: dict[str, int]
    active_config: str


@dataclass
class ServiceSummary:
    """Per vehicle results plus link and service counters."""

    vehicles: dict[int, VehicleSummary]
    link_counters: dict[str, dict[str, int]]
    service_counters: dict[str, int]
    records: int
    messages: int
    #: sinks that failed and were isolated: (sink class name, error)
    failed_sinks: list[tuple[str, str]] = field(default_factory=list)
    #: a replay stopped before the end of its log: where ("" = it ran to the end)
    cut: str = ""

    @property
    def rejected_frames(self) -> int:
        return sum(
            c.get("bad_crc", 0) + c.get("bad_header", 0) + c.get("truncated", 0)
            for c in self.link_counters.values()
        )

    def to_text(self) -> str:
        """A short human summary (printed by ``replay`` and ``serve`` at exit)."""
        lines = [
            f"messages {self.messages}, records {self.records}, "
            f"rejected frames {self.rejected_frames}"
        ]
        if self.cut:
            lines.append(f"CUT SHORT: {self.cut}: the output covers only the log up to there")
        for sink, err in self.failed_sinks:
            lines.append(f"SINK FAILED: {sink}: {err}")
        for name, c in self.link_counters.items():
            lines.append(f"link {name}: " + ", ".join(f"{k}={v}" for k, v in c.items()))
        if self.service_counters:
            lines.append(
                "service: " + ", ".join(f"{k}={v}" for k, v in self.service_counters.items())
            )
        for sysid, v in sorted(self.vehicles.items()):
            lines.append(f"vehicle {sysid}: active={v.active_config}")
            if not any(v.counters.get(f"rx_{m}", 0) for m in VELOCITY_MESSAGES):
                lines.append(
                    "  no velocity measurement received (LOCAL_POSITION_NED): every estimate is "
                    "dead reckoning from the IMU, and fault detection never ran"
                )
            if v.counters.get("fdi_off_imu_too_slow", 0):
                lines.append(
                    f"  fault detection off for {v.counters['fdi_off_imu_too_slow']} velocity "
                    "samples: the IMU stream was below [fdi] min_imu_rate_hz (only dropout "
                    "and freeze were tested)"
                )
            if v.truth_samples:
                lines.append(f"  RMSE vs SIM_STATE (n, e, d) m/s over {v.truth_samples} samples:")
                for cfg, r in v.rmse_ned_mps.items():
                    if r is not None:
                        lines.append(f"    {cfg:<7} {r[0]:8.4f} {r[1]:8.4f} {r[2]:8.4f}")
            else:
                lines.append("  no SIM_STATE truth: no RMSE")
            for f in v.faults:
                lines.append(
                    f"  fault isolated: axis {f['axis']} ({f['kind']}) at t = {f['t_detect_s']:.3f} s"
                )
            for s in v.switches:
                jump = "n/a" if s.get("jump_mps") is None else f"{s['jump_mps']:.3f} m/s"
                lines.append(
                    f"  switch: {s['from']} -> {s['to']} at t = {s['t_boot_s']:.3f} s "
                    f"({s['reason']}), jump {jump}"
                )
            dropped = {
                k: n
                for k, n in v.counters.items()
                if k
                in (
                    "late",
                    "duplicate",
                    "reordered",
                    "time_backwards",
                    "time_jump",
                    "clock_reset",
                    "nan_field",
                    "imu_absent",
                    "gap",
                    "other_component",
                )
            }
            shown = ", ".join(f"{k}={n}" for k, n in dropped.items()) or "none"
            lines.append(f"  samples dropped/flagged: {shown}")
        return "\n".join(lines)


def rmse_table(summary: ServiceSummary, sysid: int) -> list[tuple[str, float, float, float]]:
    """(config, n, e, d) RMSE rows for one vehicle (NaN where no truth)."""
    v = summary.vehicles[sysid]
    rows: list[tuple[str, float, float, float]] = []
    for c in (*CONFIGS, "active"):
        r = v.rmse_ned_mps.get(c) or (math.nan, math.nan, math.nan)
        rows.append((c, r[0], r[1], r[2]))
    return rows
