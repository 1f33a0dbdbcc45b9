"""The project's test kit: helpers shared by tests/, benchmarks/ and scripts/.

An ordinary package (``tests/support/glmav_testkit``), declared in pyproject.toml so that
``pip install -e '.[test]'`` makes it importable everywhere without ``sys.path`` edits;
pytest runs with ``--import-mode=importlib`` and puts nothing on ``sys.path`` either.
It is meant for a clone of the repository (some helpers read ``configs/`` through
:data:`REPO_ROOT`), never for a deployment.
"""

from __future__ import annotations

from pathlib import Path

#: The repository this kit belongs to (tests/support/glmav_testkit -> the root).
REPO_ROOT = Path(__file__).resolve().parents[3]
