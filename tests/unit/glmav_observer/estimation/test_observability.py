"""The observability helper: the true O has rank 2 for c1..c3; the paper's Ω has rank 3."""

from __future__ import annotations

import numpy as np
import pytest

from glmav_observer.commands.check import exact_kinematics_scenario
from glmav_observer.estimation.observability import (
    observability_matrices,
    observability_rank,
    unobserved_direction_body,
)
from glmav_observer.frames import ShapeError, e_exact

LOST = {"c1": 2, "c2": 0, "c3": 1}
DT = 0.01
SC = exact_kinematics_scenario(np.arange(301) * DT)  # 3 s of exact kinematics from (48)


@pytest.mark.parametrize("config", ["c1", "c2", "c3"])
def test_true_rank_is_two_and_paper_rank_is_three(config: str) -> None:
    assert observability_rank(config, SC.euler_rad, SC.omega_body_radps, DT, "true") == 2
    assert observability_rank(config, SC.euler_rad, SC.omega_body_radps, DT, "interval") == 2
    assert observability_rank(config, SC.euler_rad, SC.omega_body_radps, DT, "paper") == 3
    obs = observability_matrices(config, SC.euler_rad, SC.omega_body_radps, DT, "true")
    # the second block Q̇ + Q A vanishes: finite-difference error ≈ Δt²|ω|³ ≲ 1e-5 here
    assert np.abs(obs[:, 2:, :]).max() < 1e-4
    # while the paper's C Ė is of the size of |ω| (≈ 0.2-0.4 rad/s in this scenario)
    P = observability_matrices(config, SC.euler_rad, SC.omega_body_radps, DT, "paper")
    assert np.abs(P[:, 2:, :]).max() > 0.1


@pytest.mark.parametrize("config", ["c1", "c2", "c3"])
def test_unobserved_direction_is_the_lost_earth_axis_in_body(config: str) -> None:
    d = unobserved_direction_body(config, SC.euler_rad, SC.omega_body_radps, DT)
    expected = e_exact(SC.euler_rad)[:, LOST[config], :]  # Eᵀ e_l
    # the null vector of O = [CE; ~0]: Eᵀe_l exactly, up to the ~1e-5 finite-difference block
    assert np.abs(d - expected).max() < 1e-5
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)


def test_paper_condition_26_holds_only_for_rotation_about_the_lost_axis() -> None:
    """Level, yaw rate only: ω_e is parallel to the down axis, which c1 loses; then C Ė has
    no component that reveals it and the paper's Ω has rank 2 as well."""
    t = np.arange(200) * DT
    euler = np.stack((np.zeros_like(t), np.zeros_like(t), 0.5 * t), axis=1)
    omega = np.tile([0.0, 0.0, 0.5], (t.size, 1))
    assert observability_rank("c1", euler, omega, DT, "paper") == 2
    assert observability_rank("c2", euler, omega, DT, "paper") == 3


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="no unobserved direction"):
        unobserved_direction_body("full", SC.euler_rad, SC.omega_body_radps, DT)
    with pytest.raises(ShapeError, match="omega_history_radps"):
        observability_rank("c1", SC.euler_rad, SC.omega_body_radps[:-1], DT)
    with pytest.raises(ShapeError, match="euler_history_rad"):
        observability_rank("c1", np.zeros((2, 3)), np.zeros((2, 3)), DT)
    with pytest.raises(ValueError, match="dt_s"):
        observability_rank("c1", SC.euler_rad, SC.omega_body_radps, 0.0)
    with pytest.raises(ValueError, match="form"):
        observability_rank("c1", SC.euler_rad, SC.omega_body_radps, DT, "nope")  # type: ignore[arg-type]
