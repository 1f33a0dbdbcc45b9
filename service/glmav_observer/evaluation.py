"""Error against truth and fault-isolation scoring, in one place.

One definition of "error against truth" for everything that reports one (the service's
summary, the Rerun sink's error plots, the corpus tests, the benchmarks): an estimate
published at vehicle time t is compared with the truth (``SIM_STATE``) linearly
interpolated at t; estimates outside the truth's time span, between truth samples more
than :data:`TRUTH_MAX_GAP_S` apart, or earlier than ``skip_s`` after the first estimate,
are not scored. Batch form :func:`errors_against_truth`, online form
:class:`TruthScorer`, the interpolation itself :func:`interpolate_truth`.

It also replays a recorded log through the product (:class:`glmav_observer.app.Service`,
the same ingest and estimator as ``serve``) with velocity faults injected into
``LOCAL_POSITION_NED`` (:class:`VelocityFault`), and returns what happened: RMSE per
configuration, every isolation, every switch and its jump, and the error time series.
Replays are deterministic (noise faults use a seeded generator).
"""

from __future__ import annotations

import collections
import copy
import lzma
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

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

#: Truth samples further apart than this are not interpolated between (a truth dropout):
#: SIM_STATE comes at 50 Hz (0.02 s) from both simulators, with jitter to 0.03 s.
TRUTH_MAX_GAP_S = 0.1
#: xz magic: compressed logs are read as they are (the corpus in tests/data is xz).
_XZ_MAGIC = b"\xfd7zXZ\x00"


def read_log_bytes(path: str | Path) -> bytes:
    """A tlog's bytes, decompressed if the file is xz."""
    data = Path(path).read_bytes()
    return lzma.decompress(data) if data.startswith(_XZ_MAGIC) else data


# ---------------------------------------------------------------------- error against truth
def errors_against_truth(
    t_est_s: FloatArray,
    v_est_ned_mps: FloatArray,
    t_truth_s: FloatArray,
    v_truth_ned_mps: FloatArray,
    *,
    max_gap_s: float = TRUTH_MAX_GAP_S,
) -> tuple[FloatArray, FloatArray]:
    """(times, errors (n, 3)) of estimates against truth interpolated at their times.

    Truth is interpolated per NED axis (linear, :func:`interpolate_truth`); estimates
    outside [t_truth[0], t_truth[-1]] or between truth samples more than ``max_gap_s``
    apart are dropped. Both time arrays must be non-decreasing.
    """
    ok, truth = interpolate_truth(t_est_s, t_truth_s, v_truth_ned_mps, max_gap_s=max_gap_s)
    return t_est_s[ok], v_est_ned_mps[ok] - truth[ok]


class TruthScorer:
    """The same definition, online: per configuration, RMSE and max |error| per NED axis of
    the estimates against truth linearly interpolated at their times.

    Fed in publication order (:meth:`add_estimate`, :meth:`add_truth`, or :meth:`add`
    with records of one vehicle). An estimate waits for the truth sample after it; it is
    scored when the truth samples that bracket it are at most ``max_gap_s`` apart (no
    interpolation across a truth dropout) and it is at least ``skip_s`` after the first
    estimate of its timeline (a clock reset starts a new timeline: the skip applies
    again). Memory is bounded: an estimate that can no longer be bracketed within
    ``max_gap_s`` is dropped. This is what the service's summary (the demo's table,
    ``replay``'s RMSE) reports; :func:`errors_against_truth` is the batch form for a
    whole recorded series (benchmarks, corpus tests) and :func:`interpolate_truth` the
    vectorised interpolation the Rerun sink plots.
    """

    #: an estimate this much earlier than the previous one is a new timeline (a reboot)
    RESET_BACKWARDS_S = 1.0

    def __init__(self, *, skip_s: float = 0.0, max_gap_s: float = TRUTH_MAX_GAP_S) -> None:
        self.skip_s = skip_s
        self.max_gap_s = max_gap_s
        #: per configuration: [n, Σe² n, Σe² e, Σe² d, max|e| n, max|e| e, max|e| d]
        self._acc: dict[str, list[float]] = {}
        #: truth samples received at or after the skip (what the errors were scored against)
        self.truth_samples = 0
        self._pending: collections.deque[tuple[float, str, Vec3]] = collections.deque()
        self._t_first_s: float | None = None
        self._t_last_est_s = -math.inf
        self._truth: tuple[float, Vec3] | None = None  # the latest truth sample
        self._truth_prev: tuple[float, Vec3] | None = None  # the one before it

    def _new_timeline(self) -> None:
        self._pending.clear()
        self._t_first_s = None
        self._t_last_est_s = -math.inf
        self._truth = self._truth_prev = None

    def add(self, record: Record) -> None:
        """A record of this vehicle: velocity estimates and truth are used, others ignored."""
        if isinstance(record, VelocityRecord):
            self.add_estimate(record.config, record.t_boot_s, record.v_ned_mps)
        elif isinstance(record, TruthRecord):
            self.add_truth(record.t_boot_s, record.v_ned_mps)

    def add_estimate(self, config: str, t_s: float, v_ned_mps: Vec3) -> None:
        if t_s > self._t_last_est_s:
            self._t_last_est_s = t_s
        elif t_s < self._t_last_est_s - self.RESET_BACKWARDS_S:
            self._new_timeline()
            self._t_last_est_s = t_s
        if self._t_first_s is None:
            self._t_first_s = t_s
        if t_s < self._t_first_s + self.skip_s:
            return
        b = self._truth
        if b is not None and t_s <= b[0]:
            a = self._truth_prev
            if t_s == b[0]:
                self._score(config, v_ned_mps, b[1])
            elif a is not None and a[0] <= t_s and b[0] - a[0] <= self.max_gap_s:
                self._score(config, v_ned_mps, _lerp(a, b, t_s))
            return
        p = self._pending
        p.append((t_s, config, v_ned_mps))
        # what cannot be bracketed within max_gap_s any more (no truth since) goes
        if p[0][0] < t_s - self.max_gap_s:
            horizon = t_s - self.max_gap_s
            while p and p[0][0] < horizon:
                p.popleft()

    def add_truth(self, t_s: float, v_ned_mps: Vec3) -> None:
        last = self._truth
        if last is not None and t_s < last[0] - self.RESET_BACKWARDS_S:
            self._new_timeline()
            last = None
        if last is not None and t_s <= last[0]:
            return  # a repeated or late truth sample brackets nothing new
        if self._t_first_s is not None and t_s >= self._t_first_s + self.skip_s:
            self.truth_samples += 1
        new = (t_s, v_ned_mps)
        p = self._pending
        t_lerp, v_lerp = math.nan, v_ned_mps  # the truth at the last time interpolated
        while p and p[0][0] <= t_s:
            te, config, ve = p.popleft()
            if te == t_s:
                self._score(config, ve, v_ned_mps)
            elif last is not None and last[0] <= te and t_s - last[0] <= self.max_gap_s:
                if te != t_lerp:  # the configurations of one step share their time
                    t_lerp, v_lerp = te, _lerp(last, new, te)
                self._score(config, ve, v_lerp)
        self._truth_prev, self._truth = last, new

    def _score(self, config: str, v_est: Vec3, v_truth: Vec3) -> None:
        acc = self._acc.get(config)
        if acc is None:
            acc = self._acc[config] = [0.0] * 7
        e0, e1, e2 = v_est[0] - v_truth[0], v_est[1] - v_truth[1], v_est[2] - v_truth[2]
        acc[0] += 1.0
        acc[1] += e0 * e0
        acc[2] += e1 * e1
        acc[3] += e2 * e2
        # max(acc[k], |e|) as max returns it (the second only if larger), without the call
        a0, a1, a2 = abs(e0), abs(e1), abs(e2)
        acc[4] = a0 if a0 > acc[4] else acc[4]
        acc[5] = a1 if a1 > acc[5] else acc[5]
        acc[6] = a2 if a2 > acc[6] else acc[6]

    def n(self, config: str) -> int:
        """Estimates of ``config`` scored."""
        acc = self._acc.get(config)
        return 0 if acc is None else int(acc[0])

    def rmse(self) -> dict[str, Vec3 | None]:
        """Per configuration scored: RMSE per NED axis."""
        return {
            c: (math.sqrt(a[1] / a[0]), math.sqrt(a[2] / a[0]), math.sqrt(a[3] / a[0]))
            for c, a in self._acc.items()
        }

    def max_abs(self) -> dict[str, Vec3 | None]:
        """Per configuration scored: the largest |error| per NED axis."""
        return {c: (a[4], a[5], a[6]) for c, a in self._acc.items()}


def _lerp(a: tuple[float, Vec3], b: tuple[float, Vec3], t_s: float) -> Vec3:
    w = (t_s - a[0]) / (b[0] - a[0])
    va, vb = a[1], b[1]
    return (va[0] + w * (vb[0] - va[0]), va[1] + w * (vb[1] - va[1]), va[2] + w * (vb[2] - va[2]))


def interpolate_truth(
    t_est_s: npt.ArrayLike,
    t_truth_s: npt.ArrayLike,
    v_truth: npt.ArrayLike,
    *,
    max_gap_s: float = TRUTH_MAX_GAP_S,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Truth at estimate times by linear interpolation between bracketing truth samples.

    ``t_truth_s`` ascending (N,), ``v_truth`` (N, k). Returns ``(ok, v)``: ``ok[i]`` is
    True when ``t_est_s[i]`` lies within [t_truth[0], t_truth[-1]] and the bracketing
    samples are at most ``max_gap_s`` apart (no interpolation across a truth dropout);
    ``v[ok]`` the interpolated truth (rows with ``ok`` False are NaN).
    """
    t_e = np.asarray(t_est_s, dtype=np.float64)
    t_t = np.asarray(t_truth_s, dtype=np.float64)
    v_t = np.asarray(v_truth, dtype=np.float64)
    if v_t.ndim == 1:
        v_t = v_t[:, None]
    out = np.full((len(t_e), v_t.shape[1]), np.nan)
    ok = np.zeros(len(t_e), dtype=bool)
    if len(t_t) == 0 or len(t_e) == 0:
        return ok, out
    hi = np.searchsorted(t_t, t_e, side="left")  # first truth sample at or after t_est
    exact = (hi < len(t_t)) & (t_t[np.minimum(hi, len(t_t) - 1)] == t_e)
    inside = (hi > 0) & (hi < len(t_t))
    lo = np.clip(hi - 1, 0, len(t_t) - 1)
    hi_c = np.clip(hi, 0, len(t_t) - 1)
    gap = t_t[hi_c] - t_t[lo]
    inside &= gap <= max_gap_s
    ok = inside | exact
    w = np.where(gap > 0, (t_e - t_t[lo]) / np.where(gap > 0, gap, 1.0), 0.0)
    interp = v_t[lo] + w[:, None] * (v_t[hi_c] - v_t[lo])
    interp[exact] = v_t[hi_c[exact]]
    out[ok] = interp[ok]
    return ok, out


def rmse(errors: FloatArray) -> Vec3 | None:
    """Per-axis RMSE of an (n, 3) error array (None when empty)."""
    if len(errors) == 0:
        return None
    r = np.sqrt(np.mean(errors**2, axis=0))
    return (float(r[0]), float(r[1]), float(r[2]))


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
