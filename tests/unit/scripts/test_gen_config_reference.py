"""The generated references (scripts/gen_config_reference.py) are up to date with the
configuration reader and the CLI, and say what they must."""

from __future__ import annotations

import importlib.util
import re
import sys
import tomllib
from types import ModuleType

from glmav_observer.cli import COMMANDS
from glmav_observer.config import parse_config
from glmav_testkit import REPO_ROOT

SCRIPT = REPO_ROOT / "scripts" / "gen_config_reference.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_config_reference", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_service_toml_reference_is_generated_from_the_reader() -> None:
    gen = _script()
    page = gen.render()
    committed = gen.OUT.read_text(encoding="utf-8")
    assert committed == page, "docs/reference/service-toml.md is stale: run the script"
    # every key of the shipped file is in the reference, with the reader's default where
    # the reader has one (the shipped file says its values are the defaults)
    shipped = tomllib.loads((REPO_ROOT / "configs" / "service.toml").read_text(encoding="utf-8"))
    rows = dict(re.findall(r"^\| `(\w+)` \| [^|]+ \| `([^`]*)` \|", page, flags=re.M))
    assert len(rows) >= 60

    def leaves(table: dict[str, object]) -> list[str]:
        out = []
        for k, v in table.items():
            out += leaves(v) if isinstance(v, dict) else [k]  # type: ignore[arg-type]
        return out

    missing = [k for k in leaves(shipped) if k not in rows]
    assert missing == []
    assert rows["reorder_window_s"] == "0.0"
    assert rows["max_vehicles"] == str(parse_config({}).ingest.max_vehicles)


def test_cli_reference_lists_every_command_and_option() -> None:
    gen = _script()
    committed = gen.CLI_OUT.read_text(encoding="utf-8")
    # argparse's wording differs between Python versions: compare what it must contain
    for name in COMMANDS:
        assert f"## glmav-observer {name}\n" in committed
    from glmav_observer.cli import build_parser

    for name, sub in gen._subparsers(build_parser()).items():
        section = committed.split(f"## glmav-observer {name}\n", 1)[1].split("\n## ", 1)[0]
        for action in sub._actions:
            for option in action.option_strings:
                assert option in section, f"{name} {option}: run the script"
