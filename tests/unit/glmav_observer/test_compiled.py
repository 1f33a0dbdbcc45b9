"""The pure-Python modules compiled by Cython (setup.py's PY_MODULES) and the finder that
never runs a compiled copy older than its source (glmav_observer/_compiled.py)."""

from __future__ import annotations

import importlib
import json
import lzma
import os
import subprocess
import sys
from pathlib import Path

import glmav_observer
from glmav_observer import _compiled

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "tests" / "data" / "ardupilot_sitl" / "b_quad_gps_off.tlog.xz"


def _setup_py_modules() -> list[str]:
    """PY_MODULES as setup.py lists them (read, not imported: setup.py runs setup())."""
    text = (REPO / "setup.py").read_text()
    block = text.split("PY_MODULES = [", 1)[1].split("\n]\n", 1)[0]
    return [
        "glmav_observer." + line.strip().strip('",')
        for line in block.splitlines()
        if line.strip().startswith('"')
    ]


def test_every_module_the_build_compiled_runs_compiled() -> None:
    record = json.loads(_compiled.RECORD.read_text())
    modules = _setup_py_modules()
    # the record is what the last build compiled: exactly setup.py's list
    assert sorted(record) == sorted(modules)
    assert len(modules) == 46
    for name in modules:
        module = importlib.import_module(name)
        # a failure here is an edited source not rebuilt yet: `pip install -e .`
        assert _compiled.is_compiled(module), f"{name} runs from {module.__file__}"


def _run(code: str, *args: str, interpreted: str = "0") -> subprocess.CompletedProcess[str]:
    """``code`` in a fresh interpreter, compiled (``interpreted="0"``) or from source."""
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, _compiled.INTERPRETED_ENV: interpreted},
        check=True,
    )


def test_a_source_that_differs_from_the_compiled_one_runs_from_source() -> None:
    # a fresh interpreter: the record's hash of one module made different from its
    # source's, as an edit after the build would; that module is imported from its .py
    # with a warning naming it, the others stay compiled
    code = """
import sys, glmav_observer
from glmav_observer import _compiled
finder = sys.meta_path[0]
finder.compiled_sha256["glmav_observer.ingest.rates"] = "0" * 64
import glmav_observer.ingest.rates as rates, glmav_observer.ingest.clock as clock
print(_compiled.is_compiled(rates), _compiled.is_compiled(clock), rates.__file__.endswith(".py"))
print(finder.from_source)
"""
    out = _run(code)
    lines = out.stdout.splitlines()
    assert lines[0] == "False True True"
    assert lines[1] == "{'glmav_observer.ingest.rates': 'stale'}"
    assert "glmav_observer.ingest.rates runs interpreted" in out.stderr
    assert "pip install -e ." in out.stderr


def test_the_finder_is_installed_once_and_first() -> None:
    assert isinstance(sys.meta_path[0], _compiled.SourceWhenStale)
    assert _compiled.install() is sys.meta_path[0]
    assert sum(isinstance(f, _compiled.SourceWhenStale) for f in sys.meta_path) == 1
    assert glmav_observer.__version__


def test_compiled_and_interpreted_replays_write_the_same_bytes(tmp_path: Path) -> None:
    # the one implementation, two ways of running it: a corpus flight with a GPS loss
    # (isolation, hand-over, aiding) replayed compiled and with every compiled module's
    # source interpreted; the records (every float, repr'd) must be byte-identical, as
    # Cython keeps Python's float operations and their order (setup.py's directives)
    log = tmp_path / FLIGHT.name.removesuffix(".xz")
    log.write_bytes(lzma.decompress(FLIGHT.read_bytes()))
    code = """
import sys
from glmav_observer.cli import main
sys.exit(main(["replay", sys.argv[1], "--out", sys.argv[2], "--no-progress"]))
"""
    outs = {}
    for mode, env in (("compiled", "0"), ("interpreted", "1")):
        out = tmp_path / f"{mode}.jsonl"
        _run(code, str(log), str(out), interpreted=env)
        outs[mode] = out.read_bytes()
    n_records = outs["compiled"].count(b"\n")
    # 130 s of flight: velocity records of 5 configurations at the output rate, health, events
    assert n_records > 10_000
    assert outs["compiled"] == outs["interpreted"]
