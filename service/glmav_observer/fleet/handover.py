"""What a ``serve --claim`` service continues a taken-over vehicle from.

Every claiming service asks the others for the ``<prefix>/*/state`` of the vehicles it
hears but does not own, once per claim turn (:class:`~glmav_observer.fleet.claims.
ClaimManager`): the state queryable already holds, per vehicle, the latest velocity
record of every configuration and of ``active`` (with the dead-reckoned σ) and the latest
health record (active configuration, isolated faults, residuals, the FDI's reference
fit: b̂, δψ̂, d̂ with their σ). No new key: one query per turn, one reply per vehicle
and owner (about 3 kB of JSON). :func:`seed_from_state` turns the newest reply into the
:class:`~glmav_observer.estimation.vehicle.EstimatorSeed` the new owner's estimator
starts from (:meth:`~glmav_observer.estimation.vehicle.VehicleEstimator.seed`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from glmav_observer.estimation.fdi_types import FaultKind
from glmav_observer.estimation.seed import EstimatorSeed
from glmav_observer.records import CONFIGS, NED_AXES, FaultEvent, ReferenceFitSummary

#: The fault kinds that isolate a velocity axis (an ``accel_bias`` event isolates none).
VELOCITY_FAULT_KINDS = frozenset(k.value for k in FaultKind)


class HandoverError(ValueError):
    """A state payload that cannot seed an estimator (the message says what is missing)."""


def _num(x: Any) -> float:
    """A JSON number (null: NaN, JSON has none)."""
    if x is None:
        return math.nan
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise HandoverError(f"{x!r} is not a number")
    return float(x)


def _vec3(x: Any) -> tuple[float, float, float]:
    if not isinstance(x, list | tuple) or len(x) != 3:
        raise HandoverError(f"{x!r} is not a 3-vector")
    return (_num(x[0]), _num(x[1]), _num(x[2]))


def state_time_s(state: Mapping[str, Any]) -> float:
    """The vehicle time of a state payload's active estimate (NaN without one)."""
    try:
        return _num(state["velocity"]["active"]["t_boot_s"])
    except (KeyError, TypeError, HandoverError):
        return math.nan


def seed_from_state(state: Mapping[str, Any]) -> EstimatorSeed:
    """The seed in a ``glmav.state/1`` payload (docs/zenoh.md); :class:`HandoverError`
    if it has no active estimate or a malformed field."""
    try:
        return _seed(state)
    except (KeyError, TypeError) as err:
        raise HandoverError(f"state payload without {err}") from None


def _seed(state: Mapping[str, Any]) -> EstimatorSeed:
    velocity = state.get("velocity") or {}
    active = velocity.get("active")
    if not isinstance(active, Mapping):
        raise HandoverError("state payload without an active estimate")
    v_ned: dict[str, tuple[float, float, float]] = {}
    sigma: dict[str, float] = {}
    for name in (*CONFIGS, "active"):
        rec = velocity.get(name)
        if not isinstance(rec, Mapping):
            continue
        v_ned[name] = _vec3(rec["v_ned_mps"])
        if rec.get("sigma_lost_mps") is not None:
            sigma[name] = _num(rec["sigma_lost_mps"])
    health = state.get("health")
    if not isinstance(health, Mapping):
        return EstimatorSeed(
            _num(active["t_boot_s"]),
            v_ned,
            active.get("source_config") or "full",
            sigma,
        )
    isolated = tuple(
        FaultEvent(f["axis"], f["kind"], _num(f["t_detect_s"]), f.get("t_onset_s"))
        for f in health.get("isolated_faults") or ()
        if f.get("axis") in NED_AXES and f.get("kind") in VELOCITY_FAULT_KINDS
    )
    fit = health.get("reference_fit")
    summary = None
    if isinstance(fit, Mapping):
        summary = ReferenceFitSummary(
            _vec3(fit["accel_bias_body_mps2"]),
            _vec3(fit["accel_bias_sigma_mps2"]),
            _num(fit["heading_error_rad"]),
            _num(fit["heading_error_sigma_rad"]),
            _num(fit["measurement_lag_s"]),
            _num(fit["measurement_lag_sigma_s"]),
        )
        if not all(
            math.isfinite(x)
            for x in (
                *summary.accel_bias_body_mps2,
                *summary.accel_bias_sigma_mps2,
                summary.heading_error_rad,
                summary.heading_error_sigma_rad,
                summary.measurement_lag_s,
                summary.measurement_lag_sigma_s,
            )
        ):
            summary = None  # a fit with a hole is no prior: the config's priors instead
    return EstimatorSeed(
        _num(active["t_boot_s"]),
        v_ned,
        str(health.get("active_config") or active.get("source_config") or "full"),
        sigma,
        isolated,
        _vec3(health.get("residual_ned_mps") or [None, None, None]),
        summary,
    )
