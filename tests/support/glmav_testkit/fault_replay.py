"""Replays of recorded logs through the product with faults injected, for the tests and
benchmarks (the corpus, the golden replays, the aiding).

:func:`replay` runs a recorded log through the product (:class:`glmav_observer.app.Service`,
the same ingest and estimator as ``serve``) with velocity faults injected into
``LOCAL_POSITION_NED`` (:class:`VelocityFault`) or shocks into ``RAW_IMU``
(:class:`ImuShock`), and returns what happened: RMSE per configuration, every isolation,
every switch and its jump, and the error time series. Replays are deterministic (noise
faults use a seeded generator). Not part of the product: the service injects nothing
(the demo's fault is the simulator's, set through its parameters).
"""

from __future__ import annotations

import copy
import lzma
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from glmav_observer.evaluation import errors_against_truth, rmse
from glmav_observer.records import (
    NED_AXES,
    FaultEvent,
    MeasurementRecord,
    Record,
    ReferenceFitSummary,
    TruthRecord,
    VelocityRecord,
)

if TYPE_CHECKING:
    from glmav_observer.estimation.selection import SwitchEvent

FaultKindName = Literal["bias", "freeze", "nan", "noise"]
Vec3 = tuple[float, float, float]
FloatArray = np.ndarray[Any, np.dtype[np.float64]]

#: xz magic: compressed logs are read as they are (the corpus in tests/data is xz).
_XZ_MAGIC = b"\xfd7zXZ\x00"


def read_log_bytes(path: str | Path) -> bytes:
    """A tlog's bytes, decompressed if the file is xz."""
    data = Path(path).read_bytes()
    return lzma.decompress(data) if data.startswith(_XZ_MAGIC) else data


# ---------------------------------------------------------------------- collected records
@dataclass
class Series:
    """One estimate's time series (vehicle time, NED velocity)."""

    t_s: list[float] = field(default_factory=list)
    v_ned_mps: list[Vec3] = field(default_factory=list)

    def arrays(self) -> tuple[FloatArray, FloatArray]:
        return np.asarray(self.t_s, dtype=float), np.asarray(self.v_ned_mps, dtype=float).reshape(
            -1, 3
        )


class RecordCollector:
    """A sink that keeps velocity and truth series per configuration (one vehicle)."""

    def __init__(self) -> None:
        self.series: dict[str, Series] = {}
        self.truth = Series()
        self.source_config: list[tuple[float, str]] = []

    def write(self, record: Record) -> None:
        if isinstance(record, VelocityRecord):
            s = self.series.setdefault(record.config, Series())
            s.t_s.append(record.t_boot_s)
            s.v_ned_mps.append(record.v_ned_mps)
        elif isinstance(record, TruthRecord):
            self.truth.t_s.append(record.t_boot_s)
            self.truth.v_ned_mps.append(record.v_ned_mps)
        elif isinstance(record, MeasurementRecord):
            s = self.series.setdefault("measurement", Series())
            s.t_s.append(record.t_boot_s)
            s.v_ned_mps.append(record.v_ned_mps)

    def close(self) -> None:
        return None

    def errors(self, config: str, skip_s: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """Errors of ``config`` against truth, from ``skip_s`` after its first estimate."""
        s = self.series.get(config)
        if s is None or not s.t_s:
            return np.zeros(0), np.zeros((0, 3))
        t, v = s.arrays()
        keep = t >= t[0] + skip_s
        tt, vt = self.truth.arrays()
        return errors_against_truth(t[keep], v[keep], tt, vt)


# ---------------------------------------------------------------------- injected faults
@dataclass(frozen=True, slots=True)
class VelocityFault:
    """A fault injected into one NED axis of ``LOCAL_POSITION_NED`` over [t_on_s, t_off_s).

    ``bias``: + ``size_mps``; ``freeze``: the last value before t_on_s is repeated;
    ``nan``: NaN; ``noise``: + white Gaussian noise of σ ``size_mps``.
    """

    axis: int  # 0 n, 1 e, 2 d
    kind: FaultKindName
    t_on_s: float
    t_off_s: float
    size_mps: float = 0.0

    @property
    def axis_name(self) -> str:
        return NED_AXES[self.axis]

    @property
    def expected_kind(self) -> str:
        """The fault kind the FDI should report (a NaN run is a dropout)."""
        return "dropout" if self.kind == "nan" else self.kind


@dataclass(frozen=True, slots=True)
class ImuShock:
    """One IMU sample replaced by a shock: the first ``RAW_IMU`` at or after ``t_s`` reads
    ``f_body_mps2`` (converted to its mG counts, clipped to int16)."""

    t_s: float
    f_body_mps2: Vec3


_VEL_FIELDS = ("vx", "vy", "vz")
_MG_PER_MPS2 = 1000.0 / 9.80665


class FaultInjector:
    """Applies :class:`VelocityFault` s to decoded ``LOCAL_POSITION_NED`` messages and
    :class:`ImuShock` s to ``RAW_IMU`` messages, in place."""

    def __init__(self, faults: Sequence[VelocityFault | ImuShock], seed: int = 0) -> None:
        self.faults = tuple(f for f in faults if isinstance(f, VelocityFault))
        self.shocks = [f for f in faults if isinstance(f, ImuShock)]
        self._rng = np.random.default_rng(seed)
        self._last_good: list[float] = [math.nan, math.nan, math.nan]
        self._frozen: dict[int, float] = {}

    def follow(self, other: FaultInjector) -> None:
        """Continue from ``other``'s last good values (a replay that shares a prefix)."""
        self._last_good = list(other._last_good)

    def apply(self, msg: Any) -> None:
        name = msg.get_type()
        if name == "RAW_IMU" and self.shocks:
            t = msg.time_usec * 1e-6
            for shock in [x for x in self.shocks if t >= x.t_s]:
                counts = [
                    max(-32768, min(32767, round(v * _MG_PER_MPS2))) for v in shock.f_body_mps2
                ]
                msg.xacc, msg.yacc, msg.zacc = counts
                self.shocks.remove(shock)
            return
        if name != "LOCAL_POSITION_NED":
            return
        t = msg.time_boot_ms * 1e-3
        for f in self.faults:
            name = _VEL_FIELDS[f.axis]
            if not f.t_on_s <= t < f.t_off_s:
                self._frozen.pop(id(f), None)
                continue
            v = float(getattr(msg, name))
            if f.kind == "bias":
                v += f.size_mps
            elif f.kind == "nan":
                v = math.nan
            elif f.kind == "noise":
                v += float(self._rng.normal(0.0, f.size_mps))
            else:  # freeze
                v = self._frozen.setdefault(id(f), self._last_good[f.axis])
            setattr(msg, name, v)
        for i, name in enumerate(_VEL_FIELDS):
            if not any(f.axis == i and f.t_on_s <= t < f.t_off_s for f in self.faults):
                self._last_good[i] = float(getattr(msg, name))


# ---------------------------------------------------------------------- replay + scoring
@dataclass(frozen=True, slots=True)
class Isolation:
    t_s: float
    axis: str
    kind: str


@dataclass(frozen=True, slots=True)
class Switch:
    t_s: float
    from_config: str
    to_config: str
    reason: str
    jump_mps: float | None


@dataclass
class LogResult:
    """What the product did on one log (one vehicle: the first with estimates)."""

    name: str
    rmse_ned_mps: dict[str, Vec3 | None]
    isolations: list[Isolation]
    switches: list[Switch]
    counters: dict[str, int]
    collector: RecordCollector
    skip_s: float
    #: what the FDI's reference fit had learnt at the end of the log (None: never fitted)
    reference_fit: ReferenceFitSummary | None = None
    #: the estimator's own events, whole (``VehicleEstimator.faults`` / ``.switches``:
    #: what the service's summary publishes with ``to_dict()``); the golden replays keep them
    fault_events: list[FaultEvent] = field(default_factory=list)
    switch_events: list[SwitchEvent] = field(default_factory=list)

    def errors(self, config: str) -> tuple[FloatArray, FloatArray]:
        return self.collector.errors(config, self.skip_s)

    def isolations_outside(self, windows: Iterable[tuple[float, float]]) -> list[Isolation]:
        """Isolations not inside any (t_on, t_off) window."""
        w = list(windows)
        return [i for i in self.isolations if not any(a <= i.t_s <= b for a, b in w)]

    def max_jump_mps(self) -> float:
        return max((s.jump_mps or 0.0 for s in self.switches), default=0.0)


def replay(
    path: str | Path,
    config: Any = None,
    faults: Sequence[VelocityFault | ImuShock] = (),
    *,
    seed: int = 0,
    sysid: int | None = None,
) -> LogResult:
    """Replay a tlog (plain or xz) through the service with ``faults`` injected.

    ``config`` is a :class:`glmav_observer.config.ServiceConfig` (default: built-in
    defaults). Scores the vehicle ``sysid`` (default: the first that produced estimates).
    """
    return next(replay_cases(path, [faults], config, seed=seed, sysid=sysid))


def _onset_s(f: VelocityFault | ImuShock) -> float:
    return f.t_on_s if isinstance(f, VelocityFault) else f.t_s


def _injectable_at(msg: Any) -> float | None:
    """The time :class:`FaultInjector` reads from ``msg`` (None: it never changes ``msg``)."""
    name = msg.get_type()
    if name == "LOCAL_POSITION_NED":
        return float(msg.time_boot_ms) * 1e-3
    if name == "RAW_IMU":
        return float(msg.time_usec) * 1e-6
    return None


def replay_cases(
    path: str | Path,
    cases: Sequence[Sequence[VelocityFault | ImuShock]],
    config: Any = None,
    *,
    seed: int = 0,
    sysid: int | None = None,
    collector_type: Callable[[], RecordCollector] = RecordCollector,
) -> Iterator[LogResult]:
    """:func:`replay` of one log once per case (a set of faults), the same results as
    separate replays at a fraction of the cost: the log is decoded once, and the messages
    before the first one any case's faults could change are replayed once and the
    service's state copied for each case (``copy.deepcopy``; the copies share only the
    MAVLink encoder, which a replay uses for nothing it scores). Messages from the split
    on are copied before injection, so no case sees another's faults;
    tests/integration/glmav_observer/test_ardupilot_corpus.py asserts equality with
    :func:`replay`. Results come one case at a time (each holds its own series).
    ``collector_type`` makes the sink every case's records reach (a subclass can keep more
    than the series: glmav_testkit.golden keeps the whole records, decimated).
    """
    from glmav_observer.app import Service
    from glmav_observer.config import ServiceConfig
    from glmav_observer.ingest.framing import FrameCounters, iter_tlog

    cfg = config if config is not None else ServiceConfig()
    link = str(path)
    recs = list(iter_tlog(read_log_bytes(path), FrameCounters()))
    onsets = [_onset_s(f) for case in cases for f in case]
    t_split = min(onsets, default=math.inf)
    # the first message a fault could change: every earlier one reaches every case as it is
    split = next(
        (
            i
            for i, r in enumerate(recs)
            if (t := _injectable_at(r.msg)) is not None and t >= t_split
        ),
        len(recs),
    )
    base = Service(cfg, [collector_type()])
    tracker = FaultInjector((), seed)  # no faults: it only follows the last good values
    for rec in recs[:split]:
        tracker.apply(rec.msg)
        base.feed_message(rec.msg, rec.t_host_us * 1e-6, link)
    for k, case in enumerate(cases):
        # the last case continues the prefix's own service: no copy left to make
        service = base.copy_state() if k < len(cases) - 1 else base
        collector = service.sinks[0]
        assert isinstance(collector, RecordCollector)
        injector = FaultInjector(case, seed)
        injector.follow(tracker)
        for rec in recs[split:]:
            msg = rec.msg
            if _injectable_at(msg) is not None:
                msg = copy.copy(msg)  # injection is in place: keep the shared message clean
            injector.apply(msg)
            service.feed_message(msg, rec.t_host_us * 1e-6, link)
        service.close()
        yield _result(path, cfg, service, collector, sysid)


def _result(
    path: str | Path, cfg: Any, service: Any, collector: RecordCollector, sysid: int | None
) -> LogResult:
    ests = {**service._retired, **service.estimators}
    if sysid is None:
        sysid = next((s for s, e in sorted(ests.items()) if e.t_first_s is not None), None)
    if sysid is None:
        raise ValueError(f"{path}: no vehicle produced estimates")
    est = ests[sysid]
    skip = cfg.estimation.metrics_skip_s
    result = LogResult(
        name=Path(path).name.split(".")[0],
        rmse_ned_mps={},
        isolations=[Isolation(f.t_detect_s, f.axis, f.kind) for f in est.faults],
        switches=[
            Switch(s.t_boot_s, s.from_config, s.to_config, s.reason, s.jump_mps)
            for s in est.switches
        ],
        counters=est.all_counters(),
        collector=collector,
        skip_s=skip,
        reference_fit=est.reference_fit_summary(),
        fault_events=list(est.faults),
        switch_events=list(est.switches),
    )
    for c in collector.series:
        result.rmse_ned_mps[c] = rmse(result.errors(c)[1])
    return result
