"""The state a taken-over vehicle's estimator continues from (``serve --claim``).

Another service's last published state of the vehicle (:class:`EstimatorSeed`, read
from its state queryable by :mod:`glmav_observer.fleet.handover`) seeds the new owner's
:class:`~glmav_observer.estimation.vehicle.VehicleEstimator`: every configuration starts
from its last estimate, isolated axes stay isolated with σ growing from where it was, and
the FDI's reference fit starts from b̂, δψ̂, d̂ and their σ. This module holds the seed and
the pure parts of applying it; the estimator applies it at its first usable sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from glmav_observer.estimation.fdi_reference import Integrals, Reference, dead_reckoning_age_s
from glmav_observer.estimation.fdi_types import FdiConfig
from glmav_observer.records import FaultEvent, ReferenceFitSummary

Vec3 = tuple[float, float, float]

#: The oldest state (vehicle s between its estimates and the first sample it is applied
#: at) a vehicle taken over is continued from (:meth:`VehicleEstimator.seed`). The new
#: owner has none of the IMU between the two: a measured axis converges again at rate γ
#: anyway, but a dead-reckoned (isolated) axis keeps the velocity change of that interval
#: as its error, |∫ V̇ dt| ≤ max|V̇| · age (0.2 m/s at 0.1 m/s² in a hover); an older
#: state starts cold from the measurement.
SEED_MAX_AGE_S = 2.0

#: A seed is a hypothesis (issue 31 D1: a peer's false state was continued for a whole
#: flight): every velocity measurement within this many vehicle seconds of the seed's
#: application is compared with the seeded active estimate (:func:`seed_disagreement`).
SEED_CHECK_S = 1.0
#: The gate, in σ of the innovation ν = y − v̂ per NED axis, with
#: σ² = σ_meas² + σ_handover² + (A · (age + max_lag))²: the measurement's noise, the
#: hand-over's own σ, and the velocity change nobody integrated: the seed's age (the new
#: owner has no IMU between the state and its first sample) plus the measurement's lag
#: (up to ``max_lag_s``), at A = ``SEED_CHECK_ACCEL_MPS2``. 5σ: a Gaussian axis exceeds
#: it with probability 6e-7, so a true state is almost never refused, and a refusal only
#: costs what every takeover cost before seeds (a cold start from the measurement). Every
#: axis is checked, an isolated one too (a false isolation is how a forged state keeps
#: its lie, D1); a genuine fault larger than the gate at the takeover starts cold.
SEED_GATE_SIGMA = 5.0
#: 1σ of the mean acceleration a vehicle may have had, unseen, over the seed's age and the
#: measurement's lag, m/s² (3σ = 3 m/s²: a brisk manoeuvre of a small multirotor).
SEED_CHECK_ACCEL_MPS2 = 1.0


def seed_disagreement(
    innovation_mps: Vec3, age_s: float, fdi: FdiConfig
) -> tuple[int, float, float] | None:
    """The first NED axis whose innovation exceeds the gate: ``(axis, |ν|, gate)`` in
    m/s; None when the measurement agrees with the seed (see :data:`SEED_GATE_SIGMA`)."""
    unseen = SEED_CHECK_ACCEL_MPS2 * (max(age_s, 0.0) + fdi.max_lag_s)
    sigma = math.sqrt(fdi.sigma_meas_mps**2 + fdi.sigma_handover_mps**2 + unseen**2)
    gate = SEED_GATE_SIGMA * sigma
    for j, nu in enumerate(innovation_mps):
        if not abs(nu) <= gate:  # (NaN: disagrees)
            return j, abs(nu), gate
    return None


@dataclass(frozen=True, slots=True)
class EstimatorSeed:
    """The last state another service published of a vehicle it estimated (its state
    queryable and health, docs/zenoh.md), to continue from on a ``serve --claim`` takeover."""

    t_boot_s: float  # vehicle time of the estimates
    #: NED velocity per configuration (``full``, ``c1``, ``c2``, ``c3``) and ``active``
    v_ned_mps: Mapping[str, Vec3]
    active_config: str
    #: 1σ of each dead-reckoned axis (per configuration and ``active``, where one is lost)
    sigma_lost_mps: Mapping[str, float] = field(default_factory=dict)
    #: the velocity axes isolated at ``t_boot_s`` (not ``accel_bias`` events)
    isolated: tuple[FaultEvent, ...] = ()
    #: the health record's residual per NED axis: an isolated axis's fault level
    residual_ned_mps: Vec3 = (0.0, 0.0, 0.0)
    reference_fit: ReferenceFitSummary | None = None

    def dead_reckoning_start_s(self, key: str, fdi: FdiConfig, t_default: float) -> float:
        """The start of the dead reckoning of ``key`` (a configuration or ``active``) whose
        σ was ``sigma_lost_mps[key]`` at the seed's time; ``t_default`` without one."""
        sigma = self.sigma_lost_mps.get(key)
        if sigma is None or not math.isfinite(sigma):
            return t_default
        return self.t_boot_s - dead_reckoning_age_s(fdi, sigma)


def seed_reference(
    fit: ReferenceFitSummary, active_v: Vec3, ints: Integrals, sigma_handover_mps: float
) -> tuple[Reference, tuple[float, ...], tuple[float, ...]]:
    """The FDI's reference fit restarted from a seed's summary at the integrals ``ints``:
    θ = (v, b̂, δψ̂, d̂) with the seed's σ (the hand-over σ on v); (reference, θ, σ)."""
    theta = (*active_v, *fit.accel_bias_body_mps2, fit.heading_error_rad, fit.measurement_lag_s)
    sig_v = sigma_handover_mps
    sig = (
        sig_v, sig_v, sig_v, *fit.accel_bias_sigma_mps2,
        fit.heading_error_sigma_rad, fit.measurement_lag_sigma_s,
    )  # fmt: skip
    b_int, c_int, _ = ints
    cov = np.diag(np.square(np.maximum(np.asarray(sig, dtype=np.float64), 1e-6)))
    ref = Reference(tuple(float(x) for x in theta), cov, b_int, (c_int[0], c_int[1], c_int[2]))
    return ref, theta, sig
