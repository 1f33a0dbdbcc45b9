"""Error against truth and fault-isolation scoring, in one place.

One definition of "error against truth" for everything that reports one (the service's
summary, the corpus tests, the benchmarks): an estimate published at vehicle time t is
compared with the truth (``SIM_STATE``) linearly interpolated at t; estimates outside the
truth's time span, or earlier than ``skip_s`` after the first estimate, are not scored.

It also replays a recorded log through the product (:class:`glmav_observer.app.Service`,
the same ingest and estimator as ``serve``) with velocity faults injected into
``LOCAL_POSITION_NED`` (:class:`VelocityFault`), and returns what happened: RMSE per
configuration, every isolation, every switch and its jump, and the error time series.
Replays are deterministic (noise faults use a seeded generator).
"""

from __future__ import annotations

import lzma
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from glmav_observer.records import (
    NED_AXES,
    MeasurementRecord,
    Record,
    ReferenceFitSummary,
    TruthRecord,
    VelocityRecord,
)

FaultKindName = Literal["bias", "freeze", "nan", "noise"]
Vec3 = tuple[float, float, float]
FloatArray = np.ndarray[Any, np.dtype[np.float64]]

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
) -> tuple[FloatArray, FloatArray]:
    """(times, errors (n, 3)) of estimates against truth interpolated at their times.

    Truth is interpolated per NED axis (linear); estimates outside [t_truth[0],
    t_truth[-1]] are dropped. Both time arrays must be non-decreasing.
    """
    if len(t_truth_s) < 2 or len(t_est_s) == 0:
        return np.zeros(0), np.zeros((0, 3))
    keep = (t_est_s >= t_truth_s[0]) & (t_est_s <= t_truth_s[-1])
    t = t_est_s[keep]
    truth = np.column_stack([np.interp(t, t_truth_s, v_truth_ned_mps[:, i]) for i in range(3)])
    return t, v_est_ned_mps[keep] - truth


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
    from glmav_observer.app import Service
    from glmav_observer.config import ServiceConfig
    from glmav_observer.ingest.framing import FrameCounters, iter_tlog

    cfg = config if config is not None else ServiceConfig()
    collector = RecordCollector()
    service = Service(cfg, [collector])
    injector = FaultInjector(faults, seed)
    link = str(path)
    for rec in iter_tlog(read_log_bytes(path), FrameCounters()):
        injector.apply(rec.msg)
        service.feed_message(rec.msg, rec.t_host_us * 1e-6, link)
    service.close()
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
        counters=dict(est.counters),
        collector=collector,
        skip_s=skip,
        reference_fit=est.reference_fit_summary(),
    )
    for c in collector.series:
        result.rmse_ned_mps[c] = rmse(result.errors(c)[1])
    return result
