"""The column items the buffer hands to the sender (:mod:`.buffer` -> :mod:`.send`): one
``rr.send_columns`` call per entity and item, grouped in a :class:`Batch`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, slots=True)
class ScalarRows:
    """Scalar entities sharing time stamps: ``(path, values (rows, instances))`` each."""

    t_s: npt.NDArray[np.float64]
    columns: list[tuple[str, npt.NDArray[np.float64]]]


@dataclass(frozen=True, slots=True)
class PoseRows:
    """Transform3D rows: translation (rows, 3) in m, quaternion (rows, 4) x, y, z, w."""

    path: str
    t_s: npt.NDArray[np.float64]
    translation: npt.NDArray[np.float64]
    quaternion: npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ArrowRows:
    """Arrows3D rows: one vector (rows, 3) per row."""

    path: str
    t_s: npt.NDArray[np.float64]
    vectors: npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class TextRows:
    """TextLog entries ``(text, level)`` at one vehicle time."""

    path: str
    t_s: float
    entries: list[tuple[str, str]]


@dataclass(frozen=True, slots=True)
class DocumentRow:
    """A Markdown TextDocument at one vehicle time (replaces the previous one in the view)."""

    path: str
    t_s: float
    markdown: str


@dataclass(frozen=True, slots=True)
class Setup:
    """A new vehicle: its static styles, and the blueprint for all vehicles so far."""

    sysid: int
    sysids: list[int]


Item = ScalarRows | PoseRows | ArrowRows | TextRows | DocumentRow | Setup


@dataclass(frozen=True, slots=True)
class Batch:
    """What the sender sends in one go; ``rows`` for the counters; ``keep`` never dropped."""

    items: list[Item]
    rows: int
    keep: bool = False
