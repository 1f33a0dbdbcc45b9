"""Configuration errors and typed readers for the simulator's TOML files.

Every reader takes the file path and a dotted key so that a bad value is reported
as ``<file>: <key>: <reason>``; the CLI turns :class:`ConfigError` into exit code 2.
Default files ship inside the package (``glmav_sitl/data``), the one copy of each:
``glmav-sitl files`` prints their paths (copy one, edit it, pass it with ``--config``,
``--vehicle`` or ``--scenario PATH``). ``configs/`` in the repository holds the service's
files only.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A configuration file is missing, unparsable, or holds a bad value."""

    def __init__(self, path: str | Path, key: str, reason: str) -> None:
        self.path = str(path)
        self.key = key
        self.reason = reason
        super().__init__(f"{self.path}: {key}: {reason}" if key else f"{self.path}: {reason}")


def data_path(*parts: str) -> Path:
    """Path of a default file shipped in ``glmav_sitl/data`` (e.g. ``data_path("sitl.toml")``)."""
    return Path(__file__).resolve().parent.joinpath("data", *parts)


def packaged_files() -> list[Path]:
    """The packaged default files: ``sitl.toml``, the vehicle file and the scenarios."""
    return sorted(p for p in data_path().rglob("*.toml") if p.is_file())


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse ``path`` as TOML; raise :class:`ConfigError` naming the file on failure."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(p, "", "file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(p, "", f"not valid TOML: {e}") from None


def get_float(
    path: str | Path,
    table: Mapping[str, Any],
    key: str,
    *,
    prefix: str = "",
    default: float | None = None,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
) -> float:
    """A finite float ``table[key]`` within ``[lo, hi]`` (``(lo, hi]`` if ``lo_open``)."""
    name = f"{prefix}{key}"
    if key not in table:
        if default is None:
            raise ConfigError(path, name, "missing")
        return default
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ConfigError(path, name, f"expected a number, got {type(v).__name__} {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise ConfigError(path, name, f"must be finite, got {x}")
    if lo is not None and (x < lo or (lo_open and x == lo)):
        raise ConfigError(
            path, name, f"{x} is below the allowed range ({'>' if lo_open else '>='} {lo})"
        )
    if hi is not None and x > hi:
        raise ConfigError(path, name, f"{x} is above the allowed range (<= {hi})")
    return x


def get_vec(
    path: str | Path,
    table: Mapping[str, Any],
    key: str,
    n: int,
    *,
    prefix: str = "",
    default: tuple[float, ...] | None = None,
    lo: float | None = None,
    hi: float | None = None,
) -> tuple[float, ...]:
    """A list of ``n`` finite numbers ``table[key]``, each within ``[lo, hi]``."""
    name = f"{prefix}{key}"
    if key not in table:
        if default is None:
            raise ConfigError(path, name, "missing")
        return default
    v = table[key]
    if not isinstance(v, list) or len(v) != n:
        raise ConfigError(path, name, f"expected a list of {n} numbers, got {v!r}")
    out = []
    for i, e in enumerate(v):
        if isinstance(e, bool) or not isinstance(e, int | float) or not math.isfinite(float(e)):
            raise ConfigError(path, f"{name}[{i}]", f"expected a finite number, got {e!r}")
        x = float(e)
        if (lo is not None and x < lo) or (hi is not None and x > hi):
            raise ConfigError(path, f"{name}[{i}]", f"{x} outside [{lo}, {hi}]")
        out.append(x)
    return tuple(out)


def get_bool(
    path: str | Path, table: Mapping[str, Any], key: str, *, prefix: str = "", default: bool
) -> bool:
    name = f"{prefix}{key}"
    if key not in table:
        return default
    v = table[key]
    if not isinstance(v, bool):
        raise ConfigError(path, name, f"expected true or false, got {v!r}")
    return v


def get_str(
    path: str | Path,
    table: Mapping[str, Any],
    key: str,
    *,
    prefix: str = "",
    default: str | None = None,
    choices: tuple[str, ...] | None = None,
) -> str:
    name = f"{prefix}{key}"
    if key not in table:
        if default is None:
            raise ConfigError(path, name, "missing")
        return default
    v = table[key]
    if not isinstance(v, str):
        raise ConfigError(path, name, f"expected a string, got {v!r}")
    if choices is not None and v not in choices:
        raise ConfigError(path, name, f"{v!r} is not one of {', '.join(choices)}")
    return v


def get_table(
    path: str | Path, table: Mapping[str, Any], key: str, *, prefix: str = ""
) -> dict[str, Any]:
    """The sub-table ``table[key]`` (empty if absent)."""
    v = table.get(key, {})
    if not isinstance(v, dict):
        raise ConfigError(path, f"{prefix}{key}", f"expected a table, got {v!r}")
    return v


def check_keys(
    path: str | Path, table: Mapping[str, Any], allowed: set[str], *, prefix: str = ""
) -> None:
    """Reject unknown keys (a typo must not be silently ignored)."""
    for k in table:
        if k not in allowed:
            raise ConfigError(
                path, f"{prefix}{k}", f"unknown key (allowed: {', '.join(sorted(allowed))})"
            )
