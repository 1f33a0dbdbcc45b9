"""Where the simulator's default files are, and how its TOML files are read.

Keys are declared and checked with :mod:`glmav_toml`, the way the service reads its own
file (the simulator does not import the service; both import that small module): every
bad value is a :class:`~glmav_toml.ConfigError` reported as ``<file>: <key>: <reason>``,
which the CLI turns into exit code 2.
Default files ship inside the package (``glmav_sitl/data``), the one copy of each:
``glmav-sitl files`` prints their paths (copy one, edit it, pass it with ``--config``,
``--vehicle`` or ``--scenario PATH``). ``configs/`` in the repository holds the service's
files only.
"""

from __future__ import annotations

from pathlib import Path


def data_path(*parts: str) -> Path:
    """Path of a default file shipped in ``glmav_sitl/data`` (e.g. ``data_path("sitl.toml")``)."""
    return Path(__file__).resolve().parent.joinpath("data", *parts)


def packaged_files() -> list[Path]:
    """The packaged default files: ``sitl.toml``, the vehicle file and the scenarios."""
    return sorted(p for p in data_path().rglob("*.toml") if p.is_file())
