"""The GPS receiver's latency, estimated from the log itself when no parameter gives it.

A receiver's velocity describes the vehicle 0.1-0.3 s before the autopilot logs it
(``EK3_GPS_DELAY``/``EKF2_GPS_DELAY`` model the same lag). Over each interval between two
GPS samples, the change of the GPS velocity must equal the integral of the earth-frame
acceleration ``E f + g e_d`` (V̇ = E Γ) over the same interval shifted back by the delay τ:

    Δv_gps,i = ∫_{t_{i−1}−τ}^{t_i−τ} (E f + g e_d) dt + b Δt_i + noise

(b: an accelerometer bias in the earth frame, fitted per axis). The estimate is the τ on a
10 ms grid over [0, 0.5] s that minimises the squared mismatch, refined by a parabola
through the grid minimum and its neighbours. It needs motion: when the mismatch curve is
flat (the best τ explains less than ``MIN_EXPLAINED`` of the variation between the best and
the worst τ, or the GPS velocity barely changes) the delay is not estimable and
:func:`estimate_gps_delay_s` returns None.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glmav_observer.frames import G_MPS2, e_exact
from glmav_observer.ingest.logfiles.streams import F64, interp_euler

MAX_DELAY_S = 0.5
STEP_S = 0.01
#: The GPS velocity must change by more than this (RMS of Δv between samples, m/s) to
#: carry information on the delay (the ArduCopter SITL log's take-off and landing: 0.048).
MIN_EXCITATION_MPS = 0.02
#: (worst − best) / worst cost: the best τ must remove at least this share of the worst
#: τ's mismatch, else the curve is too flat to locate a minimum (ArduCopter SITL log:
#: 0.91, a clear minimum; the PX4 SITL log, whose GPS velocity is mostly noise: 0.16).
MIN_EXPLAINED = 0.5


@dataclass(frozen=True, slots=True)
class DelayEstimate:
    delay_s: float
    cost_best: float
    cost_worst: float
    intervals: int


def earth_acceleration_mps2(t_imu: F64, f_body: F64, t_att: F64, euler: F64) -> F64:
    """V̇ = E f + g e_d at the IMU times, E from the attitude interpolated there."""
    E = e_exact(interp_euler(t_imu, t_att, euler))
    a: F64 = np.einsum("nij,nj->ni", E, f_body)
    a[:, 2] += G_MPS2
    return a


def estimate_gps_delay_s(
    t_imu: F64, a_ned_mps2: F64, t_gps: F64, v_gps_ned_mps: F64
) -> DelayEstimate | None:
    """The delay τ (s) that best aligns the GPS velocity with the integrated IMU, or None."""
    if len(t_gps) < 10 or len(t_imu) < 10:
        return None
    # cumulative integral of the acceleration at the IMU times (trapezoid)
    dt = np.diff(t_imu)
    v_int = np.concatenate(
        [
            [[0.0, 0.0, 0.0]],
            np.cumsum(0.5 * (a_ned_mps2[1:] + a_ned_mps2[:-1]) * dt[:, None], axis=0),
        ]
    )
    dtg = np.diff(t_gps)
    dv_gps = np.diff(v_gps_ned_mps, axis=0)
    med = float(np.median(dtg)) if len(dtg) else 0.0
    # intervals fully inside the IMU record for every τ, no gaps
    ok = (
        (dtg > 0)
        & (dtg < 2.5 * med)
        & (t_gps[:-1] - MAX_DELAY_S >= t_imu[0])
        & (t_gps[1:] <= t_imu[-1])
    )
    if ok.sum() < 10:
        return None
    dv_gps, dtg, t0, t1 = dv_gps[ok], dtg[ok], t_gps[:-1][ok], t_gps[1:][ok]
    if float(np.sqrt(np.mean(np.sum(dv_gps**2, axis=1)))) < MIN_EXCITATION_MPS:
        return None
    taus = np.arange(0.0, MAX_DELAY_S + 0.5 * STEP_S, STEP_S)
    costs = np.empty(len(taus))
    for k, tau in enumerate(taus):
        v0 = np.stack([np.interp(t0 - tau, t_imu, v_int[:, j]) for j in range(3)], axis=1)
        v1 = np.stack([np.interp(t1 - tau, t_imu, v_int[:, j]) for j in range(3)], axis=1)
        r = dv_gps - (v1 - v0)
        b = (r * dtg[:, None]).sum(axis=0) / float((dtg**2).sum())  # bias, per axis
        costs[k] = float(((r - b * dtg[:, None]) ** 2).sum())
    i = int(np.argmin(costs))
    worst = float(costs.max())
    if worst <= 0 or (worst - costs[i]) / worst < MIN_EXPLAINED:
        return None
    tau_best = float(taus[i])
    if 0 < i < len(taus) - 1:  # parabola through the minimum and its neighbours
        c0, c1, c2 = costs[i - 1], costs[i], costs[i + 1]
        den = c0 - 2 * c1 + c2
        if den > 0:
            tau_best += STEP_S * 0.5 * float(c0 - c2) / float(den)
    return DelayEstimate(tau_best, float(costs[i]), worst, int(ok.sum()))
