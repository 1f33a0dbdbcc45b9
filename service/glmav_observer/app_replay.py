"""Recorded logs through the service: :func:`replay_tlog` (a MAVLink ``.tlog``, the
:class:`~glmav_observer.app.Service` pipeline, deterministic) and :func:`replay_flight_log`
(an ArduPilot dataflash or PX4 ULog, :mod:`glmav_observer.ingest.logfiles`, with the
autopilot's EKF velocity published as ``reference`` records and RMSE against it).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from glmav_observer.app import Service
from glmav_observer.app_summary import ServiceSummary, VehicleSummary
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.evaluation import TRUTH_MAX_GAP_S, TruthScorer
from glmav_observer.ingest.framing import (
    FrameCounters,
    FrameDecoder,
    iter_tlog,
)
from glmav_observer.ingest.pipeline import FIELDS_READ
from glmav_observer.publish.sink import Sink
from glmav_observer.records import CONFIGS, Record, VelocityRecord

if TYPE_CHECKING:
    from glmav_observer.ingest.logfiles import FlightLog
    from glmav_observer.ingest.logfiles.tlog import TlogScan


def replay_tlog(
    path: str | Path,
    config: ServiceConfig,
    sinks: Sequence[Sink] = (),
    *,
    progress: Callable[[int, int], None] | None = None,
    stop_event: threading.Event | None = None,
    scan: TlogScan | None = None,
) -> ServiceSummary:
    """Run the pipeline over a ``.tlog`` (deterministic); sinks are closed at the end.

    If ``stop_event`` is set during the replay, it stops there, closes the sinks (their
    files end on whole records) and the summary's ``cut`` says where it stopped. ``scan``
    is the log's :func:`~glmav_observer.ingest.logfiles.tlog.check_tlog` (``replay`` and
    ``batch`` refuse a log the estimator cannot use): the replay goes on with the frames
    it decoded instead of reading and decoding them again."""
    if scan is not None:
        data = scan.data
        records, counters = scan.replay_records()
    else:
        data = Path(path).read_bytes()
        counters = FrameCounters()
        records = iter_tlog(data, counters, FIELDS_READ)
    service = Service(config, sinks)
    service.decoders[str(path)] = FrameDecoder(datagram=False, counters=counters)
    n = len(data)
    step = max(1, n // 200)
    next_report = 0
    cut = ""
    try:
        for rec in records:
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
    #: the airframe (multirotor, helicopter, plane, vtol, rover, boat, submarine, unknown)
    vehicle_type: str = "unknown"
    #: as ``rmse_vs_reference_ned_mps``, over the reference samples taken in flight only
    #: (:func:`~glmav_observer.ingest.logfiles.streams.in_flight_mask`)
    rmse_vs_reference_in_flight_ned_mps: dict[str, tuple[float, float, float] | None] = field(
        default_factory=dict
    )
    reference_samples_in_flight: int = 0
    #: the EKF's velocity innovation test ratios above 1 (rejected GPS velocities); None
    #: when the log has no innovation test ratio
    ekf_velocity_innovation_failures: int | None = None
    #: the GPS's rate from its median interval (Hz; a 5 Hz receiver that drops a fix
    #: now and then still reads 5), 0 without GPS
    gps_nominal_rate_hz: float = 0.0

    @property
    def vehicle_summary(self) -> VehicleSummary | None:
        return next(iter(self.service.vehicles.values()), None)

    def to_text(self) -> str:
        rates = ", ".join(
            f"{k} {v:.1f} Hz ({self.sources.get(k, '?')})" for k, v in self.rates_hz.items()
        )
        lines = [
            f"{self.format} log: {self.vehicle} ({self.vehicle_type}), {self.duration_s:.1f} s",
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
        if self.reference_samples_in_flight:
            tables.append(
                (
                    f"the EKF's velocity in flight ({self.reference_samples_in_flight} samples)",
                    self.rmse_vs_reference_in_flight_ned_mps,
                )
            )
        if self.ekf_velocity_innovation_failures is not None:
            lines.append(
                f"the EKF's velocity innovation failures (test ratio > 1, "
                f"{self.sources.get('ekf_innovations', '?')}): "
                f"{self.ekf_velocity_innovation_failures}"
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
    path: str | Path | FlightLog,
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
    ``path`` may be a log already read (:func:`~glmav_observer.ingest.logfiles.read_flight_log`:
    ``replay`` reads it before it creates its outputs).
    """
    import numpy as np

    from glmav_observer.ingest.logfiles import (
        LOG_SYSID,
        VELOCITY_SOURCES,
        FlightLog,
        read_flight_log,
    )
    from glmav_observer.ingest.logfiles.streams import in_flight_mask
    from glmav_observer.ingest.rates import RateMonitor
    from glmav_observer.ingest.samples import TruthSample
    from glmav_observer.records import ReferenceRecord

    service = Service(config, sinks)
    try:
        if velocity_source not in VELOCITY_SOURCES:
            raise ValueError(f"velocity source must be gps or ekf, got {velocity_source!r}")
        if isinstance(path, FlightLog):
            log = path
        else:
            log = read_flight_log(path, velocity_source, gps_delay_s=gps_delay_s)  # type: ignore[arg-type]
        sysid = LOG_SYSID
        monitor = RateMonitor({}, window_s=config.ingest.rate_window_s)
        est = VehicleEstimator(sysid, config.estimation, rates_fn=monitor.rates, score_truth=True)
        accel_filter_hz = log.streams.params.get("INS_ACCEL_FILTER")
        if log.streams.format == "dataflash" and accel_filter_hz is not None:
            est.set_accel_filter_hz(accel_filter_hz)  # what its IMU messages went through
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
        # the same over the reference samples taken in flight: a gap (on the ground)
        # is wider than max_gap_s, so no estimate on the ground is scored
        flying = in_flight_mask(
            log.t_reference_s, log.v_reference_ned_mps, log.streams.p_ekf_ned_m
        ).tolist()
        ref_err_flight = TruthScorer(
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
                if flying[i_ref]:
                    ref_err_flight.add_truth(tr, (vr[0], vr[1], vr[2]))
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
                    ref_err_flight.add_estimate(r.config, r.t_boot_s, r.v_ned_mps)
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
        path=str(log.path),
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
        vehicle_type=log.streams.vehicle_type,
        rmse_vs_reference_in_flight_ned_mps={
            c: ref_err_flight.rmse().get(c) for c in (*CONFIGS, "active")
        },
        reference_samples_in_flight=ref_err_flight.truth_samples,
        ekf_velocity_innovation_failures=(
            int((log.streams.ekf_vel_test_ratio > 1.0).sum())
            if "ekf_innovations" in log.streams.sources
            else None
        ),
        gps_nominal_rate_hz=(
            1.0 / float(np.median(np.diff(log.streams.t_gps_s)))
            if len(log.streams.t_gps_s) > 2
            else 0.0
        ),
    )
