"""Every tuning constant with its reason: the metadata a configuration field carries.

A tuning constant is a dataclass field made by :func:`const`: its default, its unit, the
kind of its source and its reason (the derivation, or the data it was measured on), as
``dataclasses.field`` metadata. ``scripts/gen_config_reference.py`` reads them into one
table, docs/reference/constants.md (:mod:`glmav_observer.estimation.constants_table`
lists the classes and the named module constants).

Source kinds:

- ``statistic``: a property of a distribution (a 5σ gate's false-alarm rate, χ²₁'s median);
- ``physics``: a property of the vehicle, its sensors or its motion;
- ``requirement``: what a bound of the project or a user asks (an isolation within 0.5 s);
- ``measured``: read off data, which the reason names. A constant justified only by a
  measurement on the tuning corpus (one flight, or a few) is flagged ``sensitivity``: its
  sensitivity is measured (benchmarks/constants_sensitivity.py: the corpus figures at ×0.5
  and ×2 of its value) and shown next to it.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, NamedTuple

Source = Literal["statistic", "physics", "requirement", "measured"]
SOURCES: tuple[Source, ...] = ("statistic", "physics", "requirement", "measured")


class Reason(NamedTuple):
    """A constant's unit ("" for a pure number), source kind and reason; ``sensitivity``:
    justified only by the tuning corpus (its sensitivity must be measured)."""

    unit: str
    source: Source
    reason: str
    sensitivity: bool = False


def const(
    default: Any, *, unit: str, source: Source, reason: str, sensitivity: bool = False
) -> Any:
    """A dataclass field with ``default`` and its :class:`Reason` as metadata."""
    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    meta = {"reason": Reason(unit, source, reason, sensitivity)}
    if isinstance(default, (list, dict, set)):
        raise TypeError("a constant's default must be immutable")
    return dataclasses.field(default=default, metadata=meta)


def reason_of(f: dataclasses.Field[Any]) -> Reason | None:
    """The :class:`Reason` of a field made by :func:`const`, or of one whose metadata is
    plain strings (``{"unit": ..., "source": "kind: detail", "reason": ...}``, the kind
    one of :data:`SOURCES`); else None."""
    meta = f.metadata
    r = meta.get("reason")
    if isinstance(r, Reason):
        return r
    if isinstance(r, str) and isinstance(meta.get("source"), str):
        kind, _, detail = meta["source"].partition(":")
        kind = kind.strip()
        for source in SOURCES:
            if kind == source:
                text = f"{r} ({detail.strip()})" if detail.strip() else r
                unit = str(meta.get("unit", ""))
                return Reason(unit, source, text, bool(meta.get("sensitivity", False)))
    return None
