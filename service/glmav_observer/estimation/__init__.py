"""Samples -> estimates: the paper's observer, the bank, fault isolation (numpy only, no I/O)."""

from glmav_observer.configurations import CONFIG_MASKS, DEFAULT_GAMMA, output_matrix
from glmav_observer.estimation.bank import BatchedBank, ObserverBank
from glmav_observer.estimation.observability import (
    observability_matrices,
    observability_rank,
    unobserved_direction_body,
)
from glmav_observer.estimation.observer import (
    G_MPS2,
    EForm,
    NonFiniteInputError,
    ObserverGains,
    a_matrix,
    e_matrix,
    e_small_angle,
    gamma_body_mps2,
    gravity_body_mps2,
    observer_gains,
    observer_rhs,
    zoh_step,
)
from glmav_observer.frames import ShapeError, e_exact

__all__ = [
    "CONFIG_MASKS",
    "DEFAULT_GAMMA",
    "G_MPS2",
    "BatchedBank",
    "EForm",
    "NonFiniteInputError",
    "ObserverBank",
    "ObserverGains",
    "ShapeError",
    "a_matrix",
    "e_exact",
    "e_matrix",
    "e_small_angle",
    "gamma_body_mps2",
    "gravity_body_mps2",
    "observability_matrices",
    "observability_rank",
    "observer_gains",
    "observer_rhs",
    "output_matrix",
    "unobserved_direction_body",
    "zoh_step",
]
