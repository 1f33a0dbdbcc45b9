"""The one place that opens links, sessions and recordings and wires ingest -> estimation -> sinks.

In-process API (used by the commands, the demo, the benchmarks and the tests):

- :class:`Service` ``(config, sinks)``: ``feed_bytes(link_id, data, t_arrival_s)`` and
  ``feed_message(msg, t_arrival_s)`` push input through the pipeline; ``run(links,
  stop_event)`` serves open links until the event is set; ``summary()`` gives a
  :class:`ServiceSummary`; ``close()`` closes every sink (flushing files).
- :func:`replay_tlog` ``(path, config, sinks) -> ServiceSummary``: the same pipeline
  over a recorded ``.tlog``, deterministic (the vehicle's clock drives estimation; host
  time stamps of the log are used only for vehicle eviction).
- :func:`replay_flight_log` ``(path, config, sinks) -> LogReplaySummary``: the same
  estimator over an ArduPilot dataflash or PX4 ULog (:mod:`glmav_observer.ingest.logfiles`),
  with the autopilot's EKF velocity published as ``reference`` records and RMSE against it.
- :func:`open_sinks`: the sinks a configuration asks for (file, Zenoh, Rerun); the
  Zenoh and Rerun modules are imported only when enabled.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import select
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.evaluation import TRUTH_MAX_GAP_S, TruthScorer
from glmav_observer.ingest.framing import (
    FrameCounters,
    FrameDecoder,
    SigningState,
    iter_tlog,
    new_dialect,
)
from glmav_observer.ingest.links import Link
from glmav_observer.ingest.pipeline import (
    IMU_MESSAGE_IDS,
    Ingest,
    IngestEvent,
    NewVehicle,
    VehicleConflict,
    VehicleEvicted,
    VehicleReset,
)
from glmav_observer.ingest.rates import encode_rate_request
from glmav_observer.ingest.samples import Sample
from glmav_observer.publish.file_sink import FileSink
from glmav_observer.publish.sink import Sink
from glmav_observer.records import CONFIGS, HealthRecord, Record, TruthRecord, VelocityRecord

logger = logging.getLogger(__name__)

#: Messages that carry the velocity measurement (``rx_<NAME>`` counters of a vehicle).
VELOCITY_MESSAGES = ("LOCAL_POSITION_NED",)

#: How often (host seconds) the live loop checks received rates against requested ones.
RATE_CHECK_PERIOD_S = 1.0
#: Reads from one ready link per loop turn before the loop checks stop, rates and outbox.
DRAIN_MAX_READS = 256
#: At stop, datagrams already queued are read for at most this long (host seconds): the
#: stop bound of issue 18 (SIGTERM ≤ 0.5 s under any load).
STOP_DRAIN_S = 0.5


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


class Service:
    """The pipeline: bytes/messages -> ingest -> per-vehicle estimators -> sinks."""

    def __init__(self, config: ServiceConfig, sinks: Sequence[Sink] = ()) -> None:
        self.config = config
        self.sinks: list[Sink] = list(sinks)
        #: sinks isolated after a write failed: (sink class name, error)
        self.failed_sinks: list[tuple[str, str]] = []
        self.ingest = Ingest(config.ingest)
        self.estimators: dict[int, VehicleEstimator] = {}
        self._retired: dict[int, VehicleEstimator] = {}
        self.decoders: dict[str, FrameDecoder] = {}
        self.counters: collections.Counter[str] = collections.Counter()
        self.records = 0
        self.messages = 0
        #: frames to send: (link id, bytes, peer); the live loop writes them to its links
        self.outbox: list[tuple[str, bytes, Any]] = []
        self._vehicle_link: dict[int, str] = {}
        self._vehicle_peer: dict[int, Any] = {}
        #: sequence numbers of the service's own conflict health records, per vehicle
        self._conflict_seq: dict[int, int] = {}
        #: the sender address of the datagram being processed (set by the live loop)
        self.current_peer: Any = None
        #: MAVLink 2 signing freshness, shared by every link, persisted if configured
        self.signing: SigningState | None = None
        if config.signing_key is not None:
            self.signing = SigningState(config.signing_key, config.signing_state_file)
        # what we send is signed with the same key (a signed vehicle ignores the rest)
        self._mav = new_dialect(self.signing, config.signing_key)
        self._closed = False
        self.on_records: Callable[[list[Record]], None] | None = None
        self._links: dict[str, Link] = {}
        #: per vehicle: its estimates scored against truth, where truth comes (the summary)
        self._scorers: dict[int, TruthScorer] = {}

    # ------------------------------------------------------------------ input
    def decoder(self, link_id: str, *, datagram: bool = True) -> FrameDecoder:
        dec = self.decoders.get(link_id)
        if dec is None:
            dec = self.decoders[link_id] = FrameDecoder(
                datagram=datagram,
                signing_key=self.config.signing_key,
                signing_state=self.signing,
            )
            # superseded IMU frames are counted without being decoded (same counters)
            dec.set_prefilter(self.ingest.skip_superseded, IMU_MESSAGE_IDS)
        return dec

    def feed_bytes(
        self, link_id: str, data: bytes, t_arrival_s: float, *, datagram: bool = True
    ) -> int:
        """Bytes received on ``link_id`` (one datagram, or a chunk of a stream)."""
        n = 0
        dec = self.decoder(link_id, datagram=datagram)
        skipped = dec.prefiltered
        for msg in dec.feed(data, t_arrival_s):
            n += self.feed_message(msg, t_arrival_s, link_id)
        self.messages += dec.prefiltered - skipped
        return n

    def feed_message(self, msg: Any, t_arrival_s: float, link_id: str = "") -> int:
        """One decoded message; returns the number of records produced."""
        self.messages += 1
        return self._handle(self.ingest.on_message(msg, t_arrival_s), link_id)

    def _handle(self, events: list[IngestEvent], link_id: str) -> int:
        """Ingest events -> estimators -> sinks; returns the number of records produced."""
        if not events:
            return 0
        out: list[Record] = []
        for ev in events:
            if isinstance(ev, NewVehicle):
                self._new_estimator(ev.sysid, link_id)
                continue
            if isinstance(ev, VehicleEvicted):
                est = self.estimators.pop(ev.sysid, None)
                if est is not None:
                    self._retired[ev.sysid] = est
                continue
            if isinstance(ev, VehicleReset):
                self.estimators[ev.sysid].restart("clock_reset")
                continue
            if isinstance(ev, VehicleConflict):
                if ev.active:  # what was estimated may mix two sources: start afresh later
                    self.estimators[ev.sysid].restart("conflicting_sources")
                    self.counters["conflicting_sources"] += 1
                out.append(self._conflict_health(ev.sysid))
                continue
            self._vehicle_link[ev.sysid] = link_id
            self._vehicle_peer[ev.sysid] = self.current_peer
            out.extend(self._estimate(ev))
        if out:
            self._publish(out)
        return len(out)

    def _new_estimator(self, sysid: int, link_id: str) -> None:
        v = self.ingest.vehicles[sysid]
        old = self._retired.pop(sysid, None)
        est = VehicleEstimator(
            sysid, self.config.estimation, input_counters=lambda: v.counters, rates_fn=v.rates.rates
        )
        if old is not None:  # a vehicle seen again after eviction keeps its history
            est.faults, est.switches = old.faults, old.switches
        self.estimators[sysid] = est
        self._vehicle_link[sysid] = link_id
        self._vehicle_peer[sysid] = self.current_peer

    def _conflict_health(self, sysid: int) -> HealthRecord:
        """The health record that flags (or clears) conflicting sources for ``sysid``:
        ``counters.conflicting_sources_active`` is 1 while estimation is stopped."""
        v = self.ingest.vehicles[sysid]
        est = self.estimators[sysid]
        nan = math.nan
        self._conflict_seq[sysid] = self._conflict_seq.get(sysid, 0) + 1
        counters = est.all_counters()
        counters["conflicting_sources_active"] = int(v.conflict)
        return HealthRecord(
            sysid,
            v.clock.t_now_s if v.clock.t_now_s is not None else nan,
            self._conflict_seq[sysid],
            est.active_config,
            (nan, nan, nan),
            (nan, nan, nan),
            {"n": "suspect", "e": "suspect", "d": "suspect"}
            if v.conflict
            else {"n": "warmup", "e": "warmup", "d": "warmup"},
            (),
            v.rates.rates(),
            counters,
        )

    def _estimate(self, s: Sample) -> list[Record]:
        return self.estimators[s.sysid].on_sample(s)

    def _publish(self, records: list[Record]) -> None:
        self.records += len(records)
        # scored from a vehicle's first truth record on (a real vehicle has none: then
        # this costs a lookup per record)
        scorers = self._scorers
        for r in records:
            sc = scorers.get(r.sysid)
            if sc is not None:
                if type(r) is VelocityRecord:
                    sc.add_estimate(r.config, r.t_boot_s, r.v_ned_mps)
                elif type(r) is TruthRecord:
                    sc.add_truth(r.t_boot_s, r.v_ned_mps)
            elif type(r) is TruthRecord:
                sc = scorers[r.sysid] = TruthScorer(skip_s=self.config.estimation.metrics_skip_s)
                sc.add_truth(r.t_boot_s, r.v_ned_mps)
        for sink in list(self.sinks):
            try:
                for r in records:
                    sink.write(r)
            except Exception as err:  # one failing sink (a full disk) must not stop the rest
                self._sink_failed(sink, err)
        if self.on_records is not None:
            self.on_records(records)

    def _sink_failed(self, sink: Sink, err: BaseException) -> None:
        """Isolate a sink whose write raised: log, count, close it, keep the others going.

        Counted service-wide (``sink_failed``, ``sink_failed_<Sink>``) and in every
        vehicle's counters, which health records publish (``counters.sink_failed``)."""
        name = type(sink).__name__
        self.sinks.remove(sink)
        self.failed_sinks.append((name, str(err)))
        self.counters["sink_failed"] += 1
        self.counters[f"sink_failed_{name}"] += 1
        for v in self.ingest.vehicles.values():
            v.counters["sink_failed"] += 1
        logger.error("sink failed: isolated", extra={"sink": name, "error": str(err)})
        try:
            sink.close()
        except Exception as close_err:
            logger.warning("closing a failed sink", extra={"sink": name, "error": str(close_err)})

    # ------------------------------------------------------------------ rates
    def rate_requests(self, t_host_s: float) -> None:
        """Queue the SET_MESSAGE_INTERVAL requests due at host time ``t_host_s``
        (``[rates] mode = "request"``; ingest/rates.py has the policy)."""
        conflicted = [s for s, v in self.ingest.vehicles.items() if v.conflict]
        if conflicted:  # the flag stays visible while the vehicle is not estimated
            self._publish([self._conflict_health(s) for s in conflicted if s in self.estimators])
        if not self.config.request_rates:
            return
        for sysid in list(self.ingest.vehicles):
            link = self._vehicle_link.get(sysid)
            if link is None:
                continue
            reqs = self.ingest.rate_requests(sysid, t_host_s)
            if reqs:
                logger.info(
                    "rates short: requested",
                    extra={"sysid": sysid, "messages": [r.message for r in reqs]},
                )
            for r in reqs:
                self.outbox.append(
                    (link, encode_rate_request(self._mav, r), self._vehicle_peer.get(sysid))
                )
                self.counters["rate_requests_sent"] += 1

    # ------------------------------------------------------------------ live loop
    def run(
        self,
        links: dict[str, Link],
        stop_event: threading.Event,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Serve ``links`` (id -> open link) until ``stop_event`` is set.

        Descriptors are mapped to links on every turn: a TCP link that went down has none
        until its ``read`` has reconnected it.
        """
        self._links = links
        next_rate_check = clock()
        while not stop_event.is_set():
            by_fd: dict[int, tuple[str, Link]] = {}
            for lid, lk in links.items():
                fd = lk.fileno()
                if fd is None:
                    lk.read()  # down: try to reconnect (with backoff)
                else:
                    by_fd[fd] = (lid, lk)
            try:
                ready, _, _ = select.select(list(by_fd), [], [], 0.05)
            except (InterruptedError, ValueError, OSError):
                continue
            for fd in ready:
                lid, lk = by_fd[fd]
                # drain the socket, but at most DRAIN_MAX_READS reads a turn and never past
                # a stop request: a flood must not delay shutdown or the rate checks
                for _ in range(DRAIN_MAX_READS):
                    if stop_event.is_set():
                        break
                    data = lk.read()
                    if not data:
                        break
                    self.current_peer = lk.peer
                    self.feed_bytes(lid, data, clock(), datagram=lk.datagram)
                    if not lk.datagram:
                        break
            now = clock()
            if now >= next_rate_check:
                self.rate_requests(now)
                if self.signing is not None:
                    self.signing.save()
                next_rate_check = now + RATE_CHECK_PERIOD_S
            while self.outbox:
                lid, frame, peer = self.outbox.pop(0)
                if lid in links:
                    links[lid].write(frame, peer)
        self._final_drain(links, clock)

    def _final_drain(self, links: dict[str, Link], clock: Callable[[], float]) -> None:
        """At stop: what is already queued on the links is still read, for at most
        ``STOP_DRAIN_S`` (a flood cannot hold the stop back longer)."""
        deadline = time.monotonic() + STOP_DRAIN_S
        for lid, lk in links.items():
            if lk.fileno() is None:
                continue
            while time.monotonic() < deadline:
                data = lk.read()
                if not data:
                    break
                self.current_peer = lk.peer
                self.feed_bytes(lid, data, clock(), datagram=lk.datagram)

    # ------------------------------------------------------------------ results
    def summary(self) -> ServiceSummary:
        vehicles: dict[int, VehicleSummary] = {}
        for sysid, est in sorted({**self._retired, **self.estimators}.items()):
            scorer = self._scorers.get(sysid) or TruthScorer()
            scored, worst = scorer.rmse(), scorer.max_abs()
            vehicles[sysid] = VehicleSummary(
                sysid=sysid,
                rmse_ned_mps={c: scored.get(c) for c in (*CONFIGS, "active")},
                max_abs_error_ned_mps={c: worst.get(c) for c in (*CONFIGS, "active")},
                truth_samples=scorer.truth_samples,
                faults=[f.to_dict() for f in est.faults],
                switches=[s.to_dict() for s in est.switches],
                counters=est.all_counters(),
                active_config=est.active_config,
            )
        return ServiceSummary(
            vehicles=vehicles,
            link_counters={k: d.counters.as_dict() for k, d in sorted(self.decoders.items())},
            service_counters=dict(
                sorted(
                    sum(
                        (lk.counters for lk in self._links.values()),
                        self.counters + self.ingest.counters,
                    ).items()
                )
            ),
            records=self.records,
            messages=self.messages,
            failed_sinks=list(self.failed_sinks),
        )

    def close(self) -> None:
        """Close every sink once (files flushed)."""
        if self._closed:
            return
        self._closed = True
        if self.signing is not None:
            self.signing.save()
        # samples still held by the reorder buffer are estimated, not lost
        self._handle(self.ingest.flush(), "")
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as err:  # e.g. the last buffer of a file on a full disk
                name = type(sink).__name__
                self.failed_sinks.append((name, str(err)))
                self.counters["sink_failed"] += 1
                self.counters[f"sink_failed_{name}"] += 1
                logger.error("sink close failed", extra={"sink": name, "error": str(err)})


# ---------------------------------------------------------------------- replay
def replay_tlog(
    path: str | Path,
    config: ServiceConfig,
    sinks: Sequence[Sink] = (),
    *,
    progress: Callable[[int, int], None] | None = None,
    stop_event: threading.Event | None = None,
) -> ServiceSummary:
    """Run the pipeline over a ``.tlog`` (deterministic); sinks are closed at the end.

    If ``stop_event`` is set during the replay, it stops there, closes the sinks (their
    files end on whole records) and the summary's ``cut`` says where it stopped."""
    data = Path(path).read_bytes()
    service = Service(config, sinks)
    counters = FrameCounters()
    service.decoders[str(path)] = FrameDecoder(datagram=False, counters=counters)
    n = len(data)
    step = max(1, n // 200)
    next_report = 0
    cut = ""
    try:
        for rec in iter_tlog(data, counters):
            if stop_event is not None and stop_event.is_set():
                cut = f"stopped at byte {rec.offset} of {n} ({100 * rec.offset // max(n, 1)} %)"
                break
            service.feed_message(rec.msg, rec.t_host_us * 1e-6, str(path))
            if progress is not None and rec.offset >= next_report:
                progress(rec.offset, n)
                next_report = rec.offset + step
        if progress is not None and not cut:
            progress(n, n)
    finally:
        service.close()
    summary = service.summary()
    summary.cut = cut
    return summary


# ---------------------------------------------------------------------- flight logs
@dataclass
class LogReplaySummary:
    """What a flight-log replay found and produced (printed by ``replay``, tabled by ``batch``)."""

    path: str
    format: str
    vehicle: str
    duration_s: float
    rates_hz: dict[str, float]
    sources: dict[str, str]
    dropped: dict[str, int]
    velocity_source: str
    gps_delay_s: float
    gps_delay_source: str
    service: ServiceSummary
    #: per configuration (and ``active``): RMSE against the EKF velocity, m/s (n, e, d)
    rmse_vs_reference_ned_mps: dict[str, tuple[float, float, float] | None]
    reference_samples: int
    #: the log's first time stamp (s, autopilot clock)
    t_start_s: float = 0.0

    @property
    def vehicle_summary(self) -> VehicleSummary | None:
        return next(iter(self.service.vehicles.values()), None)

    def to_text(self) -> str:
        rates = ", ".join(
            f"{k} {v:.1f} Hz ({self.sources.get(k, '?')})" for k, v in self.rates_hz.items()
        )
        lines = [
            f"{self.format} log: {self.vehicle}, {self.duration_s:.1f} s",
            f"rates: {rates}",
            f"velocity measurement: {self.velocity_source}"
            + (
                f", GPS delay {self.gps_delay_s * 1e3:.0f} ms ({self.gps_delay_source})"
                if self.velocity_source == "gps"
                else ""
            ),
            f"samples {self.service.messages}, records {self.service.records}, "
            f"dropped while reading: {self.dropped or 'none'}",
        ]
        v = self.vehicle_summary
        tables = []
        if v is not None and v.truth_samples:
            tables.append((f"simulator truth ({self.sources.get('truth', '?')})", v.rmse_ned_mps))
        if self.reference_samples:
            tables.append(
                (
                    f"the EKF's velocity ({self.sources.get('ekf', '?')})",
                    self.rmse_vs_reference_ned_mps,
                )
            )
        if not tables:
            lines.append("no truth and no reference: no RMSE")
        for title, table in tables:
            lines.append(f"RMSE against {title}, m/s, NED")
            lines.append("config      north     east     down")
            for cfg, r in table.items():
                if r is not None:
                    lines.append(f"{cfg:<7} {r[0]:8.3f} {r[1]:8.3f} {r[2]:8.3f}")
        if v is not None:
            for f in v.faults:
                lines.append(
                    f"fault isolated: axis {f['axis']} ({f['kind']}) at t = {f['t_detect_s']:.3f} s"
                    f" ({f['t_detect_s'] - self.t_start_s:.1f} s into the log)"
                )
            for sw in v.switches:
                lines.append(
                    f"switch: {sw['from']} -> {sw['to']} at t = {sw['t_boot_s']:.3f} s"
                    f" ({sw['t_boot_s'] - self.t_start_s:.1f} s into the log, {sw['reason']})"
                )
            lines.append(f"active configuration at the end: {v.active_config}")
        return "\n".join(lines)


def replay_flight_log(
    path: str | Path,
    config: ServiceConfig,
    sinks: Sequence[Sink] = (),
    *,
    velocity_source: str = "gps",
    gps_delay_s: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LogReplaySummary:
    """Run the estimator over an ArduPilot dataflash or PX4 ULog; sinks are closed at the end.

    Raises :class:`~glmav_observer.ingest.logfiles.LogError` for a log it cannot read (the
    sinks are closed then too). Deterministic: the samples are sorted by time of validity.
    """
    import numpy as np

    from glmav_observer.ingest.logfiles import LOG_SYSID, VELOCITY_SOURCES, read_flight_log
    from glmav_observer.ingest.rates import RateMonitor
    from glmav_observer.ingest.samples import TruthSample
    from glmav_observer.records import ReferenceRecord

    service = Service(config, sinks)
    try:
        if velocity_source not in VELOCITY_SOURCES:
            raise ValueError(f"velocity source must be gps or ekf, got {velocity_source!r}")
        log = read_flight_log(path, velocity_source, gps_delay_s=gps_delay_s)  # type: ignore[arg-type]
        sysid = LOG_SYSID
        monitor = RateMonitor({}, window_s=config.ingest.rate_window_s)
        est = VehicleEstimator(sysid, config.estimation, rates_fn=monitor.rates)
        service.estimators[sysid] = est
        ref_source = log.streams.sources.get("ekf", "ekf")
        t_ref = log.t_reference_s.tolist()
        v_ref = log.v_reference_ned_mps.tolist()
        # the estimates against the log's own estimator (its EKF), by the definition
        # against truth (evaluation.TruthScorer), with the bracket allowed to span three
        # of the reference's intervals (an EKF output can come at 10 Hz)
        ref_dt_s = float(np.median(np.diff(t_ref))) if len(t_ref) > 1 else 0.0
        ref_err = TruthScorer(
            skip_s=config.estimation.metrics_skip_s,
            max_gap_s=max(TRUTH_MAX_GAP_S, 3.0 * ref_dt_s),
        )
        names = {"AttitudeSample": "attitude", "ImuSample": "imu", "VelocitySample": "velocity"}
        n = len(log.samples)
        step = max(1, n // 200)
        i_ref = 0

        def references_until(t: float) -> None:
            nonlocal i_ref
            out: list[Record] = []
            while i_ref < len(t_ref) and t_ref[i_ref] <= t:
                tr, vr = t_ref[i_ref], v_ref[i_ref]
                out.append(ReferenceRecord(sysid, tr, (vr[0], vr[1], vr[2]), ref_source, i_ref + 1))
                ref_err.add_truth(tr, (vr[0], vr[1], vr[2]))
                i_ref += 1
            if out:
                service._publish(out)

        for k, smp in enumerate(log.samples):
            references_until(smp.t_boot_s)
            service.messages += 1
            if not isinstance(smp, TruthSample):
                # offline: the log's time is the only clock (host time = vehicle time)
                monitor.note(names[type(smp).__name__], smp.t_boot_s, smp.t_boot_s)
            recs = est.on_sample(smp)
            for r in recs:
                if isinstance(r, VelocityRecord):
                    ref_err.add_estimate(r.config, r.t_boot_s, r.v_ned_mps)
            if recs:
                service._publish(recs)
            if progress is not None and k % step == 0:
                progress(k, n)
        references_until(float("inf"))
        if progress is not None:
            progress(n, n)
    finally:
        service.close()
    return LogReplaySummary(
        path=str(path),
        format=log.format,
        vehicle=log.vehicle,
        duration_s=log.duration_s(),
        rates_hz=log.streams.rates_hz(),
        sources=dict(log.streams.sources),
        dropped=dict(log.streams.dropped),
        velocity_source=log.velocity_source,
        gps_delay_s=log.gps_delay_s,
        gps_delay_source=log.gps_delay_source,
        service=service.summary(),
        rmse_vs_reference_ned_mps={c: ref_err.rmse().get(c) for c in (*CONFIGS, "active")},
        reference_samples=ref_err.truth_samples,
        t_start_s=log.streams.span_s()[0],
    )


# ---------------------------------------------------------------------- sinks
class OutputError(ValueError):
    """An output the user named cannot be written (the message says which and why)."""


def check_output_file(path: str | Path) -> None:
    """Refuse an output file whose directory is missing (it is not created) or that
    cannot be written (a read-only file system, no permission): :class:`OutputError`."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{p}: directory {parent} does not exist (it is not created)")
    existed = p.exists()
    try:
        with p.open("ab"):
            pass
    except OSError as err:
        raise OutputError(f"{p}: cannot write: {err.strerror}") from None
    if not existed:
        p.unlink(missing_ok=True)


def check_tcp_port_free(host: str, port: int, what: str) -> None:
    """:class:`OutputError` if another process listens on ``host:port`` (checked before a
    server that would otherwise start without it and keep running)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # ignore TIME_WAIT only
        try:
            s.bind((host, port))
        except OSError as err:
            raise OutputError(
                f"{what}: {host}:{port} is taken by another process ({err.strerror})"
            ) from None


def open_sinks(
    config: ServiceConfig,
    *,
    out: str | None = None,
    zenoh_config: str | None = None,
    zenoh_enabled: bool | None = None,
    rerun_mode: str | None = None,
    recording_name: str | None = None,
    rerun_fallback_save_path: str | None = None,
    zenoh_check_unique: bool = True,
) -> list[Sink]:
    """The sinks asked for by the config and the command line (closed by the caller).

    ``rerun_fallback_save_path``: ``--rerun spawn`` without a display saves there instead
    (None: the Rerun sink's default). ``zenoh_check_unique``: see
    :func:`~glmav_observer.publish.zenoh_sink.open_zenoh_sink`."""
    sinks: list[Sink] = []
    try:
        path = out if out is not None else config.out
        if path:
            sinks.append(FileSink(path))
        z_on = config.zenoh.enabled if zenoh_enabled is None else zenoh_enabled
        if z_on:
            from glmav_observer.publish.zenoh_sink import open_zenoh_sink

            zcfg = zenoh_config if zenoh_config is not None else (config.zenoh.config or None)
            sinks.append(
                open_zenoh_sink(
                    zcfg,
                    prefix=config.zenoh.prefix,
                    decimation=config.zenoh.decimation,
                    service_id=config.service_id,
                    effective_config=config.effective(),
                    check_unique=zenoh_check_unique,
                )
            )
        if config.mavlink_out.enabled:
            from glmav_observer.publish.mavlink_out import MavlinkOutSink

            sinks.append(MavlinkOutSink(config.mavlink_out, signing_key=config.signing_key))
        mode = rerun_mode if rerun_mode is not None else config.rerun.mode
        if mode != "off":
            from glmav_observer.publish.rerun import open_rerun_sink
            from glmav_observer.publish.rerun.viewer import (
                DEFAULT_FALLBACK_SAVE_PATH,
                DEFAULT_GRPC_PORT,
                DEFAULT_WEB_PORT,
            )

            if mode.startswith("save:"):
                check_output_file(mode.removeprefix("save:"))
            elif mode == "serve":
                for port in (DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT):
                    check_tcp_port_free(config.rerun.serve_bind, port, "--rerun serve")

            sinks.append(
                open_rerun_sink(
                    mode,
                    decimation=config.rerun.decimation,
                    serve_bind=config.rerun.serve_bind,
                    recording_name=recording_name,
                    fallback_save_path=rerun_fallback_save_path or DEFAULT_FALLBACK_SAVE_PATH,
                )
            )
    except BaseException:
        for s in sinks:
            s.close()
        raise
    return sinks


# ---------------------------------------------------------------------- serve
def serve(
    config: ServiceConfig,
    sinks: Sequence[Sink],
    links: Iterable[str],
    stop_event: threading.Event | None = None,
    *,
    service: Service | None = None,
    ready: threading.Event | None = None,
) -> ServiceSummary:
    """Open ``links``, serve until SIGINT/SIGTERM (or ``stop_event``), close everything.

    ``service``: a Service built by the caller over ``sinks`` (e.g. a claiming one).
    ``ready`` is set once every link is open (a caller in another thread may then start
    the traffic: nothing sent to a UDP port before it is bound arrives)."""
    stop = stop_event if stop_event is not None else threading.Event()
    opened: dict[str, Link] = {}
    service = service if service is not None else Service(config, sinks)
    with stop_on_signals(stop):
        try:
            for conn in links:
                opened[conn] = Link(conn, udp_receive_buffer_bytes=config.udp_receive_buffer_bytes)
                logger.info("link open", extra={"link": conn})
            if ready is not None:
                ready.set()
            service.run(opened, stop)
        finally:
            for lk in opened.values():
                lk.close()
            service.close()
    return service.summary()


@contextlib.contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """Inside: SIGINT and SIGTERM set ``stop`` (logged) instead of interrupting; the
    previous handlers come back on leaving. Only in the main thread (Python delivers
    signals there); elsewhere a no-op."""
    previous: dict[signal.Signals, Any] = {}

    def on_signal(signum: int, frame: FrameType | None) -> None:
        logger.info("stopping", extra={"signal": signal.Signals(signum).name})
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def rmse_table(summary: ServiceSummary, sysid: int) -> list[tuple[str, float, float, float]]:
    """(config, n, e, d) RMSE rows for one vehicle (NaN where no truth)."""
    v = summary.vehicles[sysid]
    rows: list[tuple[str, float, float, float]] = []
    for c in (*CONFIGS, "active"):
        r = v.rmse_ned_mps.get(c) or (math.nan, math.nan, math.nan)
        rows.append((c, r[0], r[1], r[2]))
    return rows
