"""The lost axis against the floor (issue 32): the floor of every loss of ``benchmarks.aero``
beside its dead reckoning and aided errors, and the issue's bounds judged on them.

The floor (``estimation/aero/floor.py``) is the σ of an oracle Kalman filter with the true
drag law and wind, from a hand-over by the healthy oracle; its median |e| is 0.674 σ.

- glmav-sitl: the simulator's own IMU noise, bias random walk, turbulence and velocity
  noise (``glmav_testkit.aero_floor``);
- ArduPilot SITL: its frame model's drag and the flight's wind (``glmav_testkit.
  ardupilot_floor``, read from ArduPilot's ``SIM_Frame.cpp``, ``SIM_Aircraft.cpp``), fed
  the earth-frame acceleration the service has (RAW_IMU rotated by the EKF's ATTITUDE),
  whose error's random walk is measured on the flight against SIM_STATE
  (:func:`input_error_random_walk`): without it the oracle, with SITL's exact
  accelerometer and the true attitude, would know the lost axis to 4 mm/s.

**The as-flown floor** (ArduPilot flights): the same oracle without the gift of a perfect
drag law (``glmav_testkit.ardupilot_floor.law_misfit_ne_mps``). It is granted the best
constant law of the frame model's form (k, q and a body bias per body axis, fitted over the
flight against the truth), the mean wind at its height and the statistics of the law's
misfit (white plus a Gauss-Markov part, measured on the flight), the misfit's values not.
On the calm flights that misfit is 0.03-0.06 m/s correlated over 1-3.5 s (the service's
attitude is the EKF's; the thrust and the heli's flapping vary): the filter cannot average
it away as it does the white quantisation the oracle is left with. On glmav-sitl flights
the oracle's law is the simulator's own and its turbulence is measured in the
simulator's terms: the as-flown floor is the oracle's floor there.

On d the oracle has no drag measurement (the thrust is not known to it; the horizontal
rows see d only through the tilt): its floor there is its own dead reckoning, an upper
bound of the true floor.

The bounds (per flight and axis, over its losses): where the floor's median at +60 s is
below half of dead reckoning's, the aided median ≤ 1.5 × the floor's at +10 s and +60 s;
in every loss the aided RMS ≤ dead reckoning's + 0.02 m/s; |e| ≤ 2σ 95 % of the time.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Sequence
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from glmav_observer.estimation.aero.floor import (
    FloorModel,
    median_abs_error_mps,
    sigma_after_loss_mps,
)
from glmav_testkit.ardupilot_floor import (
    LawMisfit,
    ardupilot_floor_model,
    as_flown_floor_model,
    causal_hand_over,
    height_above_start_m,
    law_misfit_ne_mps,
    misfit_statistics,
    sidecar,
)

if TYPE_CHECKING:
    from benchmarks.aero import Flight

FloatArray = NDArray[np.float64]

#: the bounds of issue 32
FLOOR_APPLIES_BELOW = 0.5  # the floor's +60 s median below this × dead reckoning's
FLOOR_FACTOR = 1.5  # aided median ≤ this × the floor's
#: aided worse than dead reckoning: RMS over a loss above DR's by more than this, m/s (the
#: pseudo-measurement noise floor at which the two are indistinguishable)
WORSE_TOL_MPS = 0.02
COVER_MIN = 0.95  # fraction of the time |e| ≤ 2σ
#: the intervals over which the input's acceleration error is averaged, s, and the lags
#: (in intervals) whose difference variances separate its random walk from its white part
INPUT_ERROR_INTERVAL_S = 1.0
_LAG_SHORT = 1
_LAG_LONG = 30


def input_error_random_walk(fl: Flight) -> FloatArray:
    """Per NED axis, the random walk N_b (m/s³/√Hz) of the error of the earth-frame
    acceleration the estimator integrates (``fl.a_ned_imu_mps2``) against the truth's
    (SIM_STATE's velocity differenced): over 1 s intervals d_k = mean error; a random walk
    b plus white noise w gives Var(d_{k+L} − d_k) = N_b² L T + 2σ_w², so N_b² =
    (V_30 − V_1)/(29 T). (A drift that follows the manoeuvres counts as random walk: the
    oracle is granted its statistics, not its values.)"""
    t = fl.t_imu_s
    dt = np.diff(t, prepend=t[0])
    a_int = np.cumsum(fl.a_ned_imu_mps2 * dt[:, None], axis=0)
    t0 = max(float(t[0]), float(fl.t_truth_s[0])) + 1.0
    t1 = min(float(t[-1]), float(fl.t_truth_s[-1])) - 1.0
    edges = np.arange(t0, t1, INPUT_ERROR_INTERVAL_S)
    a_at = np.column_stack([np.interp(edges, t, a_int[:, i]) for i in range(3)])
    v_at = np.column_stack(
        [np.interp(edges, fl.t_truth_s, fl.v_truth_ned_mps[:, i]) for i in range(3)]
    )
    d = (np.diff(a_at, axis=0) - np.diff(v_at, axis=0)) / INPUT_ERROR_INTERVAL_S
    if len(d) <= _LAG_LONG:
        raise ValueError(f"{fl.name}: too short to measure its input's error")
    v_s = np.var(d[_LAG_SHORT:] - d[:-_LAG_SHORT], axis=0)
    v_l = np.var(d[_LAG_LONG:] - d[:-_LAG_LONG], axis=0)
    q_b = (v_l - v_s) / ((_LAG_LONG - _LAG_SHORT) * INPUT_ERROR_INTERVAL_S)
    out: FloatArray = np.sqrt(np.maximum(q_b, 0.0))
    return out


def _truth_at_velocity(fl: Flight) -> FloatArray:
    """The truth's NED velocity at the velocity samples' times (linear interpolation)."""
    out: FloatArray = np.column_stack(
        [np.interp(fl.t_vel_s, fl.t_truth_s, fl.v_truth_ned_mps[:, i]) for i in range(3)]
    )
    return out


def velocity_sigma_mps(fl: Flight) -> FloatArray:
    """Per NED axis, the RMS of the measured velocity against the truth (the healthy
    oracle's measurement noise)."""
    out: FloatArray = np.sqrt(np.mean((fl.v_meas_ned_mps - _truth_at_velocity(fl)) ** 2, axis=0))
    return out


@cache
def _sigmas(m: FloorModel, aided: bool, horizon_s: float) -> tuple[float, float]:
    s10, s60 = sigma_after_loss_mps(m, np.array([10.0, horizon_s]), aided=aided)
    return float(s10), float(s60)


def floor_of_case(
    fl: Flight, case: dict[str, Any], horizon_s: float, sidecar_dir: Path | None
) -> dict[str, float]:
    """The floor's σ and median at +10 s and +``horizon_s`` for one loss of
    ``benchmarks.aero`` (``case`` as its ``run_case`` returns it)."""
    axis = "ned".index(str(case["axis"]))
    aided = axis != 2
    as_flown: FloorModel | None = None
    misfit: LawMisfit | None = None
    if fl.source.startswith("glmav-sitl"):
        m = _sitl_model(str(fl.name).removesuffix(" +cyclic"), axis)
    else:
        if sidecar_dir is None:
            raise ValueError(f"{fl.name}: no sidecar directory for its floor")
        meta = _sidecar(sidecar_dir / f"{fl.name}.json")
        span = float(fl.t_vel_s[-1] - fl.t_vel_s[0])
        imu_span = float(fl.t_imu_s[-1] - fl.t_imu_s[0])
        m = ardupilot_floor_model(
            meta,
            float(case["t_loss_s"]),
            horizon_s,
            velocity_rate_hz=(len(fl.t_vel_s) - 1) / span,
            imu_rate_hz=(len(fl.t_imu_s) - 1) / imu_span,
            velocity_sigma_mps=float(_flight_stats(fl)[1][axis]),
            input_bias_random_walk=float(_flight_stats(fl)[0][axis]),
        )
        if aided:
            misfit = _misfit(fl, meta)[axis]
            as_flown = as_flown_floor_model(m, misfit)
    s10, s60 = _sigmas(m, aided, horizon_s)
    # glmav-sitl and d: the as-flown floor is the oracle's (the module docstring)
    a10, a60 = (s10, s60) if as_flown is None else _sigmas(as_flown, aided, horizon_s)
    c10, c60 = a10, a60
    causal: LawMisfit | None = None
    if as_flown is not None and misfit is not None:
        causal = _causal_misfit(fl, meta, float(case["t_loss_s"]), horizon_s)[axis]
        if causal is None:  # no law before the loss: the oracle can only dead-reckon
            c10, c60 = _sigmas(m, False, horizon_s)
        else:
            cm = as_flown_floor_model(m, causal)
            c10, c60 = (
                float(x)
                for x in sigma_after_loss_mps(
                    cm,
                    np.array([10.0, horizon_s]),
                    p0=causal_hand_over(cm, misfit.slow_sigma_mps),
                )
            )
    return {
        "floor_sigma10_mps": s10,
        "floor_sigma60_mps": s60,
        "floor_median10_mps": median_abs_error_mps(s10),
        "floor_median60_mps": median_abs_error_mps(s60),
        "floor_drag_sigma_mps": m.drag_sigma_mps,
        "floor_input_random_walk": m.accel_bias_random_walk,
        "asflown_median10_mps": median_abs_error_mps(a10),
        "asflown_median60_mps": median_abs_error_mps(a60),
        "misfit_white_sigma_mps": math.nan if misfit is None else misfit.white_sigma_mps,
        "misfit_slow_sigma_mps": math.nan if misfit is None else misfit.slow_sigma_mps,
        "misfit_slow_tau_s": math.nan if misfit is None else misfit.slow_tau_s,
        "causal_median10_mps": median_abs_error_mps(c10),
        "causal_median60_mps": median_abs_error_mps(c60),
        "causal_slow_sigma_mps": math.nan if causal is None else causal.slow_sigma_mps,
        "causal_slow_tau_s": math.nan if causal is None else causal.slow_tau_s,
    }


#: per-flight caches, keyed by :func:`_flight_key` (not ``id``: a flight freed and another
#: built at the same address would read the first one's figures)
_MISFITS: dict[tuple[str, str], tuple[LawMisfit, LawMisfit]] = {}
_CAUSAL: dict[tuple[str, str, float, float], tuple[LawMisfit | None, LawMisfit | None]] = {}


def _flight_key(fl: Flight) -> tuple[str, str]:
    """A flight's identity across the objects built from it: its source and name (one
    recording each; glmav-sitl flights have no sidecar and are not cached here)."""
    return fl.source, str(fl.name)


def _law_misfit(
    fl: Flight, meta: dict[str, Any], fit_mask: NDArray[np.bool_] | None = None
) -> tuple[NDArray[np.bool_], FloatArray]:
    """``law_misfit_ne_mps`` on an ArduPilot flight: the truth's velocity at the velocity
    samples' times, its height from the truth's down velocity."""
    t = fl.t_vel_s
    h = np.interp(t, fl.t_truth_s, height_above_start_m(fl.t_truth_s, fl.v_truth_ned_mps[:, 2]))
    return law_misfit_ne_mps(
        meta,
        t,
        v_truth_ned_mps=_truth_at_velocity(fl),
        height_m=h,
        e_body_to_ned=fl.E_vel,
        f_mean_body_mps2=fl.f_mean_body_mps2,
        fit_mask=fit_mask,
    )


def _misfit(fl: Flight, meta: dict[str, Any]) -> tuple[LawMisfit, LawMisfit]:
    """The drag law's misfit statistics on n and e of an ArduPilot flight (the law fitted
    over its airborne samples, the statistics read over them, their mean removed)."""
    key = _flight_key(fl)
    if key not in _MISFITS:
        ok, err = _law_misfit(fl, meta)
        dt = float(np.median(np.diff(fl.t_vel_s)))
        _MISFITS[key] = (misfit_statistics(err[ok, 0], dt), misfit_statistics(err[ok, 1], dt))
    return _MISFITS[key]


def _causal_misfit(
    fl: Flight, meta: dict[str, Any], t_loss_s: float, horizon_s: float
) -> tuple[LawMisfit | None, LawMisfit | None]:
    """The causal floor's misfit on n and e for a loss at ``t_loss_s``: the law fitted on
    the airborne samples before the loss only, its misfit's statistics read over the
    loss's window with its mean kept (what the law is off by after the loss, which the
    healthy filter could not see). None: fewer than MIN_FIT_SAMPLES airborne samples
    before the loss, no law to aid with."""
    key = (*_flight_key(fl), t_loss_s, horizon_s)
    if key not in _CAUSAL:
        t = fl.t_vel_s
        before = t < t_loss_s
        try:
            ok, err = _law_misfit(fl, meta, fit_mask=before)
        except ValueError:
            _CAUSAL[key] = (None, None)
            return _CAUSAL[key]
        window = ok & (t >= t_loss_s) & (t <= t_loss_s + horizon_s)
        dt = float(np.median(np.diff(t)))
        _CAUSAL[key] = (
            misfit_statistics(err[window, 0], dt, keep_mean=True),
            misfit_statistics(err[window, 1], dt, keep_mean=True),
        )
    return _CAUSAL[key]


_STATS: dict[tuple[str, str], tuple[FloatArray, FloatArray]] = {}


def _flight_stats(fl: Flight) -> tuple[FloatArray, FloatArray]:
    key = _flight_key(fl)
    if key not in _STATS:
        _STATS[key] = (input_error_random_walk(fl), velocity_sigma_mps(fl))
    return _STATS[key]


@cache
def _sidecar(path: Path) -> dict[str, Any]:
    return sidecar(path)


@cache
def _sitl_model(label: str, axis: int) -> FloorModel:
    """glmav-sitl's floor model of a flight labelled ``scenario/profile``."""
    from glmav_sitl.scenario import load_scenario
    from glmav_testkit.aero_floor import sitl_floor_model

    scenario, profile = label.split("/")
    sc = dataclasses.replace(load_scenario(scenario), sensor_profile=profile)
    return sitl_floor_model(sc, axis)


#: the floors each loss is judged against: (the tables' label, the case's key prefix)
FLOORS: tuple[tuple[str, str], ...] = (
    ("floor", "floor"),
    ("as-flown", "asflown"),
    ("causal", "causal"),
)


def _against(label: str, f10: float, f60: float, med: dict[str, float]) -> dict[str, Any]:
    """One floor's columns of a flight-axis: its medians, whether the bound applies (its
    +60 s median below ``FLOOR_APPLIES_BELOW`` × dead reckoning's), the aided medians over
    it and whether the bound is met."""
    applies = f60 < FLOOR_APPLIES_BELOW * med["err60_dr_mps"]
    r10 = _ratio(med["err10_aided_mps"], f10)
    r60 = _ratio(med["err60_aided_mps"], f60)
    return {
        f"{label} +10": f10,
        f"{label} +60": f60,
        f"{label} applies": applies,
        f"aided/{label} +10": r10,
        f"aided/{label} +60": r60,
        f"{label} bound met": (not applies) or (r10 <= FLOOR_FACTOR and r60 <= FLOOR_FACTOR),
    }


def judge_groups(cases: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per flight and axis (its losses): the floors, dead reckoning and aided side by side,
    and the bounds against each floor (:func:`_against`)."""
    keys = sorted({(str(c["set"]), str(c["flight"]), str(c["axis"])) for c in cases})
    out = []
    for set_name, flight, axis in keys:
        cs = [c for c in cases if (c["set"], c["flight"], c["axis"]) == (set_name, flight, axis)]
        med = {
            k: statistics.median(float(c[k]) for c in cs)
            for k in (
                "err10_dr_mps",
                "err10_aided_mps",
                "err60_dr_mps",
                "err60_aided_mps",
                *(f"{p}_median{h}_mps" for _, p in FLOORS for h in (10, 60)),
            )
        }
        row: dict[str, Any] = {
            "set": set_name,
            "flight": flight,
            "axis": axis,
            "losses": len(cs),
            "DR +10": med["err10_dr_mps"],
            "aided +10": med["err10_aided_mps"],
            "DR +60": med["err60_dr_mps"],
            "aided +60": med["err60_aided_mps"],
            "DR RMS": statistics.median(float(c["rms_dr_mps"]) for c in cs),
            "aided RMS": statistics.median(float(c["rms_aided_mps"]) for c in cs),
            "cover DR": statistics.fmean(float(c["cover2_dr"]) for c in cs),
            "cover aided": statistics.fmean(float(c["cover2_aided"]) for c in cs),
            "aided > 50 %": sum(float(c["aided_fraction"]) > 0.5 for c in cs),
            "worse than DR": sum(
                float(c["rms_aided_mps"]) > float(c["rms_dr_mps"]) + WORSE_TOL_MPS for c in cs
            ),
        }
        for label, p in FLOORS:
            row |= _against(label, med[f"{p}_median10_mps"], med[f"{p}_median60_mps"], med)
        out.append(row)
    return out


def _ratio(a: float, b: float) -> float:
    """a/b, ∞ for a floor of 0 (a calm glmav-sitl flight: nothing but the model limits)."""
    return a / b if b > 0.0 else math.inf


#: the tables' columns, in order (the JSON is written with its keys sorted)
GROUP_KEYS: tuple[str, ...] = (
    "set",
    "flight",
    "axis",
    "losses",
    "floor +10",
    "DR +10",
    "aided +10",
    "floor +60",
    "DR +60",
    "aided +60",
    "DR RMS",
    "aided RMS",
    "cover DR",
    "cover aided",
    "aided > 50 %",
    "floor applies",
    "aided/floor +10",
    "aided/floor +60",
    "floor bound met",
    "as-flown +10",
    "as-flown +60",
    "as-flown applies",
    "aided/as-flown +10",
    "aided/as-flown +60",
    "as-flown bound met",
    "causal +10",
    "causal +60",
    "causal applies",
    "aided/causal +10",
    "aided/causal +60",
    "causal bound met",
    "worse than DR",
)
SET_KEYS: tuple[str, ...] = (
    "set",
    "losses",
    "aided > 50 %",
    "floor applies (flight-axes)",
    "floor bound met",
    "aided/floor +60, median",
    "as-flown applies (flight-axes)",
    "as-flown bound met",
    "aided/as-flown +60, median",
    "causal applies (flight-axes)",
    "causal bound met",
    "aided/causal +60, median",
    "worse than DR",
    "worst RMS excess",
    "cover aided",
    "cover DR",
    "losses cover < 0.95",
)


def judge_sets(
    cases: Sequence[dict[str, Any]], groups: Sequence[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Per set: how many flight-axes each floor's bound applies to and meets, the losses
    worse than dead reckoning, σ coverage over all the time of its losses."""
    out = []
    for set_name in sorted({str(c["set"]) for c in cases}):
        cs = [c for c in cases if c["set"] == set_name]
        gs = [g for g in groups if g["set"] == set_name]
        worse = [float(c["rms_aided_mps"]) - float(c["rms_dr_mps"]) for c in cs]
        row: dict[str, Any] = {
            "set": set_name,
            "losses": len(cs),
            "aided > 50 %": sum(float(c["aided_fraction"]) > 0.5 for c in cs),
        }
        for label, _ in FLOORS:
            app = [g for g in gs if g[f"{label} applies"]]
            row |= {
                f"{label} applies (flight-axes)": f"{len(app)}/{len(gs)}",
                f"{label} bound met": sum(bool(g[f"{label} bound met"]) for g in app),
                f"aided/{label} +60, median": (
                    statistics.median(float(g[f"aided/{label} +60"]) for g in app)
                    if app
                    else math.nan
                ),
            }
        row |= {
            "worse than DR": sum(w > WORSE_TOL_MPS for w in worse),
            "worst RMS excess": max(worse),
            "cover aided": statistics.fmean(float(c["cover2_aided"]) for c in cs),
            "cover DR": statistics.fmean(float(c["cover2_dr"]) for c in cs),
            "losses cover < 0.95": sum(float(c["cover2_aided"]) < COVER_MIN for c in cs),
        }
        out.append(row)
    return out
