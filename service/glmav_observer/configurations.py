"""The sensor-failure configurations of the observer bank: one table, everything else derived.

Koehl et al. (IFAC 2011) run the observer once per configuration: ``full`` measures the
three NED velocity axes, ``c1``, ``c2`` and ``c3`` have each lost one (down, north and east).
:data:`CONFIGURATIONS` is the only place that says so. The names and their order (the
bank's order), the lost axis, the measurement mask (which NED axes are measured, D = CᵀC =
diag(mask)), the output matrix C (the rows of the identity the mask selects, (18)), the
configuration that does without an axis (the hand-over target when that axis fails) and
the default gain γ are read from it by the records, the bank, the observer, the fault
isolation, the vehicle estimator and the Rerun view.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

AxisName = Literal["n", "e", "d"]
#: The earth-frame (NED) axes, in index order (0 north, 1 east, 2 down).
NED_AXES: tuple[AxisName, AxisName, AxisName] = ("n", "e", "d")


@dataclass(frozen=True, slots=True)
class Configuration:
    """One configuration of the bank.

    ``lost_axis``: the NED axis it does not measure (None for ``full``).
    ``default_gamma_per_s``: its observer gain γ (1/s) unless the service configuration says
    otherwise. c1..c3: the paper's (49). full: the minimiser of the steady error²
    (b/γ)² + γ σ_y²/(2 f) with accelerometer bias b = 0.2 m/s², velocity noise σ_y = 0.05
    m/s at f = 30 Hz (design.md): γ³ = 4 f b²/σ_y² → γ ≈ 12.4 (docs/design/observer-notes.md).
    """

    name: str
    lost_axis: AxisName | None
    default_gamma_per_s: float

    @property
    def lost_index(self) -> int | None:
        """Index (0 n, 1 e, 2 d) of the lost axis, None for ``full``."""
        return None if self.lost_axis is None else NED_AXES.index(self.lost_axis)

    @property
    def mask(self) -> tuple[bool, bool, bool]:
        """The measured NED axes (n, e, d)."""
        lost = self.lost_index
        return (lost != 0, lost != 1, lost != 2)

    def output_matrix(self) -> NDArray[np.float64]:
        """C: the rows of the identity of the measured axes, (3, 3) or (2, 3)."""
        return np.eye(3)[[i for i, m in enumerate(self.mask) if m]]


#: The configurations in bank order (design.md, "Estimation").
CONFIGURATIONS: tuple[Configuration, ...] = (
    Configuration("full", None, 12.0),  # C = I
    Configuration("c1", "d", 90.0),  # C1 = [[1,0,0],[0,1,0]], down lost
    Configuration("c2", "n", 70.0),  # C2 = [[0,1,0],[0,0,1]], north lost
    Configuration("c3", "e", 70.0),  # C3 = [[1,0,0],[0,0,1]], east lost
)

# ------------------------------------------------------------------ derived from the table

#: The configuration names in bank order.
CONFIGS: tuple[str, ...] = tuple(c.name for c in CONFIGURATIONS)
#: The estimate published beside the bank's while one axis is lost: the hand-over
#: configuration with that axis aided by the learnt drag model (estimation/aiding.py).
AIDED = "aided"
#: Name -> the NED axis it does not measure (None for ``full``).
LOST_AXIS_OF_CONFIG: dict[str, AxisName | None] = {c.name: c.lost_axis for c in CONFIGURATIONS}
#: Name -> the index of that axis (None for ``full``).
LOST_INDEX_OF_CONFIG: dict[str, int | None] = {c.name: c.lost_index for c in CONFIGURATIONS}
#: The configuration that does not use each NED axis (index 0 n, 1 e, 2 d): the hand-over
#: target when that axis is isolated.
CONFIG_WITHOUT_AXIS: tuple[str, str, str] = tuple(  # type: ignore[assignment]
    next(c.name for c in CONFIGURATIONS if c.lost_index == i) for i in range(3)
)
#: (4, 3) bool, bank order: which NED axes (n, e, d) each configuration measures.
CONFIG_MASKS: NDArray[np.bool_] = np.array([c.mask for c in CONFIGURATIONS], dtype=bool)
CONFIG_MASKS.setflags(write=False)
#: Name -> the default γ (1/s).
DEFAULT_GAMMA: dict[str, float] = {c.name: c.default_gamma_per_s for c in CONFIGURATIONS}


def config_index(name: str) -> int:
    """The bank index of a configuration; ``ValueError`` naming the known ones otherwise."""
    try:
        return CONFIGS.index(name)
    except ValueError:
        raise ValueError(f"unknown configuration {name!r}; expected one of {CONFIGS}") from None


def output_matrix(name: str) -> NDArray[np.float64]:
    """C of the configuration: identity (3, 3) for ``full``; C1, C2, C3 (2, 3) for c1..c3."""
    return CONFIGURATIONS[config_index(name)].output_matrix()
