"""Error against truth and fault-isolation scoring, in one place.

One definition of "error against truth" for everything that reports one (the service's
summary, the Rerun sink's error plots, the corpus tests, the benchmarks): an estimate
published at vehicle time t is compared with the truth (``SIM_STATE``) linearly
interpolated at t; estimates outside the truth's time span, between truth samples more
than :data:`TRUTH_MAX_GAP_S` apart, or earlier than ``skip_s`` after the first estimate,
are not scored. Batch form :func:`errors_against_truth`, online form
:class:`TruthScorer`, the interpolation itself :func:`interpolate_truth`.

A layer just above the records (it imports nothing else of the service): a vehicle's
estimator (``VehicleEstimator(score_truth=True)``, as the service makes them) starts a
:class:`TruthScorer` at its first truth sample and hands it every estimate of every
configuration from then on, without building a record for it (:meth:`TruthScorer.
add_estimates`). Replaying logs with
injected faults, for the tests and benchmarks, is the test kit's
(``glmav_testkit.fault_replay``).
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from glmav_observer.records import Record, TruthRecord, VelocityRecord

Vec3 = tuple[float, float, float]
FloatArray = np.ndarray[Any, np.dtype[np.float64]]

#: Truth samples further apart than this are not interpolated between (a truth dropout):
#: SIM_STATE comes at 50 Hz (0.02 s) from both simulators, with jitter to 0.03 s.
TRUTH_MAX_GAP_S = 0.1


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
        #: estimates waiting for the truth sample after them: (t, configurations, NED v)
        self._pending: collections.deque[tuple[float, Sequence[str], Sequence[Vec3]]] = (
            collections.deque()
        )
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
        self.add_estimates(t_s, (config,), (v_ned_mps,))

    def add_estimates(self, t_s: float, configs: Sequence[str], v_ned_mps: Sequence[Vec3]) -> None:
        """Estimates of several configurations published at one time ``t_s`` (one step of
        the estimator: the same as :meth:`add_estimate` for each in turn, in one call)."""
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
                v_truth = b[1]
            elif a is not None and a[0] <= t_s and b[0] - a[0] <= self.max_gap_s:
                v_truth = _lerp(a, b, t_s)
            else:
                return
            score = self._score
            for config, v in zip(configs, v_ned_mps, strict=True):
                score(config, v, v_truth)
            return
        p = self._pending
        p.append((t_s, configs, v_ned_mps))
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
        score = self._score
        while p and p[0][0] <= t_s:
            te, configs, ves = p.popleft()
            if te == t_s:
                v_truth = v_ned_mps
            elif last is not None and last[0] <= te and t_s - last[0] <= self.max_gap_s:
                if te != t_lerp:  # the estimates of one step share their time
                    t_lerp, v_lerp = te, _lerp(last, new, te)
                v_truth = v_lerp
            else:
                continue
            for config, ve in zip(configs, ves, strict=True):
                score(config, ve, v_truth)
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
