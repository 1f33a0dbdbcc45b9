"""Outputs at their consumers' rates (issue 28): an estimator that builds only what its
sinks read publishes the same arithmetic, only less often.

The same corpus flight (ArduPilot SITL, GPS switched off: the autopilot's velocity goes
unaided, axes are isolated and re-admitted; its SIM_STATE truth left out) is replayed twice through the service: once
with a sink that reads everything, once with a sink that reads the live defaults
(configurations 10 Hz, active and aided 50 Hz, health 5 Hz). The second run's velocity
records must be exactly the first run's, decimated by the builder's rule
(:func:`glmav_observer.reads.next_due_s`) per stream, with the decisions identical.
"""

from __future__ import annotations

import lzma
import math
from pathlib import Path
from typing import Any

import pytest

from glmav_observer.app import Service
from glmav_observer.app_summary import ServiceSummary
from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.framing import FrameCounters, iter_tlog
from glmav_observer.reads import EVERY, Reads, next_due_s
from glmav_observer.records import HealthRecord, Record, VelocityRecord
from glmav_testkit.fault_replay import FaultInjector, VelocityFault

DATA = Path(__file__).resolve().parents[2] / "data" / "ardupilot_sitl"
LIVE = Reads(
    {
        "full": 10.0, "c1": 10.0, "c2": 10.0, "c3": 10.0,
        "active": 50.0, "aided": 50.0, "health": 5.0, "measurement": EVERY,
    }
)  # fmt: skip


class _Collect:
    def __init__(self, reads: Reads | None = None) -> None:
        if reads is not None:
            self.reads = reads
        self.records: list[Record] = []

    def write(self, record: Record) -> None:
        self.records.append(record)

    def close(self) -> None:
        pass


def _decimate(records: list[VelocityRecord], rate_hz: float) -> list[VelocityRecord]:
    """The builder's rule, applied after the fact to every record of one stream."""
    out, due = [], -math.inf
    for r in records:
        if r.t_boot_s >= due:
            out.append(r)
            due = next_due_s(r.t_boot_s, rate_hz)
    return out


def _replay(messages: list[tuple[Any, float]], sink: _Collect) -> tuple[Service, ServiceSummary]:
    service = Service(ServiceConfig(request_rates=False), [sink])
    for msg, t in messages:
        service.feed_message(msg, t, "log")
    service.close()
    return service, service.summary()


@pytest.fixture(scope="module")
def runs() -> tuple[_Collect, _Collect, ServiceSummary, ServiceSummary]:
    data = lzma.decompress((DATA / "a_quad_wind.tlog.xz").read_bytes())
    # a 1 m/s bias on east from 70 s to 80 s: an isolation, a switch and a recovery;
    # without its SIM_STATE: a real vehicle's stream
    inject = FaultInjector([VelocityFault(1, "bias", 70.0, 80.0, 1.0)])
    messages = []
    for r in iter_tlog(data, FrameCounters()):
        if r.msg.get_type() == "SIM_STATE":
            continue
        inject.apply(r.msg)
        messages.append((r.msg, r.t_host_us * 1e-6))
    full, live = _Collect(), _Collect(LIVE)
    _, s_full = _replay(messages, full)
    service, s_live = _replay(messages, live)
    # the live run built what its sink reads, and no more (no gate held anything back)
    assert service.records == len(live.records)
    assert service.estimators[1].out.reads == LIVE
    return full, live, s_full, s_live


def _stream(records: list[Record], config: str) -> list[VelocityRecord]:
    return [r for r in records if type(r) is VelocityRecord and r.config == config]


def test_decisions_are_identical_whatever_is_built(runs: tuple[Any, ...]) -> None:
    _, _, s_full, s_live = runs
    v_full, v_live = s_full.vehicles[1], s_live.vehicles[1]
    assert v_full.faults == v_live.faults
    assert v_full.switches == v_live.switches  # jump_mps included, bit for bit
    # the flight has decisions to compare: the injected bias is isolated, the active
    # configuration switches and comes back
    assert len(v_full.faults) == 1 and len(v_full.switches) == 2


@pytest.mark.parametrize(("config", "rate_hz"), [("full", 10.0), ("c2", 10.0), ("active", 50.0)])
def test_built_records_are_the_full_rate_ones_decimated(
    runs: tuple[Any, ...],
    config: str,
    rate_hz: float,
) -> None:
    full, live, _, _ = runs
    every = _stream(full.records, config)
    built = _stream(live.records, config)
    want = _decimate(every, rate_hz)
    # a decision makes active due at once: those extra records are the full-rate ones too
    if config == "active":
        extra = [r for r in built if r not in set(want)]
        assert all(r._replace(seq=0) in {w._replace(seq=0) for w in every} for r in extra)
        built = [r for r in built if r not in set(extra)]
    # the same records (sequence numbers count what was built: compared apart)
    assert [r._replace(seq=0) for r in built] == [r._replace(seq=0) for r in want]
    assert [r.seq for r in _stream(live.records, config)] == list(
        range(1, len(_stream(live.records, config)) + 1)
    )  # consecutive: a consumer sees that nothing was lost
    # one per period of the flight's time (this log's IMU runs at 50 Hz: 10 Hz builds one
    # step in five); a restart's gap has none: 5 % below at most
    span_s = every[-1].t_boot_s - every[0].t_boot_s
    assert span_s * rate_hz * 0.95 <= len(want) <= span_s * rate_hz + 2  # both ends
    assert len(want) < len(every) or rate_hz >= 50.0


def test_health_at_its_rate_and_at_every_decision(runs: tuple[Any, ...]) -> None:
    full, live, _, s_live = runs
    health = [r for r in live.records if type(r) is HealthRecord]
    n_full = sum(1 for r in full.records if type(r) is HealthRecord)
    # 5 Hz against 10 Hz, plus one at each decision
    decisions = len(s_live.vehicles[1].faults) + len(s_live.vehicles[1].switches)
    assert len(health) <= n_full // 2 + decisions + 2
    assert len(health) >= n_full // 2 - 2
    # every switch is in a health record built at the first IMU step after it: ≤ 1 IMU
    # period (20 ms at ArduPilot's 50 Hz RAW_IMU) plus the RAW_IMU stamp's lead over the
    # same tick's LOCAL_POSITION_NED (µs against ms: up to 1 ms)
    for sw in s_live.vehicles[1].switches:
        after = [h for h in health if h.t_boot_s >= sw["t_boot_s"]]
        assert after and after[0].t_boot_s - sw["t_boot_s"] <= 0.021, sw
        assert after[0].active_config == sw["to"]


def test_a_vehicle_that_sends_truth_is_scored_on_every_estimate() -> None:
    """A simulator's vehicle (SIM_STATE): the summary's RMSE is over every sample whatever
    the outputs read (the same figures as with a sink that reads everything), and no
    record is built for it: the estimator hands its scorer the estimates, the service
    builds what the sink reads and no more."""
    data = lzma.decompress((DATA / "a_quad_wind.tlog.xz").read_bytes())
    # (about 45 s of the flight: its first 20 s are before the EKF's first estimate)
    messages = [(r.msg, r.t_host_us * 1e-6) for r in iter_tlog(data, FrameCounters())][:20_000]
    full, live = _Collect(), _Collect(LIVE)
    service_full, s_full = _replay(messages, full)
    service, s_live = _replay(messages, live)
    assert s_full.vehicles[1].truth_samples > 1000  # the prefix is long enough to score
    assert s_live.vehicles[1].rmse_ned_mps == s_full.vehicles[1].rmse_ned_mps
    assert s_live.vehicles[1].max_abs_error_ned_mps == s_full.vehicles[1].max_abs_error_ned_mps
    # every estimate scored: each configuration's, at every IMU sample from the first
    # truth sample on, as many as the sink that reads everything got after the skip
    scorer, scorer_full = service.estimators[1].scorer, service_full.estimators[1].scorer
    assert scorer is not None and scorer_full is not None
    # (truth comes from the start, the first estimate once the EKF's velocity does: the
    # skip counts from it)
    t_first = _stream(full.records, "full")[0].t_boot_s
    skip_s = ServiceConfig().estimation.metrics_skip_s
    for config in ("full", "c2", "active"):
        every = [r for r in _stream(full.records, config) if r.t_boot_s >= t_first + skip_s]
        assert scorer.n(config) == scorer_full.n(config)
        # scored: the records after the skip that truth brackets (SIM_STATE comes at the
        # IMU's 50 Hz with every sample: all but those after the last truth sample)
        assert len(every) - 5 <= scorer.n(config) <= len(every)
        if LIVE.rate(config) == 10.0:  # five times what the sink reads at 10 Hz
            assert scorer.n(config) > 4 * len(_stream(live.records, config))
    # what the service built is what the sink got: nothing for the scoring
    assert service.records == len(live.records)
    # ... at its rate: the same records as the full-rate ones decimated, numbered as built
    got, want = _stream(live.records, "full"), _decimate(_stream(full.records, "full"), 10.0)
    assert [r._replace(seq=0) for r in got] == [r._replace(seq=0) for r in want]
    assert [r.seq for r in got] == list(range(1, len(got) + 1))
