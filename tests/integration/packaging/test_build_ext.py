"""The compiled core's build (setup.py): what a user sees without a C compiler, and that
the modules it builds are the ones the package imports."""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from glmav_testkit import REPO_ROOT


def _setup_modules() -> list[tuple[str, str]]:
    """setup.py's MODULES, read without running its setup()."""
    ns: dict[str, object] = {}
    src = (REPO_ROOT / "setup.py").read_text(encoding="utf-8")
    head = src.split("\ndef _extensions", 1)[0].split("\nclass BuildExt", 1)[0]
    exec(compile(head, "setup.py", "exec"), ns)
    modules = ns["MODULES"]
    assert isinstance(modules, list)
    return modules


@pytest.mark.slow  # pip sets up an isolated build environment: 20-80 s
def test_without_a_compiler_the_build_says_what_to_install(tmp_path: Path) -> None:
    """CC pointing nowhere: the build stops with a message naming the packages to install
    and what the compiler said, not a traceback, and no wheel."""
    for name in ("setup.py", "pyproject.toml", "README.md", "MANIFEST.in"):
        shutil.copy(REPO_ROOT / name, tmp_path / name)
    for pkg in ("service", "common", "sim_bridge"):
        shutil.copytree(REPO_ROOT / pkg, tmp_path / pkg,
                        ignore=shutil.ignore_patterns("*.so", "*.c", "__pycache__"))  # fmt: skip
    env = {**os.environ, "CC": str(tmp_path / "no-such-compiler")}
    # as a user's `pip install .` runs it: an isolated build environment (setuptools and
    # Cython from the package index, as pyproject's build-system asks)
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "w"),
         str(tmp_path)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out[-2000:]
    assert "building its compiled core failed" in out, out[-2000:]
    assert "apt-get install gcc python3-dev" in out
    assert "no-such-compiler" in out  # what the compiler (not) said
    assert not any((tmp_path / "w").glob("*.whl"))
    assert "Traceback" not in out


def test_every_module_setup_builds_is_the_one_imported() -> None:
    """Each (module, source) of setup.py: the source exists, and the installed package
    imports that module from a compiled file (an extension, not a Python copy)."""
    modules = _setup_modules()
    assert len(modules) >= 5  # rotation, inputs, despike, bank_core, imu_window at least
    for name, source in modules:
        assert (REPO_ROOT / source).is_file(), source
        mod = importlib.import_module(name)
        assert mod.__file__ is not None and mod.__file__.endswith(".so"), (name, mod.__file__)
        stub = (REPO_ROOT / source).with_suffix(".pyi")
        assert stub.is_file(), f"{source}: no type stub beside it"
