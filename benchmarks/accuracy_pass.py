"""One pass of the accuracy benchmark (:mod:`benchmarks.accuracy`): the product's
estimator and the baselines over a flight's samples, every estimate at the truth samples
(:class:`Trace`), and the convergence time read from a cold-start trace.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.baselines import (
    DeadReckoning,
    KalmanVelocity,
    RawMeasurement,
    earth_accel_mps2,
)
from glmav_observer.config import load_config
from glmav_observer.configurations import LOST_AXIS_OF_CONFIG
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.ingest.samples import (
    AttitudeSample,
    ImuSample,
    Sample,
    TruthSample,
    VelocitySample,
)
from glmav_observer.records import CONFIGS, NED_AXES, VelocityRecord

FloatArray = NDArray[np.float64]

#: The estimates compared at every truth sample, in column order of the trace.
ESTIMATES: tuple[str, ...] = (
    *(f"bank:{c}" for c in CONFIGS),
    "bank:active",
    *(f"kf:{c}" for c in CONFIGS),
    *(f"raw:{c}" for c in CONFIGS),
    "dr",
)


# ---------------------------------------------------------------------------- one pass


@dataclasses.dataclass
class Trace:
    """Truth and every estimate at the truth samples (T,), (T, 3), name -> (T, 3)."""

    t_s: FloatArray
    v_true_ned_mps: FloatArray
    est: dict[str, FloatArray]
    t_start_s: float
    faults: list[dict[str, Any]]
    switches: list[dict[str, Any]]
    counters: dict[str, int]


#: Cold start: the initial estimate is off by the paper's (48) body velocity, taken as an
#: NED error (m/s), so that the 5 % convergence time has an error to converge from.
COLD_OFFSET_NED_MPS = (2.0, -1.3, 1.3)


def run_pass(samples: Sequence[Sample], *, cold: bool, until_s: float = math.inf) -> Trace:
    """The estimator and the baselines over ``samples``.

    Warm (``cold=False``): everyone starts from the first measurement, as the estimator
    does. Cold: every estimate starts off by :data:`COLD_OFFSET_NED_MPS`; the KF's prior
    is σ = 2 m/s per axis (the size of that error).

    The KFs and dead reckoning share one integral of the held earth-frame acceleration
    between the instants they are read or updated: with F = I and additive Q,
    predicting once over the sum equals predicting at every IMU step.
    """
    est = VehicleEstimator(1, load_config(None).estimation)  # the daemon's defaults
    kfs: list[KalmanVelocity] = []
    raws: list[RawMeasurement] = []
    dr: DeadReckoning | None = None
    euler: tuple[float, float, float] | None = None
    f: tuple[float, float, float] | None = None
    pending_y: tuple[float, float, float] | None = None
    acc_dv = np.zeros(3)  # ∫ a dt since the last flush
    acc_dt = 0.0
    t_prev = math.nan
    t0 = math.nan
    latest: dict[str, Any] = {}
    t_l: list[float] = []
    v_l: list[tuple[float, float, float]] = []
    cols: dict[str, list[Any]] = {n: [] for n in ESTIMATES}

    def flush() -> None:
        nonlocal acc_dv, acc_dt
        if acc_dt > 0.0 and dr is not None:
            a_mean = acc_dv / acc_dt
            dr.predict(acc_dt, a_mean)
            for kf in kfs:
                kf.predict(acc_dt, a_mean)
        acc_dv = np.zeros(3)
        acc_dt = 0.0

    for s in samples:
        held = (euler, f)
        recs = est.on_sample(s)
        t_bank = est.t_bank_s
        if not kfs and t_bank is not None and isinstance(s, VelocitySample):
            # the estimator just started from this measurement: so do the baselines
            v0 = s.v_ned_mps
            if cold:
                assert euler is not None
                v0 = tuple(v + o for v, o in zip(v0, COLD_OFFSET_NED_MPS, strict=True))  # type: ignore[assignment]
                for c in CONFIGS:
                    est.bank.set_state_ned(c, v0, euler)
            p0 = 4.0 if cold else 0.05**2
            kfs = [KalmanVelocity(v0, p0_mps2=p0) for _ in CONFIGS]
            raws = [RawMeasurement(v0) for _ in CONFIGS]
            dr = DeadReckoning(v0)
            t_prev = t0 = t_bank
            latest = {f"bank:{c}": v0 for c in (*CONFIGS, "active")}
        elif kfs and t_bank is not None and t_bank > t_prev:
            assert held[0] is not None and held[1] is not None
            if pending_y is not None:  # applied at its own time, with the axes the bank used
                masks = est.bank.last_meas_mask
                flush()
                for i in range(4):
                    kfs[i].update(pending_y, masks[i])
                    raws[i].update(pending_y, masks[i])
                pending_y = None
            dt = t_bank - t_prev
            acc_dv += earth_accel_mps2(held[0], held[1]) * dt
            acc_dt += dt
            t_prev = t_bank
        if isinstance(s, AttitudeSample):
            euler = s.euler_rad
        elif isinstance(s, ImuSample):
            f = s.f_body_mps2
        elif isinstance(s, VelocitySample) and kfs:
            pending_y = s.v_ned_mps
        for r in recs:
            if isinstance(r, VelocityRecord):
                latest[f"bank:{r.config}"] = r.v_ned_mps
        if isinstance(s, TruthSample) and kfs and dr is not None:
            if s.t_boot_s > until_s:
                break
            flush()
            t_l.append(s.t_boot_s)
            v_l.append(s.v_ned_mps)
            for c in (*CONFIGS, "active"):
                cols[f"bank:{c}"].append(latest[f"bank:{c}"])
            for i, c in enumerate(CONFIGS):
                cols[f"kf:{c}"].append(kfs[i].v_ned_mps)
                cols[f"raw:{c}"].append(raws[i].v_ned_mps)
            cols["dr"].append(dr.v_ned_mps)
    return Trace(
        t_s=np.asarray(t_l),
        v_true_ned_mps=np.asarray(v_l),
        est={n: np.asarray(v) for n, v in cols.items()},
        t_start_s=t0,
        faults=[ev.to_dict() for ev in est.faults],
        switches=[sw.to_dict() for sw in est.switches],
        counters=dict(est.counters),
    )


# ---------------------------------------------------------------------------- metrics


def _config_of(name: str) -> str:
    return name.split(":")[1] if ":" in name else "full"


def measured_axes(config: str) -> list[int]:
    lost = LOST_AXIS_OF_CONFIG.get(config)
    return [j for j in range(3) if lost is None or NED_AXES[j] != lost]


def convergence_time(tr: Trace, name: str) -> float:
    """Cold start: time from the start until the measured-axis error first falls below 5 %
    of its initial value (inf if it never does within the pass)."""
    config = _config_of(name)
    cfg = "full" if config == "active" or name == "dr" else config
    meas = measured_axes(cfg)
    err = np.linalg.norm(tr.est[name][:, meas] - tr.v_true_ned_mps[:, meas], axis=1)
    below = np.flatnonzero(err <= 0.05 * float(err[0]))
    return float(tr.t_s[below[0]] - tr.t_start_s) if below.size else math.inf
