"""Reading an ``.rrd`` back (tests, notebooks, checks)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from glmav_observer.publish.rerun.paths import TIMELINE


def read_recording(
    path: str | Path,
) -> dict[str, dict[str, list[Any]]]:
    """Read an ``.rrd`` back: entity path -> component -> values, with ``"vehicle_time"``.

    For each entity, ``out[path]["vehicle_time"]`` holds the vehicle time of each temporal
    row in seconds and ``out[path][component]`` the row values as Python lists
    (e.g. ``"Scalars:scalars"`` -> ``[[1.0], ...]``), rows sorted by time; static rows are
    under ``out[path]["static:" + component]``.
    """
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list[Any]]] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        entity = out.setdefault(chunk.entity_path, {})
        names = [n for n in batch.schema.names if not n.startswith("rerun.controls")]
        if chunk.is_static:
            for name in names:
                entity.setdefault(f"static:{name}", []).extend(batch.column(name).to_pylist())
            continue
        if TIMELINE not in names:
            continue
        t_ns = batch.column(TIMELINE).cast("int64").to_pylist()
        for name in names:
            values = (
                [t * 1e-9 for t in t_ns] if name == TIMELINE else batch.column(name).to_pylist()
            )
            entity.setdefault(name, []).extend(values)
    for entity in out.values():
        if TIMELINE in entity:
            order = sorted(range(len(entity[TIMELINE])), key=entity[TIMELINE].__getitem__)
            for name, values in entity.items():
                if not name.startswith("static:") and len(values) == len(order):
                    entity[name] = [values[i] for i in order]
    return out
