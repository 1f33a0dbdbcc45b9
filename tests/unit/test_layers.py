"""The import graph points one way: no module imports a higher layer.

The service's layers, lowest first (a module may import its own layer and those below):

    0 _version, frames, logs,         constants, rotations, logging setup, the finder that
      _compiled, stop                 never runs a stale compiled module, stopping on signals
    1 configurations                  the table of sensor-failure configurations
    2 records                         what the service publishes
    3 reads, evaluation               what a sink reads; error against truth (the scorer)
    4 ingest                          MAVLink framing, links, samples, log files
    5 estimation                      the observer bank, FDI, aiding, per-vehicle estimator
    6 publish                         sinks: file, Zenoh, Rerun, MAVLink out
    7 config                          service.toml read into the settings of the layers below
    8 app, app_summary, app_sinks, app_replay   the service: ingest -> estimation -> sinks
    9 fleet                           workers and claims around the service
   10 commands                        the CLI's subcommands
   11 cli, glmav_observer (package)   the entry point

Between packages: the service and the simulator import neither each other nor the test
kit; the shared TOML reader (glmav_toml) imports none of them. Fault injection and log
replays with faults live in the test kit (glmav_testkit.fault_replay), never in the
product. Every import counts, including those inside functions and under TYPE_CHECKING
(a type-only upward import is still a dependency a reader must follow).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from glmav_testkit import REPO_ROOT

LAYERS: dict[str, int] = {
    "_version": 0,
    "frames": 0,
    "rotation": 0,  # the compiled E (13) and E v (frames re-exports them)
    "logs": 0,
    "_compiled": 0,  # imports nothing of the project; the package installs it first
    "stop": 0,  # setting a stop event from a signal handler
    "configurations": 1,
    "records": 2,
    "reads": 3,
    "evaluation": 3,
    "ingest": 4,
    "estimation": 5,
    "publish": 6,
    "config": 7,
    "app": 8,
    "app_summary": 8,
    "app_sinks": 8,
    "app_replay": 8,
    "fleet": 9,
    "commands": 10,
    "cli": 11,
    "": 11,  # the package itself (glmav_observer/__init__.py)
}

#: Which top-level packages each package may import (besides itself and third parties).
ALLOWED_PACKAGES: dict[str, frozenset[str]] = {
    "glmav_observer": frozenset({"glmav_toml"}),
    "glmav_sitl": frozenset({"glmav_toml"}),
    "glmav_toml": frozenset(),
}
PROJECT_PACKAGES = frozenset({"glmav_observer", "glmav_sitl", "glmav_toml", "glmav_testkit"})
PACKAGE_DIRS = {
    "glmav_observer": REPO_ROOT / "service" / "glmav_observer",
    "glmav_sitl": REPO_ROOT / "sim_bridge" / "glmav_sitl",
    "glmav_toml": REPO_ROOT / "common" / "glmav_toml",
}


def _module_name(package: str, path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIRS[package]).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join((package, *parts))


#: an import line of a Cython source (``from X import``/``cimport``, ``import X``,
#: ``cimport X``): its module at the start of a line (the compiled core uses absolute ones)
_PYX_IMPORT = re.compile(r"^(?:from\s+([\w.]+)\s+c?import\b|c?import\s+([\w.]+))", re.M)


def _pyx_imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of a compiled module's source (.pyx/.pxd: Cython,
    which ``ast`` cannot parse)."""
    text = path.read_text(encoding="utf-8")
    return [
        (text.count("\n", 0, m.start()) + 1, m.group(1) or m.group(2))
        for m in _PYX_IMPORT.finditer(text)
    ]


def _sources(root: Path) -> list[Path]:
    """The package's Python and Cython sources."""
    return sorted([*root.rglob("*.py"), *root.rglob("*.pyx"), *root.rglob("*.pxd")])


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``path``, relative ones resolved."""
    if path.suffix in (".pyx", ".pxd"):
        return _pyx_imports(path)
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            found.append((node.lineno, name))
            # `from glmav_observer import commands` imports the submodule commands
            if name == "glmav_observer":
                root = PACKAGE_DIRS[name]
                found.extend(
                    (node.lineno, f"{name}.{a.name}")
                    for a in node.names
                    if (root / f"{a.name}.py").exists() or (root / a.name).is_dir()
                )
    return found


def _layer_of(module: str) -> tuple[str, int]:
    """The layer name and rank of a glmav_observer module."""
    parts = module.split(".")
    top = parts[1] if len(parts) > 1 else ""
    if top not in LAYERS:
        raise AssertionError(
            f"{module}: top-level module {top!r} has no layer: add it to LAYERS in {__file__}"
        )
    return top, LAYERS[top]


def upward_imports() -> list[str]:
    """Every import that breaks the rules above, as 'file:line: what'."""
    problems: list[str] = []
    for package, root in PACKAGE_DIRS.items():
        for path in _sources(root):
            module = _module_name(package, path)
            where = path.relative_to(REPO_ROOT)
            for line, target in _imports(path, module):
                target_pkg = target.split(".")[0]
                if target_pkg not in PROJECT_PACKAGES or target_pkg == package:
                    if package == "glmav_observer" and target_pkg == package:
                        (name, rank), (t_name, t_rank) = _layer_of(module), _layer_of(target)
                        if t_rank > rank:
                            problems.append(
                                f"{where}:{line}: {module} (layer {rank}, {name or 'package'}) "
                                f"imports {target} (layer {t_rank}, {t_name or 'package'})"
                            )
                    continue
                if target_pkg not in ALLOWED_PACKAGES[package]:
                    problems.append(f"{where}:{line}: {package} imports {target}")
    return problems


def test_no_module_imports_a_higher_layer() -> None:
    problems = upward_imports()
    assert problems == [], "upward imports:\n" + "\n".join(problems)


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    """The rule itself: a lower module importing a higher one is reported (so the test
    above cannot pass by seeing nothing)."""
    # the real graph has imports of every kind: the walk found them
    n_imports = sum(
        len(_imports(p, _module_name("glmav_observer", p)))
        for p in _sources(PACKAGE_DIRS["glmav_observer"])
    )
    assert n_imports > 300
    # the compiled core's imports are read too (Cython's cimport among them)
    pyx = PACKAGE_DIRS["glmav_observer"] / "estimation" / "inputs.pyx"
    assert "glmav_observer.rotation" in {m for _, m in _pyx_imports(pyx)}
    # a relative import from estimation resolved against its package, and ranked
    bad = tmp_path / "bad.py"
    bad.write_text("from ..app import Service\nfrom glmav_observer.config import X\n")
    got = _imports(bad, "glmav_observer.estimation.bad")
    assert got == [(1, "glmav_observer.app"), (2, "glmav_observer.config")]
    assert _layer_of("glmav_observer.estimation.bad")[1] < _layer_of(got[0][1])[1]
    assert _layer_of("glmav_observer.estimation.bad")[1] < _layer_of(got[1][1])[1]
    # and an import from the package's __init__ resolves to the package itself
    init = tmp_path / "__init__.py"
    init.write_text("from . import records\n")
    assert _imports(init, "glmav_observer.publish") == [(1, "glmav_observer.publish")]
