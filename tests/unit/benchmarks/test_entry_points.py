"""The benchmarks and scripts that use the test kit start as documented, with no
``sys.path`` edits anywhere: ``glmav_testkit`` is an installed package."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from glmav_testkit import REPO_ROOT


@pytest.mark.parametrize(
    "command",
    [
        ["-m", "benchmarks.faults_accuracy", "--help"],
        ["-m", "benchmarks.soak", "--help"],
        ["-m", "benchmarks.fuzz_ingest", "--help"],
        ["scripts/faultproxy.py", "--help"],
    ],
)
def test_starts_without_path_edits(command: list[str]) -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, *command], cwd=REPO_ROOT, env=env, capture_output=True, text=True,
        check=False,
        timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage:"), done.stdout[:200]


def test_no_code_edits_sys_path() -> None:
    edits = re.compile(r"sys\.path\.(insert|append|extend)|sys\.path\s*[+]?=")
    found = [
        f"{path.relative_to(REPO_ROOT)}:{n}"
        for folder in ("service", "sim_bridge", "benchmarks", "scripts", "tests")
        for path in sorted((REPO_ROOT / folder).rglob("*.py"))
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if edits.search(line) and path.name != "test_entry_points.py"
    ]
    assert found == []
