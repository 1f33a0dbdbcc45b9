"""The table of configurations and what is derived from it."""

from __future__ import annotations

import numpy as np
import pytest

from glmav_observer.configurations import (
    CONFIG_MASKS,
    CONFIG_WITHOUT_AXIS,
    CONFIGS,
    CONFIGURATIONS,
    LOST_INDEX_OF_CONFIG,
    NED_AXES,
    config_index,
    output_matrix,
)
from glmav_observer.publish.rerun.paths import ISOLATED_AXIS_INDEX


def test_each_configuration_is_the_paper_s() -> None:
    # Koehl et al. (2011): C1 loses the down axis, C2 north, C3 east; full measures all
    assert CONFIGS == ("full", "c1", "c2", "c3")
    assert [c.lost_axis for c in CONFIGURATIONS] == [None, "d", "n", "e"]
    np.testing.assert_array_equal(output_matrix("c1"), [[1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(output_matrix("c2"), [[0, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(output_matrix("c3"), [[1, 0, 0], [0, 0, 1]])
    np.testing.assert_array_equal(output_matrix("full"), np.eye(3))


@pytest.mark.parametrize("config", CONFIGS)
def test_mask_output_matrix_and_lost_axis_are_one_fact(config: str) -> None:
    c = CONFIGURATIONS[config_index(config)]
    C = c.output_matrix()
    p = C.shape[0]
    np.testing.assert_array_equal(C @ C.T, np.eye(p))  # rows of the identity
    np.testing.assert_array_equal(C.T @ C, np.diag(CONFIG_MASKS[config_index(config)]))  # D
    assert p == 3 - (c.lost_axis is not None)
    if c.lost_axis is not None:
        j = NED_AXES.index(c.lost_axis)
        assert LOST_INDEX_OF_CONFIG[config] == j
        assert not C[:, j].any()  # the lost axis is in no row of C
        assert CONFIG_WITHOUT_AXIS[j] == config  # the hand-over target when j fails
    assert c.default_gamma_per_s > 0.0


def test_isolated_axis_codes_are_distinct() -> None:
    assert ISOLATED_AXIS_INDEX[None] == 0
    assert sorted(ISOLATED_AXIS_INDEX.values()) == list(range(len(NED_AXES) + 2))
    assert [ISOLATED_AXIS_INDEX[a] for a in NED_AXES] == [1, 2, 3]


def test_unknown_configuration_is_named() -> None:
    with pytest.raises(ValueError, match=r"unknown configuration 'c4'.*full"):
        config_index("c4")
