"""The one place that opens links, sessions and recordings and wires ingest -> estimation -> sinks.

In-process API (used by the commands, the demo, the benchmarks and the tests):

- :class:`Service` ``(config, sinks)``: ``feed_bytes(link_id, data, t_arrival_s)`` and
  ``feed_message(msg, t_arrival_s)`` push input through the pipeline; ``run(links,
  stop_event)`` serves open links until the event is set; ``summary()`` gives a
  :class:`~glmav_observer.app_summary.ServiceSummary`; ``close()`` closes every sink
  (flushing files).
- :func:`serve`: open links and serve them until SIGINT/SIGTERM/SIGHUP.

Its parts, one module each: :mod:`glmav_observer.app_sinks` (the sinks a configuration asks
for), :mod:`glmav_observer.app_replay` (``.tlog`` and flight-log replays through the
service) and :mod:`glmav_observer.app_summary` (what a run produced, as text).
"""

from __future__ import annotations

import collections
import contextlib
import copy
import dataclasses
import logging
import math
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from types import FrameType
from typing import Any

from glmav_observer.app_summary import ServiceSummary, VehicleSummary
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.evaluation import TruthScorer
from glmav_observer.ingest.framing import (
    FrameDecoder,
    SigningState,
    new_dialect,
)
from glmav_observer.ingest.link_budget import LinkCapacity, fit_rates
from glmav_observer.ingest.links import (
    KERNEL_DROPS_COUNTER,
    UDP_DRAIN_BATCH,
    KernelDrops,
    Link,
)
from glmav_observer.ingest.pipeline import (
    Admission,
    Ingest,
    IngestEvent,
    NewVehicle,
    RadioStatus,
    VehicleAutopilot,
    VehicleConflict,
    VehicleEvicted,
    VehicleReset,
)
from glmav_observer.ingest.rates import encode_interval_query, encode_rate_request
from glmav_observer.publish.sink import Sink
from glmav_observer.reads import (
    READS_ALL,
    READS_NONE,
    Reads,
    ReadsGate,
    reads_of,
)
from glmav_observer.records import CONFIGS, HealthRecord, Record
from glmav_observer.stop import set_from_signal_handler

logger = logging.getLogger(__name__)

#: The ingest events about a vehicle rather than a sample of it.
_VEHICLE_EVENTS = (
    NewVehicle,
    VehicleEvicted,
    VehicleReset,
    VehicleConflict,
    RadioStatus,
    VehicleAutopilot,
)
#: How often (host seconds) the live loop checks received rates against requested ones.
RATE_CHECK_PERIOD_S = 1.0
#: Reads from one ready link per loop turn before the loop checks stop, rates and outbox.
DRAIN_MAX_READS = 256
#: At stop, datagrams already queued are read for at most this long (host seconds): the
#: stop bound of issue 18 (SIGTERM ≤ 0.5 s under any load).
STOP_DRAIN_S = 0.5
#: At stop, after the streams are set back to their intervals before the service, how long
#: (host seconds) it waits for the vehicles' COMMAND_ACKs before closing the links (a TCP
#: link closed with unread bytes is reset, which may drop what was not sent yet).
RESTORE_WAIT_S = 0.3


class Service:
    """The pipeline: bytes/messages -> ingest -> per-vehicle estimators -> sinks."""

    def __init__(
        self,
        config: ServiceConfig,
        sinks: Sequence[Sink] = (),
        *,
        admission: Admission | None = None,
    ) -> None:
        """``admission``: ``max_vehicles`` shared with the other workers of one service
        (:class:`~glmav_observer.fleet.admission.SharedAdmission`)."""
        self.config = config
        self.sinks: list[Sink] = list(sinks)
        #: sinks isolated after a write failed: (sink class name, error)
        self.failed_sinks: list[tuple[str, str]] = []
        # control samples only for the cyclic regressors that use them (else ignored)
        control = config.estimation.aero_control is not None
        self.ingest = Ingest(dataclasses.replace(config.ingest, control_samples=control), admission)
        self.estimators: dict[int, VehicleEstimator] = {}
        self._retired: dict[int, VehicleEstimator] = {}
        self.decoders: dict[str, FrameDecoder] = {}
        self.counters: collections.Counter[str] = collections.Counter()
        #: datagrams the kernel dropped on the UDP links this service reads (it fell behind)
        self.kernel_drops = KernelDrops()
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
        #: ... and its arrival (time.monotonic's clock; the kernel's receive stamp where the
        #: link has one: ``Link.arrival_s``), for a caller measuring latency
        self.current_arrival_s: float = math.nan
        #: MAVLink 2 signing freshness, shared by every link, persisted if configured
        self.signing: SigningState | None = None
        if config.signing_key is not None:
            self.signing = SigningState(config.signing_key, config.signing_state_file)
        # what we send is signed with the same key (a signed vehicle ignores the rest)
        self._mav = new_dialect(self.signing, config.signing_key)
        self._closed = False
        self._on_records: Callable[[list[Record]], None] | None = None
        self._links: dict[str, Link] = {}
        #: per live link: its capacity (ingest/link_budget.py)
        self._capacity: dict[str, LinkCapacity] = {}
        #: the rate requests are checked at the next loop turn (a reboot, a reconnect)
        self._rates_now = False
        #: what the estimators build (the union of the sinks' reads) and, per sink that
        #: reads less, the gate that hands it only its own (glmav_observer.reads)
        self.built: Reads = READS_ALL
        self._gates: dict[int, ReadsGate] = {}
        self._update_reads()

    # ------------------------------------------------------------------ outputs
    def _update_reads(self) -> None:
        """What the estimators build: the union of what the sinks read (a sink that does
        not say reads everything; so does the ``on_records`` hook). A sink reading less is
        gated. The summary's scoring against truth reads no record: each estimator feeds
        its own :class:`~glmav_observer.evaluation.TruthScorer` (``score_truth``)."""
        #: sinks told of each configuration switch at its own time (``switch_at``)
        self._switch_sinks: list[Any] = [s for s in self.sinks if hasattr(s, "switch_at")]
        built = READS_NONE
        for sink in self.sinks:
            built = built.union(reads_of(sink))
        if self._on_records is not None:
            built = READS_ALL
        self._gates = {
            id(sink): ReadsGate(r, built)
            for sink in self.sinks
            if not (r := reads_of(sink)).covers(built)
        }
        if built != self.built:
            self.built = built
            for est in self.estimators.values():
                est.out.set_reads(built)

    @property
    def on_records(self) -> Callable[[list[Record]], None] | None:
        """Called with every record built, after the sinks (a hook reads every record)."""
        return self._on_records

    @on_records.setter
    def on_records(self, hook: Callable[[list[Record]], None] | None) -> None:
        self._on_records = hook
        self._update_reads()

    # ------------------------------------------------------------------ input
    def decoder(self, link_id: str, *, datagram: bool = True) -> FrameDecoder:
        dec = self.decoders.get(link_id)
        if dec is None:
            dec = self.decoders[link_id] = FrameDecoder(
                datagram=datagram,
                signing_key=self.config.signing_key,
                signing_state=self.signing,
                fields_of=self.ingest.fields_of,  # the rest framed, CRC-checked, not decoded
            )
        return dec

    def feed_bytes(
        self, link_id: str, data: bytes, t_arrival_s: float, *, datagram: bool = True
    ) -> int:
        """Bytes received on ``link_id`` (one datagram, or a chunk of a stream)."""
        n = 0
        cap = self._capacity.get(link_id)
        if cap is not None:
            cap.rx_bytes += len(data)
        for msg in self.decoder(link_id, datagram=datagram).feed(data):
            n += self.feed_message(msg, t_arrival_s, link_id)
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
            if not isinstance(ev, _VEHICLE_EVENTS):  # a sample: the common case
                self._vehicle_link[ev.sysid] = link_id
                self._vehicle_peer[ev.sysid] = self.current_peer
                vest = self.estimators[ev.sysid]
                if not self._switch_sinks:
                    out.extend(vest.on_sample(ev))
                    continue
                n_switches = len(vest.switches)
                out.extend(vest.on_sample(ev))
                for sw in vest.switches[n_switches:]:  # told before the records that follow
                    for sink in self._switch_sinks:
                        sink.switch_at(ev.sysid, sw.t_boot_s)
                continue
            if isinstance(ev, NewVehicle):
                self._new_estimator(ev.sysid, link_id)
                continue
            if isinstance(ev, VehicleAutopilot):
                self.estimators[ev.sysid].set_autopilot(ev.autopilot, ev.mav_type)
                continue
            if isinstance(ev, VehicleEvicted):
                est = self.estimators.pop(ev.sysid, None)
                if est is not None:
                    self._retired[ev.sysid] = est
                continue
            if isinstance(ev, VehicleReset):
                self.estimators[ev.sysid].restart("clock_reset")
                self._renew_rates(ev.sysid)  # a reboot: the intervals set are lost
                continue
            if isinstance(ev, RadioStatus):
                cap = self._capacity.get(link_id)
                if (
                    cap is not None
                    and cap.fixed is None
                    and cap.radio_status(ev.txbuf_percent, time.monotonic())
                ):
                    logger.info(
                        "radio full: stream rates fitted to it",
                        extra={"link": link_id, "bytes_per_s": cap.bytes_per_s},
                    )
                    self._rates_now = True
                continue
            if isinstance(ev, VehicleConflict):
                if ev.active:  # what was estimated may mix two sources: start afresh later
                    self.estimators[ev.sysid].restart("conflicting_sources")
                    self.counters["conflicting_sources"] += 1
                out.append(self._conflict_health(ev.sysid))
        if out:
            self._publish(out)
        return len(out)

    def _new_estimator(self, sysid: int, link_id: str) -> None:
        v = self.ingest.vehicles[sysid]
        old = self._retired.pop(sysid, None)
        est = VehicleEstimator(
            sysid,
            self.config.estimation,
            input_counters=v.input_counters,
            rates_fn=v.rates.rates,
            reads=self.built,
            score_truth=True,
        )
        if old is not None:  # a vehicle seen again after eviction keeps its history
            est.faults, est.switches = old.faults, old.switches
            est.scorer = old.scorer  # and its score so far
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

    def _publish(self, records: list[Record]) -> None:
        self.records += len(records)
        gates = self._gates
        for sink in list(self.sinks):
            try:
                gate = gates.get(id(sink))
                if gate is None:
                    for r in records:
                        sink.write(r)
                else:
                    admit = gate.admit
                    for r in records:
                        if admit(r):
                            sink.write(r)
            except Exception as err:  # one failing sink (a full disk) must not stop the rest
                self._sink_failed(sink, err)
        if self._on_records is not None:
            self._on_records(records)

    def _sink_failed(self, sink: Sink, err: BaseException) -> None:
        """Isolate a sink whose write raised: log, count, close it, keep the others going.

        Counted service-wide (``sink_failed``, ``sink_failed_<Sink>``) and in every
        vehicle's counters, which health records publish (``counters.sink_failed``)."""
        name = type(sink).__name__
        self.sinks.remove(sink)
        self._update_reads()
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
            link_id = self._vehicle_link.get(sysid)
            if link_id is None:
                continue
            lk = self._links.get(link_id)
            if lk is not None and lk.down:
                continue  # nothing can be sent: nothing is due, no back-off grows
            self._plan_rates(sysid, link_id)
            reqs = self.ingest.rate_requests(sysid, t_host_s)
            if reqs:
                logger.info(
                    "rates short: requested",
                    extra={"sysid": sysid, "messages": [r.message for r in reqs]},
                )
            peer = self._vehicle_peer.get(sysid)
            v = self.ingest.vehicles[sysid]
            for r in reqs:
                frames = []
                if v.rates.query_due(r.message):  # its interval before ours, asked first
                    # (and packed first: signed frames' timestamps must increase in order)
                    frames.append(encode_interval_query(self._mav, sysid, r.compid, r.message))
                frames.append(encode_rate_request(self._mav, r))
                if lk is None:  # no live loop (a fleet worker): its owner sends the outbox
                    self.outbox.extend((link_id, f, peer) for f in frames)
                elif not all(lk.write(f, peer) for f in frames):
                    continue  # not sent: not counted, due again at the next check
                self.ingest.rate_sent(r, t_host_s)
                self.counters["rate_requests_sent"] += 1

    def _plan_rates(self, sysid: int, link_id: str) -> None:
        """The rates vehicle ``sysid`` is asked for: what fits its link's budget, shared by
        the vehicles on the link (ingest/link_budget.py), or the configured ones."""
        cfg = self.config.ingest
        cap = self._capacity.get(link_id)
        if cap is None:  # a link this service does not hold (a worker's): its name says
            cap = self._capacity[link_id] = LinkCapacity(link_id, cfg.link_bytes_per_s)
        if cap.bytes_per_s is None:
            return
        n = sum(1 for lid in self._vehicle_link.values() if lid == link_id)
        budget = cfg.link_budget_fraction * cap.bytes_per_s / max(n, 1)
        plan = fit_rates(
            cfg.rates_hz, cfg.rates_min_hz, budget, signed=self.config.signing_key is not None
        )
        self.ingest.vehicles[sysid].rates.set_plan(plan, cfg.rates_min_hz)

    def _renew_rates(self, sysid: int) -> None:
        """Vehicle ``sysid`` lost the intervals the service set: asked again at once."""
        v = self.ingest.vehicles.get(sysid)
        if v is not None and self.config.request_rates and v.rates.renew(time.monotonic()):
            self.counters["rate_renewals"] += 1
            self._rates_now = True

    def restore_rates(self, links: dict[str, Link], clock: Callable[[], float]) -> int:
        """Set every stream the service changed back to its interval before (at stop, on
        the links still up); waits up to ``RESTORE_WAIT_S`` for the acknowledgements.
        Returns the requests sent."""
        if not self.config.request_rates:
            return 0
        sent = 0
        acks_before = 0
        for sysid, v in self.ingest.vehicles.items():
            lk = links.get(self._vehicle_link.get(sysid, ""))
            if lk is None or lk.down:
                continue
            acks_before += v.counters["rate_request_acks"]
            for r in v.rates.restore_requests(sysid, v.compid):
                if lk.write(encode_rate_request(self._mav, r), self._vehicle_peer.get(sysid)):
                    sent += 1
        self.counters["rate_restores_sent"] += sent
        if sent:
            logger.info("stream rates restored", extra={"requests": sent})
        deadline = time.monotonic() + RESTORE_WAIT_S
        while sent and time.monotonic() < deadline:
            acks = sum(v.counters["rate_request_acks"] for v in self.ingest.vehicles.values())
            if acks - acks_before >= sent:
                break
            got = False
            for lid, lk in links.items():
                if lk.fileno() is None:
                    continue
                data = lk.read()
                if data:
                    got = True
                    self.current_peer = lk.peer
                    self.feed_bytes(lid, data, clock(), datagram=lk.datagram)
            if not got:
                time.sleep(0.005)
        return sent

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
        cfg = self.config.ingest
        self._capacity = {
            lid: LinkCapacity(lk.conn, cfg.link_bytes_per_s) for lid, lk in links.items()
        }
        reconnects = {lid: lk.counters["tcp_reconnects"] for lid, lk in links.items()}
        next_rate_check = clock()
        while not stop_event.is_set():
            by_fd: dict[int, tuple[str, Link]] = {}
            for lid, lk in links.items():
                fd = lk.fileno()
                if fd is None:
                    lk.read()  # down: try to reconnect (with backoff)
                    if lk.counters["tcp_reconnects"] != reconnects[lid]:
                        reconnects[lid] = lk.counters["tcp_reconnects"]
                        for sysid, vl in list(self._vehicle_link.items()):
                            if vl == lid:
                                self._renew_rates(sysid)
                else:
                    by_fd[fd] = (lid, lk)
            try:
                ready, _, _ = select.select(list(by_fd), [], [], 0.05)
            except (InterruptedError, ValueError, OSError):
                continue
            for fd in ready:
                lid, lk = by_fd[fd]
                if lk.datagram:
                    # drain the socket, but at most DRAIN_MAX_READS reads a turn and never
                    # past a stop request: a flood must not delay shutdown or rate checks
                    self._drain_datagrams(lid, lk, stop_event, clock)
                    continue
                if stop_event.is_set():
                    continue
                data = lk.read()  # a stream: one read takes what is buffered
                if data:
                    self.current_peer = lk.peer
                    self.current_arrival_s = lk.arrival_s
                    self.feed_bytes(lid, data, clock(), datagram=False)
            now = clock()
            if now >= next_rate_check or self._rates_now:
                self._rates_now = False
                self.kernel_drops.check(links)
                self.rate_requests(now)
                if self.signing is not None:
                    self.signing.save()
                next_rate_check = now + RATE_CHECK_PERIOD_S
            while self.outbox:
                lid, frame, peer = self.outbox.pop(0)
                if lid in links:
                    links[lid].write(frame, peer)
        self._final_drain(links, clock)
        self.restore_rates(links, clock)
        self.kernel_drops.check(links)

    def _drain_datagrams(
        self,
        lid: str,
        lk: Link,
        stop_event: threading.Event | None,
        clock: Callable[[], float],
        *,
        max_reads: int = DRAIN_MAX_READS,
        deadline: float = math.inf,
    ) -> None:
        """Read and feed up to ``max_reads`` datagrams of a UDP link, ``UDP_DRAIN_BATCH``
        a system call; between two batches, stop at a stop request or past ``deadline``
        (``time.monotonic``). A batch read is fed whole: nothing read is lost."""
        left = max_reads
        while left > 0 and not (stop_event is not None and stop_event.is_set()):
            if deadline < math.inf and time.monotonic() >= deadline:
                break
            want = min(left, UDP_DRAIN_BATCH)
            got = lk.read_datagrams(want)
            for data, arrival_s, peer in got:
                if data:
                    self.current_peer = peer
                    self.current_arrival_s = arrival_s
                    self.feed_bytes(lid, data, clock(), datagram=True)
            left -= len(got)
            if len(got) < want:
                break  # the socket is empty

    def _final_drain(self, links: dict[str, Link], clock: Callable[[], float]) -> None:
        """At stop: what is already queued on the links is still read, for at most
        ``STOP_DRAIN_S`` (a flood cannot hold the stop back longer)."""
        deadline = time.monotonic() + STOP_DRAIN_S
        for lid, lk in links.items():
            if lk.fileno() is None:
                continue
            if lk.datagram:
                self._drain_datagrams(
                    lid, lk, None, clock, max_reads=sys.maxsize, deadline=deadline
                )
                continue
            while time.monotonic() < deadline:
                data = lk.read()
                if not data:
                    break
                self.current_peer = lk.peer
                self.current_arrival_s = lk.arrival_s
                self.feed_bytes(lid, data, clock(), datagram=False)

    # ------------------------------------------------------------------ results
    def summary(self) -> ServiceSummary:
        vehicles: dict[int, VehicleSummary] = {}
        for sysid, est in sorted({**self._retired, **self.estimators}.items()):
            scorer = est.scorer or TruthScorer()
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
            link_counters=self._link_counters(),
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

    def _link_counters(self) -> dict[str, dict[str, int]]:
        """Per link: its frames' counters, and the datagrams the kernel dropped on it."""
        counters = {k: d.counters.as_dict() for k, d in self.decoders.items()}
        for lid, n in self.kernel_drops.drops.items():
            counters.setdefault(lid, {})[KERNEL_DROPS_COUNTER] = n
        return dict(sorted(counters.items()))

    def copy_state(self) -> Service:
        """A deep copy of this service: its ingest, estimators, counters and sinks (for
        replaying several variants of one log from a shared prefix,
        :func:`glmav_testkit.fault_replay.replay_cases`). The copy shares the MAVLink
        encoder, which holds no estimation state (it encodes the rate requests and
        their sequence numbers would then interleave): copy a service that replays, not
        one that sends."""
        return copy.deepcopy(self, {id(self._mav): self._mav})

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
    """Open ``links``, serve until SIGINT/SIGTERM/SIGHUP (or ``stop_event``), close everything.

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
    """Inside: SIGINT, SIGTERM and SIGHUP (a closed terminal, a service manager's reload:
    there is nothing to reload, so it stops as SIGTERM does) set ``stop`` (logged) instead
    of interrupting; the previous handlers come back on leaving. Only in the main thread (Python delivers
    signals there); elsewhere a no-op."""
    previous: dict[signal.Signals, Any] = {}

    def on_signal(signum: int, frame: FrameType | None) -> None:
        logger.info("stopping", extra={"signal": signal.Signals(signum).name})
        set_from_signal_handler(stop)

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, on_signal)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
