"""Never run a compiled copy of a Python module that is older than its source.

The modules on the per-message path (``setup.py``'s ``PY_MODULES``) are compiled by
Cython as they are written, and the build records the SHA-256 of every source it compiled
in ``_compiled_sources.json`` beside the package. Python's import system prefers an
extension module to the source beside it, so an edit to one of those sources would be
ignored, silently, until the next build. :func:`install` puts a finder first on
``sys.meta_path`` that imports the source instead of the compiled copy

- when the source's SHA-256 differs from the one recorded (a warning names the module
  and the command that rebuilds it), or
- for every one of them when the environment sets ``GLMAV_OBSERVER_INTERPRETED=1``
  (profilers, debuggers and coverage see Python frames; a test compares the two).

A tree with no record (nothing built yet) is left to the default finders.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

#: the environment variable that runs every compiled module's source instead
INTERPRETED_ENV = "GLMAV_OBSERVER_INTERPRETED"
#: written by setup.py's build_ext once every module is built: {module: sha256 of source}
RECORD = Path(__file__).with_name("_compiled_sources.json")

logger = logging.getLogger(__name__)


def _read_record(path: Path) -> dict[str, str]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {str(k): str(v) for k, v in data.items()}


class SourceWhenStale(importlib.abc.MetaPathFinder):
    """The finder: a spec for a module's source where its compiled copy must not run;
    ``None`` (the default finders, which take the compiled copy) otherwise."""

    def __init__(self, compiled_sha256: dict[str, str], interpreted: bool) -> None:
        self.compiled_sha256 = compiled_sha256
        self.interpreted = interpreted
        #: the modules imported from source, with the reason ("stale" or "requested")
        self.from_source: dict[str, str] = {}

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        recorded = self.compiled_sha256.get(fullname)
        if recorded is None or not path:
            return None
        source = Path(path[0]) / (fullname.rpartition(".")[2] + ".py")
        if not source.is_file():
            return None  # no source beside it (a wheel without sources): the compiled copy
        if self.interpreted:
            reason = "requested"
        elif hashlib.sha256(source.read_bytes()).hexdigest() != recorded:
            reason = "stale"
            logger.warning(
                "%s runs interpreted: %s changed since the compiled core was built "
                "(rebuild it: pip install -e .)",
                fullname,
                source,
            )
        else:
            return None
        self.from_source[fullname] = reason
        return importlib.util.spec_from_file_location(fullname, source)


def install() -> SourceWhenStale:
    """Put the finder first on ``sys.meta_path`` (once per process); the finder."""
    for finder in sys.meta_path:
        if isinstance(finder, SourceWhenStale):
            return finder
    finder = SourceWhenStale(
        _read_record(RECORD), os.environ.get(INTERPRETED_ENV, "") not in ("", "0")
    )
    sys.meta_path.insert(0, finder)
    return finder


def is_compiled(module: ModuleType) -> bool:
    """Whether ``module`` was imported from a compiled extension."""
    return isinstance(getattr(module, "__loader__", None), importlib.machinery.ExtensionFileLoader)
