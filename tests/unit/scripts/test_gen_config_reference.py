"""The generated references (scripts/gen_config_reference.py) are up to date with the
configuration reader and the CLI, and say what they must."""

from __future__ import annotations

import importlib.util
import json
import re
import sys
import tomllib
from dataclasses import dataclass
from types import ModuleType

import pytest

from glmav_observer.cli import COMMANDS
from glmav_observer.config import parse_config
from glmav_observer.estimation.constants_table import constant_rows
from glmav_observer.estimation.fdi_types import FdiConfig
from glmav_observer.estimation.gain import GainConfig
from glmav_observer.estimation.reasons import SOURCES, Reason
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


# ---------------------------------------------------------------- docs/reference/constants.md
def test_constants_reference_is_generated_from_the_classes() -> None:
    gen = _script()
    page = gen.render_constants()
    committed = gen.CONSTANTS_OUT.read_text(encoding="utf-8")
    assert committed == page, "docs/reference/constants.md is stale: run the script"
    assert "not measured" not in page  # every flagged constant has its sensitivity


def test_every_constant_has_a_reason_and_measured_ones_name_their_data() -> None:
    rows = constant_rows()
    assert len(rows) >= 107  # issue 32 counted ~107; the buried literals are rows now
    names = {r.name for r in rows}
    # the literals issue 32 names are named constants now, with the values they had
    # (golden replays unchanged)
    tuning = FdiConfig().tuning
    assert tuning.scale_winsor_sigma**2 == 16.0 and tuning.refit_rows == 15
    assert (GainConfig().max_step_ratio, GainConfig().min_change_fraction) == (1.5, 0.02)
    for name in (
        "FdiTuning.scale_winsor_sigma",
        "FdiTuning.refit_rows",
        "GainConfig.max_step_ratio",
        "GainConfig.min_change_fraction",
        "FdiConfig.gate_sigma",
        "FdiConfig.noise_ratio_threshold",
        "FdiConfig.k_isolate",
        "FdiConfig.overdue_intervals",
        "DespikeConfig.floor_mps2",
        "ImuMonitorConfig.window_s",
        "aiding.RETURN_TIME_S",
    ):
        assert name in names
    data = re.compile(r"corpus|SITL|[a-h]_(quad|coax|heli)_\w+|docs/benchmarks|b_quad_gps_off")
    for r in rows:
        assert r.reason.source in SOURCES, r.name
        assert len(r.reason.reason) >= 30, f"{r.name}: a reason, not a label"
        if r.reason.source == "measured":
            assert data.search(r.reason.reason), f"{r.name}: measured on what?"


def test_constants_justified_by_the_corpus_have_their_sensitivity() -> None:
    """Issue 32: none justified only by the tuning corpus without its sensitivity at ×0.5
    and ×2 (benchmarks/constants_sensitivity.py, its committed result)."""
    from benchmarks.constants_sensitivity import CONSTANTS, constant_name

    gen = _script()
    measured = gen._sensitivity()
    benched = {constant_name(*c).split("[")[0] for c in CONSTANTS}
    flagged = [r.name for r in constant_rows() if r.reason.sensitivity]
    assert len(flagged) >= 9
    for name in flagged:
        assert name in benched, f"{name}: add it to benchmarks/constants_sensitivity.py"
        assert sorted(r["factor"] for r in measured.get(name, [])) == [0.5, 2.0], name
    result = json.loads(gen.SENSITIVITY.read_text(encoding="utf-8"))
    assert result["quick"] is False
    # the held-out flights are never part of it
    assert not any(f.startswith("h") and f[1] != "_" for f in result["flights"])


@dataclass(frozen=True)
class _Unexplained:
    threshold: float = 3.0


def test_a_constant_without_a_reason_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    import glmav_observer.estimation.constants_table as table

    monkeypatch.setattr(table, "CLASSES", (*table.CLASSES, ("_Unexplained", __name__)))
    with pytest.raises(ValueError, match=r"_Unexplained\.threshold has no reason"):
        table.constant_rows()
    monkeypatch.setattr(
        table,
        "MODULE_CONSTANTS",
        (*table.MODULE_CONSTANTS, (__name__, "GONE", Reason("", "physics", "x"))),
    )
    with pytest.raises(ValueError, match="GONE: a reason for no constant"):
        table.constant_rows()
