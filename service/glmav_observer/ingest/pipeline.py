"""Per-vehicle ingest: decoded messages -> ordered, typed samples, one stream per vehicle.

:class:`Ingest` owns, for every vehicle (MAVLink system id) it has admitted, the clock
(:class:`~glmav_observer.ingest.clock.VehicleClock`), the counters and the rate monitor.
A vehicle is created on its first sample message (``ATTITUDE``, an IMU message,
``LOCAL_POSITION_NED``, ``SIM_STATE``) or on its first ``HEARTBEAT`` from an autopilot
(``autopilot`` not ``MAV_AUTOPILOT_INVALID``, ``type`` not ``MAV_TYPE_GCS``), so that a
vehicle streaming nothing yet (ArduPilot's default rates are 0) can be asked for its
streams; ground stations and companion computers never become vehicles. The number of vehicles is capped: a new system id beyond the cap
evicts the vehicle idle longest if it has been silent for ``evict_idle_s`` (host
time), otherwise the newcomer is dropped and counted (an unknown-sysid flood cannot
grow memory or disturb the vehicles being estimated).

When several IMU messages arrive, the best source wins (HIGHRES_IMU > SCALED_IMU >
RAW_IMU): samples from a worse source are dropped (``imu_superseded``) until the
better one has been silent for ``imu_fallback_s`` of vehicle time.
"""

from __future__ import annotations

import collections
import heapq
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from glmav_observer.ingest.clock import ACCEPT, REORDERED, RESET, ClockConfig, VehicleClock
from glmav_observer.ingest.convert import (
    SAMPLE_MESSAGES,
    TIME_NONE,
    UNTIMED_MESSAGES,
    ConversionError,
    RawImuScale,
    to_sample,
)
from glmav_observer.ingest.fastframe import FAST_MESSAGES, FastMessage
from glmav_observer.ingest.link_budget import DEFAULT_BUDGET_FRACTION
from glmav_observer.ingest.rates import RateMonitor, RateRequest
from glmav_observer.ingest.samples import ImuSample, ImuSource, Sample

logger = logging.getLogger(__name__)

_IMU_SOURCE: dict[str, ImuSource] = {
    "RAW_IMU": ImuSource.RAW_IMU,
    "SCALED_IMU": ImuSource.SCALED_IMU,
    "HIGHRES_IMU": ImuSource.HIGHRES_IMU,
}
#: The counter of each sample message received (``rx_<NAME>``), built once.
_RX_COUNTER: dict[str, str] = {name: f"rx_{name}" for name in SAMPLE_MESSAGES}


@dataclass(frozen=True, slots=True)
class VehicleReset:
    """The vehicle's clock restarted (reboot) or jumped: its estimator starts afresh."""

    sysid: int
    t_boot_s: float
    reason: str


@dataclass(frozen=True, slots=True)
class NewVehicle:
    """A system id seen for the first time (its estimator is to be created)."""

    sysid: int
    compid: int


@dataclass(frozen=True, slots=True)
class VehicleEvicted:
    """A vehicle removed to make room (idle beyond ``evict_idle_s``)."""

    sysid: int


@dataclass(frozen=True, slots=True)
class VehicleConflict:
    """Two sources seem to share this system id (``active``), or one remains again."""

    sysid: int
    active: bool


@dataclass(frozen=True, slots=True)
class RadioStatus:
    """A RADIO_STATUS (a SiK radio's, or one the autopilot relays): ``txbuf_percent`` of
    the radio's transmit buffer free (:mod:`glmav_observer.ingest.link_budget`)."""

    sysid: int
    txbuf_percent: int


@dataclass(frozen=True, slots=True)
class VehicleAutopilot:
    """The vehicle's first HEARTBEAT from its own component: which firmware (``autopilot``,
    MAV_AUTOPILOT) and vehicle type (``mav_type``, MAV_TYPE) it is."""

    sysid: int
    autopilot: int
    mav_type: int


IngestEvent = (
    Sample
    | VehicleReset
    | NewVehicle
    | VehicleEvicted
    | VehicleConflict
    | RadioStatus
    | VehicleAutopilot
)

#: MAVLink: MAV_CMD_SET_MESSAGE_INTERVAL (a COMMAND_ACK answering a rate request).
_CMD_SET_MESSAGE_INTERVAL = 511
#: the messages besides the samples, HEARTBEAT and SYSTEM_TIME whose fields
#: :meth:`Ingest._other` reads (keep the two in step: the frames of every other message
#: are framed without their fields, :attr:`Ingest.fields_of`)
OTHER_READ: frozenset[str] = frozenset({"RADIO_STATUS", "MESSAGE_INTERVAL", "COMMAND_ACK"})
#: every message whose fields an :class:`Ingest` may read, whatever its configuration (a
#: log read for a replay is framed with it: ``iter_tlog(fields_of=FIELDS_READ)``)
FIELDS_READ: frozenset[str] = SAMPLE_MESSAGES | {"HEARTBEAT", "SYSTEM_TIME"} | OTHER_READ
#: MAVLink: HEARTBEAT.autopilot of a component that is not an autopilot; type of a GCS.
MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GCS = 6


@dataclass(frozen=True, slots=True)
class IngestConfig:
    """Ingest settings (``[ingest]`` of ``configs/service.toml``)."""

    max_vehicles: int = 8
    evict_idle_s: float = 10.0
    imu_fallback_s: float = 1.0
    clock: ClockConfig = field(default_factory=ClockConfig)
    raw_imu_default: RawImuScale = field(default_factory=RawImuScale)
    raw_imu_by_sysid: Mapping[int, RawImuScale] = field(default_factory=dict)
    rates_hz: Mapping[str, float] = field(default_factory=dict)
    #: the rates the estimator needs: below them a stream is asked for (rates.py)
    rates_min_hz: Mapping[str, float] = field(default_factory=dict)
    rate_window_s: float = 2.0
    rate_retry_s: float = 5.0
    rate_retry_max_s: float = 60.0
    #: a link's capacity (B/s) when set; else its serial baud rate or its radio's
    #: RADIO_STATUS say it, or it is not limited (ingest/link_budget.py)
    link_bytes_per_s: float | None = None
    #: the share of a link's capacity the requested streams may take
    link_budget_fraction: float = DEFAULT_BUDGET_FRACTION
    #: Vehicle seconds a sample is held so that samples jittered out of order on the link
    #: are released in vehicle-time order (0: none, samples are processed on arrival).
    reorder_window_s: float = 0.0
    #: SERVO_OUTPUT_RAW as control samples (the cyclic regressors of the lost-axis aiding,
    #: ``[estimation.aero_control]``); off, it is ignored like any other message.
    control_samples: bool = False


@dataclass
class VehicleInput:
    """Ingest state of one vehicle."""

    sysid: int
    compid: int
    clock: VehicleClock
    counters: collections.Counter[str]
    rates: RateMonitor
    raw_scale: RawImuScale
    t_host_last_s: float
    imu_source: ImuSource | None = None
    imu_source_t_s: float = 0.0
    #: reorder buffer: a heap of (t_boot_s, arrival number, message name, sample)
    held: list[tuple[float, int, str, Sample]] = field(default_factory=list)
    held_count: int = 0
    newest_t_s: float | None = None
    #: samples are withheld from estimation: two sources share the system id
    conflict: bool = False
    #: host time this vehicle was last reported heard to a shared admission
    t_admission_s: float = float("-inf")
    #: its HEARTBEAT's (autopilot, type), once one came from its component
    autopilot: tuple[int, int] | None = None

    def input_counters(self) -> collections.Counter[str]:
        """What this vehicle's input counted (a bound method, not a closure: a copy of the
        service, :meth:`glmav_observer.app.Service.copy_state`, then reads its own)."""
        return self.counters


class Admission(Protocol):
    """Who else counts against ``max_vehicles`` (the other workers of one service:
    :class:`~glmav_observer.fleet.admission.SharedAdmission`). ``admit`` may take the
    slot of a vehicle of any worker idle for ``evict_idle_s`` (and says whose); ``heard``
    keeps a vehicle's slot fresh and says False when another worker took it."""

    def acquire(self, sysid: int) -> bool: ...

    def admit(
        self, sysid: int, t_host_s: float | None = None, evict_idle_s: float | None = None
    ) -> tuple[bool, int | None]: ...

    def release(self, sysid: int) -> None: ...

    def heard(self, sysid: int, t_host_s: float) -> bool: ...


class Ingest:
    """Turns decoded messages into per-vehicle samples in vehicle-time order."""

    def __init__(self, config: IngestConfig, admission: Admission | None = None) -> None:
        self.config = config
        #: ``max_vehicles`` shared with other processes (None: this ingest's alone)
        self.admission = admission
        #: the messages that become samples
        self.consumed: frozenset[str] = (
            SAMPLE_MESSAGES if config.control_samples else SAMPLE_MESSAGES - {"SERVO_OUTPUT_RAW"}
        )
        self.vehicles: dict[int, VehicleInput] = {}
        #: counters not attributable to an admitted vehicle
        self.counters: collections.Counter[str] = collections.Counter()

    def _new_vehicle(self, sysid: int, compid: int, t_host_s: float) -> VehicleInput | None:
        cfg = self.config
        shared = self.admission
        admitted, taken = (
            (True, None) if shared is None else shared.admit(sysid, t_host_s, cfg.evict_idle_s)
        )
        if taken is not None and taken in self.vehicles:  # our own idle vehicle's slot
            del self.vehicles[taken]
            self.counters["evicted"] += 1
            logger.warning("vehicle evicted", extra={"sysid": taken, "new_sysid": sysid})
        if len(self.vehicles) >= cfg.max_vehicles or not admitted:
            # the cap (of this ingest, or of the service's workers together): an idle
            # vehicle of ours makes room, else the new one is dropped
            idle = min(self.vehicles.values(), key=lambda v: v.t_host_last_s, default=None)
            if idle is None or t_host_s - idle.t_host_last_s < cfg.evict_idle_s:
                self.counters["vehicle_cap_dropped"] += 1
                if admitted and shared is not None:
                    shared.release(sysid)  # over this ingest's own cap: the slot is not used
                return None
            del self.vehicles[idle.sysid]
            self.counters["evicted"] += 1
            logger.warning("vehicle evicted", extra={"sysid": idle.sysid, "new_sysid": sysid})
            if shared is not None:
                shared.release(idle.sysid)
                if not admitted and not shared.admit(sysid, t_host_s)[0]:  # another was faster
                    self.counters["vehicle_cap_dropped"] += 1
                    return None
        counters: collections.Counter[str] = collections.Counter()
        v = VehicleInput(
            sysid=sysid,
            compid=compid,
            clock=VehicleClock(cfg.clock, counters),
            counters=counters,
            rates=RateMonitor(
                cfg.rates_hz,
                cfg.rates_min_hz,
                cfg.rate_window_s,
                cfg.rate_retry_s,
                cfg.rate_retry_max_s,
                t_registered_s=t_host_s,
            ),
            raw_scale=cfg.raw_imu_by_sysid.get(sysid, cfg.raw_imu_default),
            t_host_last_s=t_host_s,
        )
        self.vehicles[sysid] = v
        logger.info("new vehicle", extra={"sysid": sysid, "compid": compid})
        return v

    def _slot_kept(self, v: VehicleInput, t_host_s: float) -> bool:
        """With a shared admission: tell it the vehicle is heard (at most every half
        ``evict_idle_s``, and at once after a silence that long), and whether its slot is
        still its own: another worker takes the slot of a vehicle idle for
        ``evict_idle_s``, as one process evicts it for a newcomer."""
        shared = self.admission
        if shared is None:
            return True
        period = min(1.0, 0.5 * self.config.evict_idle_s)
        if t_host_s - v.t_admission_s < period and t_host_s - v.t_host_last_s < period:
            return True
        v.t_admission_s = t_host_s
        return shared.heard(v.sysid, t_host_s)

    def _slot_lost(self, sysid: int) -> list[IngestEvent]:
        """The vehicle's slot went to another worker's newcomer while it was idle: it is
        evicted here too (and comes back as a new vehicle if a slot is free)."""
        del self.vehicles[sysid]
        self.counters["evicted"] += 1
        logger.warning("vehicle evicted: its slot went to another worker's vehicle",
                       extra={"sysid": sysid})  # fmt: skip
        return [VehicleEvicted(sysid)]

    def on_message(self, msg: Any, t_host_s: float) -> list[IngestEvent]:
        """One message that arrived at host time ``t_host_s``, as :class:`~glmav_observer.
        ingest.framing.FrameDecoder` and ``iter_tlog`` decode it (the high-rate messages
        are :class:`~glmav_observer.ingest.fastframe.FastMessage`); the events it causes."""
        name: str = msg.get_type()
        sysid: int = msg.get_srcSystem()
        v = self.vehicles.get(sysid)
        if name == "SYSTEM_TIME" and v is not None:
            v.clock.note_system_time(int(msg.time_unix_usec), int(msg.time_boot_ms))
            return []
        if name == "HEARTBEAT":
            return self._heartbeat(msg, sysid, v, t_host_s)
        if name not in self.consumed:
            return self._other(name, msg, v)
        events: list[IngestEvent] = []
        compid: int = msg.get_srcComponent()
        if v is not None and compid == v.compid and not self._slot_kept(v, t_host_s):
            events = self._slot_lost(sysid)
            v = None
        if v is None:
            before = set(self.vehicles)
            v = self._new_vehicle(sysid, compid, t_host_s)
            events.extend(VehicleEvicted(s) for s in before - set(self.vehicles))
            if v is None:
                return events
            events.append(NewVehicle(sysid, compid))
        elif compid != v.compid:
            v.counters["other_component"] += 1
            return events
        v.t_host_last_s = t_host_s
        v.counters[_RX_COUNTER[name]] += 1
        fast = isinstance(msg, FastMessage)
        if fast:
            t_s = v.clock.to_boot_s(msg.t_us, msg.time_kind, t_host_s)
        elif name in FAST_MESSAGES:  # a caller's bug, not bad input: say it loudly
            raise TypeError(f"{name} must come from FrameDecoder or iter_tlog (fastframe)")
        else:  # the low-rate samples carry no usable vehicle time (UNTIMED_MESSAGES)
            t_s = v.clock.to_boot_s(0, TIME_NONE, t_host_s)
        if t_s is None:
            return events
        src = _IMU_SOURCE.get(name)
        if (
            src is not None
            and v.imu_source is not None
            and src < v.imu_source
            and t_s - v.imu_source_t_s <= self.config.imu_fallback_s
        ):
            v.counters["imu_superseded"] += 1  # a better IMU message is streaming: not decoded
            return events
        try:  # a sample that cannot be used never touches the vehicle's clock
            sample = msg.sample(t_s, v.raw_scale) if fast else to_sample(msg, t_s, v.raw_scale)
        except ConversionError as err:
            v.counters[err.reason] += 1
            logger.debug("sample rejected", extra={"sysid": sysid, "reason": err.reason})
            return events
        window = self.config.reorder_window_s
        if window <= 0.0:
            self._admit(v, name, t_s, sample, events)
            return events
        clk = self.config.clock
        newest = v.newest_t_s
        if newest is not None and not (
            newest - clk.reset_backwards_s <= t_s <= newest + clk.confirm_forward_s
        ):
            # far off the timeline (a reboot, an outage or a corrupt stamp): no reordering
            # across it; release what is held, then let the clock decide about this sample
            self._release(v, math.inf, events)
            self._admit(v, name, t_s, sample, events)
            v.newest_t_s = v.clock.t_now_s  # the clock's timeline: the new one if adopted
            return events
        v.newest_t_s = t_s if newest is None else max(newest, t_s)
        heapq.heappush(v.held, (t_s, v.held_count, name, sample))
        v.held_count += 1
        self._release(v, v.newest_t_s - window, events)
        return events

    @property
    def fields_of(self) -> frozenset[str]:
        """The messages whose fields :meth:`on_message` reads (the samples', HEARTBEAT,
        SYSTEM_TIME and :data:`OTHER_READ`); of every other message only the header
        (``FrameDecoder(fields_of=...)`` then skips pymavlink's decode of them)."""
        return self.consumed | {"HEARTBEAT", "SYSTEM_TIME"} | OTHER_READ

    def _other(self, name: str, msg: Any, v: VehicleInput | None) -> list[IngestEvent]:
        """A message that is not a sample: the answers to the rate requests, a radio's
        status; the rest is ignored (counted)."""
        if name == "RADIO_STATUS":
            return [RadioStatus(int(msg.get_srcSystem()), int(msg.txbuf))]
        if v is not None and int(msg.get_srcComponent()) == v.compid:
            if name == "MESSAGE_INTERVAL":
                v.rates.note_interval(int(msg.message_id), int(msg.interval_us))
                v.counters["message_interval"] += 1
                return []
            if name == "COMMAND_ACK" and int(msg.command) == _CMD_SET_MESSAGE_INTERVAL:
                v.counters["rate_request_acks"] += 1
                return []
        self.counters["ignored_messages"] += 1
        return []

    def _heartbeat(
        self, msg: Any, sysid: int, v: VehicleInput | None, t_host_s: float
    ) -> list[IngestEvent]:
        """A HEARTBEAT: registers an autopilot not seen yet (to ask it for its streams)."""
        if int(msg.autopilot) == MAV_AUTOPILOT_INVALID or int(msg.type) == MAV_TYPE_GCS:
            self.counters["ignored_messages"] += 1
            return []
        compid = int(msg.get_srcComponent())
        lost: list[IngestEvent] = []
        if v is not None and compid == v.compid and not self._slot_kept(v, t_host_s):
            lost = self._slot_lost(sysid)
            v = None
        if v is not None:
            if compid == v.compid:
                v.t_host_last_s = t_host_s
                v.counters["heartbeat"] += 1
                return self._autopilot(v, msg, [])
            self.counters["ignored_messages"] += 1
            return []
        before = set(self.vehicles)
        v = self._new_vehicle(sysid, compid, t_host_s)
        events: list[IngestEvent] = lost + [VehicleEvicted(s) for s in before - set(self.vehicles)]
        if v is None:
            return events
        v.counters["heartbeat"] += 1
        events.append(NewVehicle(sysid, compid))
        return self._autopilot(v, msg, events)

    @staticmethod
    def _autopilot(v: VehicleInput, msg: Any, events: list[IngestEvent]) -> list[IngestEvent]:
        """The firmware and type of the vehicle's first HEARTBEAT, told once."""
        if v.autopilot is None:
            v.autopilot = (int(msg.autopilot), int(msg.type))
            events.append(VehicleAutopilot(v.sysid, *v.autopilot))
        return events

    def _release(self, v: VehicleInput, t_max_s: float, events: list[IngestEvent]) -> None:
        """Admit the held samples up to vehicle time ``t_max_s``, oldest first."""
        held = v.held
        while held and held[0][0] <= t_max_s:
            t_s, _, name, sample = heapq.heappop(held)
            self._admit(v, name, t_s, sample, events)

    def flush(self) -> list[IngestEvent]:
        """Release every held sample (at the end of a log, or when the service stops)."""
        events: list[IngestEvent] = []
        for v in self.vehicles.values():
            self._release(v, math.inf, events)
        return events

    def _admit(
        self, v: VehicleInput, name: str, t_s: float, sample: Sample, events: list[IngestEvent]
    ) -> None:
        """The vehicle's clock decides; an admitted sample is appended to ``events``."""
        if name not in UNTIMED_MESSAGES:
            adm = v.clock.admit(name, t_s, v.t_host_last_s)
            if v.clock.conflicting != v.conflict:
                v.conflict = v.clock.conflicting
                events.append(VehicleConflict(v.sysid, v.conflict))
                logger.warning(
                    "conflicting sources: estimation stopped"
                    if v.conflict
                    else "one source remains: estimation resumes",
                    extra={"sysid": v.sysid},
                )
            if adm is RESET and not v.conflict:
                events.append(VehicleReset(v.sysid, t_s, "clock_reset"))
                v.imu_source = None
            elif adm is not ACCEPT and adm is not REORDERED:
                return
        if v.conflict:
            v.counters["conflicting_sources_dropped"] += 1
            return
        if isinstance(sample, ImuSample) and not self._imu_wanted(v, sample):
            return
        v.rates.note(name, t_s, v.t_host_last_s)
        events.append(sample)

    def _imu_wanted(self, v: VehicleInput, s: ImuSample) -> bool:
        best = v.imu_source
        if (
            best is None
            or s.source >= best
            or s.t_boot_s - v.imu_source_t_s > self.config.imu_fallback_s
        ):
            if best is not None and s.source != best:
                logger.info(
                    "IMU source changed",
                    extra={"sysid": v.sysid, "from": best.name, "to": s.source.name},
                )
            v.imu_source = s.source
            v.imu_source_t_s = s.t_boot_s
            return True
        v.counters["imu_superseded"] += 1
        return False

    def rate_requests(self, sysid: int, t_host_s: float) -> list[RateRequest]:
        """SET_MESSAGE_INTERVAL requests due for ``sysid`` at host time ``t_host_s`` (counted
        by :meth:`rate_sent` once sent)."""
        v = self.vehicles.get(sysid)
        if v is None:
            return []
        return v.rates.due_requests(sysid, v.compid, t_host_s)

    def rate_sent(self, req: RateRequest, t_host_s: float) -> None:
        """``req`` was written on a live link: counted, and its next check scheduled."""
        v = self.vehicles.get(req.sysid)
        if v is None:
            return
        v.rates.sent(req, t_host_s)
        v.counters["rate_requests"] += 1
        if v.rates.asked(req.message) > 1:
            v.counters["rate_rerequest"] += 1
