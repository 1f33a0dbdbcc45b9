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


_MISFITS: dict[int, tuple[LawMisfit, LawMisfit]] = {}
_CAUSAL: dict[tuple[int, float, float], tuple[LawMisfit | None, LawMisfit | None]] = {}


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
    key = id(fl)
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
    key = (id(fl), t_loss_s, horizon_s)
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


_STATS: dict[int, tuple[FloatArray, FloatArray]] = {}


def _flight_stats(fl: Flight) -> tuple[FloatArray, FloatArray]:
    key = id(fl)
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


def judge_groups(cases: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per flight and axis (its losses): floor, dead reckoning and aided side by side, and
    the bounds. ``floor_applies``: the floor's +60 s median below half of dead
    reckoning's; ``ratio10``, ``ratio60``: aided median over the floor's."""
    keys = sorted({(str(c["set"]), str(c["flight"]), str(c["axis"])) for c in cases})
    out = []
    for set_name, flight, axis in keys:
        cs = [c for c in cases if (c["set"], c["flight"], c["axis"]) == (set_name, flight, axis)]
        med = {
            k: statistics.median(float(c[k]) for c in cs)
            for k in (
                "floor_median10_mps",
                "floor_median60_mps",
                "err10_dr_mps",
                "err10_aided_mps",
                "err60_dr_mps",
                "err60_aided_mps",
                "asflown_median10_mps",
                "asflown_median60_mps",
                "causal_median10_mps",
                "causal_median60_mps",
            )
        }
        applies = med["floor_median60_mps"] < FLOOR_APPLIES_BELOW * med["err60_dr_mps"]
        r10 = _ratio(med["err10_aided_mps"], med["floor_median10_mps"])
        r60 = _ratio(med["err60_aided_mps"], med["floor_median60_mps"])
        af_applies = med["asflown_median60_mps"] < FLOOR_APPLIES_BELOW * med["err60_dr_mps"]
        af10 = _ratio(med["err10_aided_mps"], med["asflown_median10_mps"])
        af60 = _ratio(med["err60_aided_mps"], med["asflown_median60_mps"])
        ca_applies = med["causal_median60_mps"] < FLOOR_APPLIES_BELOW * med["err60_dr_mps"]
        ca10 = _ratio(med["err10_aided_mps"], med["causal_median10_mps"])
        ca60 = _ratio(med["err60_aided_mps"], med["causal_median60_mps"])
        out.append(
            {
                "set": set_name,
                "flight": flight,
                "axis": axis,
                "losses": len(cs),
                "floor +10": med["floor_median10_mps"],
                "DR +10": med["err10_dr_mps"],
                "aided +10": med["err10_aided_mps"],
                "floor +60": med["floor_median60_mps"],
                "DR +60": med["err60_dr_mps"],
                "aided +60": med["err60_aided_mps"],
                "DR RMS": statistics.median(float(c["rms_dr_mps"]) for c in cs),
                "aided RMS": statistics.median(float(c["rms_aided_mps"]) for c in cs),
                "cover DR": statistics.fmean(float(c["cover2_dr"]) for c in cs),
                "cover aided": statistics.fmean(float(c["cover2_aided"]) for c in cs),
                "aided > 50 %": sum(float(c["aided_fraction"]) > 0.5 for c in cs),
                "floor applies": applies,
                "aided/floor +10": r10,
                "aided/floor +60": r60,
                "floor bound met": (not applies) or (r10 <= FLOOR_FACTOR and r60 <= FLOOR_FACTOR),
                "as-flown +10": med["asflown_median10_mps"],
                "as-flown +60": med["asflown_median60_mps"],
                "as-flown applies": af_applies,
                "aided/as-flown +10": af10,
                "aided/as-flown +60": af60,
                "as-flown bound met": (not af_applies)
                or (af10 <= FLOOR_FACTOR and af60 <= FLOOR_FACTOR),
                "causal +10": med["causal_median10_mps"],
                "causal +60": med["causal_median60_mps"],
                "causal applies": ca_applies,
                "aided/causal +10": ca10,
                "aided/causal +60": ca60,
                "causal bound met": (not ca_applies)
                or (ca10 <= FLOOR_FACTOR and ca60 <= FLOOR_FACTOR),
                "worse than DR": sum(
                    float(c["rms_aided_mps"]) > float(c["rms_dr_mps"]) + WORSE_TOL_MPS for c in cs
                ),
            }
        )
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
    """Per set: how many flight-axes the floor bound applies to and meets, the losses worse
    than dead reckoning, σ coverage over all the time of its losses."""
    out = []
    for set_name in sorted({str(c["set"]) for c in cases}):
        cs = [c for c in cases if c["set"] == set_name]
        gs = [g for g in groups if g["set"] == set_name]
        app = [g for g in gs if g["floor applies"]]
        af = [g for g in gs if g["as-flown applies"]]
        ca = [g for g in gs if g["causal applies"]]
        worse = [float(c["rms_aided_mps"]) - float(c["rms_dr_mps"]) for c in cs]
        cover = statistics.fmean(float(c["cover2_aided"]) for c in cs)
        out.append(
            {
                "set": set_name,
                "losses": len(cs),
                "aided > 50 %": sum(float(c["aided_fraction"]) > 0.5 for c in cs),
                "floor applies (flight-axes)": f"{len(app)}/{len(gs)}",
                "floor bound met": sum(bool(g["floor bound met"]) for g in app),
                "aided/floor +60, median": (
                    statistics.median(float(g["aided/floor +60"]) for g in app) if app else math.nan
                ),
                "as-flown applies (flight-axes)": f"{len(af)}/{len(gs)}",
                "as-flown bound met": sum(bool(g["as-flown bound met"]) for g in af),
                "aided/as-flown +60, median": (
                    statistics.median(float(g["aided/as-flown +60"]) for g in af)
                    if af
                    else math.nan
                ),
                "causal applies (flight-axes)": f"{len(ca)}/{len(gs)}",
                "causal bound met": sum(bool(g["causal bound met"]) for g in ca),
                "aided/causal +60, median": (
                    statistics.median(float(g["aided/causal +60"]) for g in ca) if ca else math.nan
                ),
                "worse than DR": sum(w > WORSE_TOL_MPS for w in worse),
                "worst RMS excess": max(worse),
                "cover aided": cover,
                "cover DR": statistics.fmean(float(c["cover2_dr"]) for c in cs),
                "losses cover < 0.95": sum(float(c["cover2_aided"]) < COVER_MIN for c in cs),
            }
        )
    return out
