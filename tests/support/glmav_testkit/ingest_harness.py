"""The service's input path, bytes to records, with an account of every message.

The same chain the daemon runs per link (``FrameDecoder`` -> ``Ingest`` -> one
``VehicleEstimator`` per admitted vehicle), driven directly so that the fuzz harness can
push a million cases through it and check, message by message, that each one was either
turned into a sample, consumed (``SYSTEM_TIME``) or rejected with a counted reason.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from glmav_observer.estimation.vehicle import EstimatorConfig, VehicleEstimator
from glmav_observer.ingest.framing import FrameCounters, FrameDecoder
from glmav_observer.ingest.pipeline import (
    Ingest,
    IngestConfig,
    NewVehicle,
    VehicleAutopilot,
    VehicleConflict,
    VehicleEvicted,
    VehicleReset,
)
from glmav_observer.records import Record, VelocityRecord


def _reasons(c: collections.Counter[str]) -> int:
    return sum(v for k, v in c.items() if not k.startswith("rx_"))


@dataclass
class Harness:
    """Bytes in, records out, per vehicle; ``outcomes`` says what became of each message."""

    datagram: bool = True
    ingest_config: IngestConfig = field(default_factory=IngestConfig)
    estimator_config: EstimatorConfig = field(default_factory=EstimatorConfig)
    keep_records: bool = True
    signing_key: bytes | None = None

    def __post_init__(self) -> None:
        self.frame_counters = FrameCounters()
        kw: dict[str, Any] = {}
        if self.signing_key is not None:
            kw["signing_key"] = self.signing_key
        self.decoder = FrameDecoder(datagram=self.datagram, counters=self.frame_counters, **kw)
        self.ingest = Ingest(self.ingest_config)
        self.estimators: dict[int, VehicleEstimator] = {}
        self.records: dict[int, list[Record]] = collections.defaultdict(list)
        self.outcomes: collections.Counter[str] = collections.Counter()
        self.n_records = 0
        self.nonfinite_velocity_records = 0
        self.resets: list[VehicleReset] = []
        self.max_vehicles_seen = 0

    def feed(self, data: bytes, t_host_s: float) -> None:
        """One datagram (or stream chunk) received at host time ``t_host_s``."""
        for msg in self.decoder.feed(data):
            self.on_message(msg, t_host_s)

    def feed_all(self, chunks: Iterable[bytes], t0_s: float = 0.0, dt_s: float = 0.001) -> None:
        for i, c in enumerate(chunks):
            self.feed(c, t0_s + i * dt_s)

    def on_message(self, msg: Any, t_host_s: float) -> None:
        ing = self.ingest
        sysid = int(msg.get_srcSystem())
        v = ing.vehicles.get(sysid)
        before = _reasons(ing.counters) + (_reasons(v.counters) if v is not None else 0)
        events = ing.on_message(msg, t_host_s)
        v = ing.vehicles.get(sysid)
        after = _reasons(ing.counters) + (_reasons(v.counters) if v is not None else 0)
        produced = False
        for ev in events:
            if isinstance(ev, NewVehicle):
                self.estimators[ev.sysid] = VehicleEstimator(ev.sysid, self.estimator_config)
            elif isinstance(ev, VehicleConflict):
                pass  # counted by the clock (conflicting_sources)
            elif isinstance(ev, VehicleAutopilot):
                self.estimators[ev.sysid].set_autopilot(ev.autopilot, ev.mav_type)
            elif isinstance(ev, VehicleEvicted):
                self.estimators.pop(ev.sysid, None)
                self.records.pop(ev.sysid, None)
            elif isinstance(ev, VehicleReset):
                self.resets.append(ev)
                self.estimators[ev.sysid].restart("clock_reset")
            else:
                produced = True
                out = self.estimators[ev.sysid].on_sample(ev)
                self.n_records += len(out)
                for r in out:
                    if isinstance(r, VelocityRecord) and not all(
                        math.isfinite(x) for x in r.v_ned_mps
                    ):
                        self.nonfinite_velocity_records += 1
                if self.keep_records:
                    self.records[ev.sysid].extend(out)
        self.max_vehicles_seen = max(self.max_vehicles_seen, len(ing.vehicles))
        if produced:
            self.outcomes["accepted"] += 1
        elif msg.get_type() == "SYSTEM_TIME" and v is not None:
            self.outcomes["consumed"] += 1
        elif after > before:
            self.outcomes["rejected"] += 1
        else:
            self.outcomes["unaccounted"] += 1

    def counts(self) -> dict[str, int]:
        """Every counter: framing, ingest-wide and summed over the admitted vehicles."""
        total: collections.Counter[str] = collections.Counter()
        total.update({f"frame.{k}": v for k, v in self.frame_counters.counts.items()})
        total.update({f"ingest.{k}": v for k, v in self.ingest.counters.items()})
        for veh in self.ingest.vehicles.values():
            total.update(
                {f"vehicle.{k}": n for k, n in veh.counters.items() if not k.startswith("rx_")}
            )
        return dict(sorted(total.items()))


def velocity_series(
    records: Iterable[Record], config: str = "full"
) -> list[tuple[float, tuple[float, float, float]]]:
    """(t_boot_s, v_ned_mps) of one configuration's velocity records."""
    return [
        (r.t_boot_s, r.v_ned_mps)
        for r in records
        if isinstance(r, VelocityRecord) and r.config == config
    ]
