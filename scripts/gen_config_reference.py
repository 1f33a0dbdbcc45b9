"""Generate docs/reference/service-toml.md, the reference of ``service.toml``, from the
configuration reader itself (docs/reference/cli.md from the CLI's parsers, and
docs/reference/constants.md, every tuning constant with its reason, from the configuration
classes: ``glmav_observer.estimation.constants_table``).

Every key the reader (``glmav_observer.config.parse_config``) reads is recorded with its
type and its default (the dataclasses' values, as the reader passes them), by reading an
empty file and the shipped ``configs/service.toml`` through a recording
``glmav_toml.TableReader``. The description of each key is its comment in
``configs/service.toml`` (which also gives the range); a key the reader reads that the
shipped file does not describe is listed with "(undocumented)", so the gap shows.

    python scripts/gen_config_reference.py            # rewrite the pages
    python scripts/gen_config_reference.py --check    # exit 1 if a page is out of date

docs/reference/cli.md is every command's ``--help`` (argparse, 100 columns), so its exact
text follows the Python version's argparse; the check compares it too.

docs/reference/constants.md is one row per constant: its name, the ``service.toml`` key
that sets it (if any: a key the reader reads), value, unit, source kind and reason; for a
constant whose sensitivity was measured (benchmarks/constants_sensitivity.py), its figures
at ×0.5 and ×2 from benchmarks/results/constants_sensitivity.json.

tests/unit/scripts/test_gen_config_reference.py runs the check.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import sys
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import glmav_toml
from glmav_observer.config import parse_config

REPO = Path(__file__).resolve().parents[1]
SERVICE_TOML = REPO / "configs" / "service.toml"
OUT = REPO / "docs" / "reference" / "service-toml.md"
CLI_OUT = REPO / "docs" / "reference" / "cli.md"
CONSTANTS_OUT = REPO / "docs" / "reference" / "constants.md"
SENSITIVITY = REPO / "benchmarks" / "results" / "constants_sensitivity.json"
#: Configuration class -> the ``service.toml`` table its fields are read from.
TOML_SECTIONS = {
    "FdiConfig": "fdi",
    "ImuMonitorConfig": "fdi.imu",
    "GpsBridgeConfig": "estimation.gps_bridge",
    "DespikeConfig": "fdi.despike",
    "EstimatorConfig": "estimation",
}

_KINDS = {bool: "bool", int: "int", float: "float", str: "string", list: "list"}


@dataclass
class Key:
    name: str  # dotted, e.g. "ingest.reorder_window_s"
    kind: str
    default: Any


@contextlib.contextmanager
def _recording() -> Iterator[dict[str, Key]]:
    """Every ``TableReader.get``/``vector`` call made inside, by dotted key (first wins)."""
    seen: dict[str, Key] = {}
    reader = glmav_toml.TableReader
    get, vector = reader.get, reader.vector

    def rec_get(
        self: Any, name: str, kind: type, default: Any = glmav_toml.REQUIRED, check: Any = None
    ) -> Any:
        seen.setdefault(
            self.key(name), Key(self.key(name), _KINDS.get(kind, kind.__name__), default)
        )
        return get(self, name, kind, default, check)

    def rec_vector(
        self: Any, name: str, n: int | None, default: Any = glmav_toml.REQUIRED, check: Any = None
    ) -> Any:
        seen.setdefault(self.key(name), Key(self.key(name), "list of numbers", default))
        return vector(self, name, n, default, check)

    reader.get = rec_get  # type: ignore[method-assign]
    reader.vector = rec_vector  # type: ignore[method-assign]
    try:
        yield seen
    finally:
        reader.get, reader.vector = get, vector  # type: ignore[method-assign]


def _comments(text: str) -> tuple[dict[str, str], dict[str, str], dict[str, str]]:
    """From the shipped file: per section its comment, per key its comment and its value."""
    sections: dict[str, str] = {}
    keys: dict[str, str] = {}
    values: dict[str, str] = {}
    section = ""
    for line in text.splitlines():
        m = re.match(r"^\[([\w.]+)\]\s*(?:#\s*(.*))?$", line)
        if m:
            section = m.group(1)
            sections[section] = (m.group(2) or "").strip()
            continue
        m = re.match(r"^(\w+)\s*=\s*(.*?)\s*(?:#\s*(.*))?$", line)
        if m:
            dotted = f"{section}.{m.group(1)}" if section else m.group(1)
            keys[dotted] = (m.group(3) or "").strip()
            values[dotted] = m.group(2)
    return sections, keys, values


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def render() -> str:
    """The page's Markdown."""
    text = SERVICE_TOML.read_text(encoding="utf-8")
    with _recording() as empty:
        parse_config({}, "<defaults>")
    with _recording() as shipped:
        parse_config(tomllib.loads(text), str(SERVICE_TOML))
    sections, described, values = _comments(text)
    keys: dict[str, Key] = {**empty}
    for name, key in shipped.items():  # keys read only when present (e.g. [rates.hz])
        keys.setdefault(name, key)
    by_section: dict[str, list[Key]] = {}
    for key in keys.values():
        section, _, _ = key.name.rpartition(".")
        by_section.setdefault(section, []).append(key)
    out = [
        "# `service.toml` reference",
        "",
        "<!-- generated by scripts/gen_config_reference.py from the configuration reader and",
        "     configs/service.toml's comments: edit those, then run the script -->",
        "",
        "Every key is optional. The default is what the service uses when the key is absent.",
        "Unknown keys and bad values are errors that name the file, the key and the reason",
        "(exit code 2). Ranges are in brackets: `[lo, hi]`, where `(` excludes the bound.",
        "Units are in the key names: `_s` is seconds, `_hz` hertz, `_mps` m/s and `_mps2` m/s².",
        "`configs/service.toml` is the same reference as a file you can copy.",
        "",
    ]
    order = list(sections) + sorted(s for s in by_section if s not in sections)
    for section in order:
        rows = by_section.get(section)
        if not rows:
            continue
        out.append(f"## `[{section}]`" if section else "## top level")
        out.append("")
        if sections.get(section):
            out += [sections[section], ""]
        out += ["| key | type | default | description |", "|---|---|---|---|"]
        for key in rows:
            short = key.name.rpartition(".")[2]
            # a key read only when present (e.g. [rates.hz]): its shipped value is the default
            default = _toml_value(key.default) if key.name in empty else values.get(key.name, "")
            desc = described.get(key.name)
            desc = "(undocumented)" if desc is None else desc
            out.append(f"| `{short}` | {key.kind} | `{_cell(default)}` | {_cell(desc)} |")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def _sensitivity() -> dict[str, list[dict[str, Any]]]:
    """Constant name -> its rows of the sensitivity result (empty without the file)."""
    if not SENSITIVITY.exists():
        return {}
    result = json.loads(SENSITIVITY.read_text(encoding="utf-8"))
    out: dict[str, list[dict[str, Any]]] = {"": [result["baseline"]]}
    for row in result["rows"]:
        out.setdefault(row["constant"].split("[")[0], []).append(row)
    return out


def sensitivity_text(rows: list[dict[str, Any]], base: dict[str, Any]) -> str:
    """The figures of a constant at ×0.5 and ×2 next to its value's, in one cell."""

    def fig(key: str, fmt: str = "{}") -> str:
        vals = [base[key]] + [r[key] for r in rows]
        return " / ".join("–" if v is None else fmt.format(v) for v in vals)

    facts = [f"×{r['factor']:g} = {_toml_value(r['value'])}" for r in rows]
    return (
        f"Sensitivity (value / {' / '.join(facts)}): isolated ≤ 0.5 s "
        f"{fig('isolated_in_time')} of {base['n_cases']}; other isolations "
        f"{fig('extra_isolations')}; flight isolations outside windows "
        f"{fig('isolations_outside_windows')}; lost axis +10 s median "
        f"{fig('lost_err_10s_median_mps', '{:.3f}')} m/s "
        "([table](../benchmarks/constants_sensitivity.md))"
    )


def render_constants() -> str:
    """docs/reference/constants.md: every constant with its reason (module docstring)."""
    from glmav_observer.estimation.constants_table import constant_rows

    with _recording() as read:
        parse_config({}, "<defaults>")
    sens = _sensitivity()
    base = sens.get("", [{}])[0]
    rows = constant_rows()
    counts = {k: sum(r.reason.source == k for r in rows) for k in ("statistic", "physics",
              "requirement", "measured")}  # fmt: skip
    out = [
        "# Every constant with its reason",
        "",
        "<!-- generated by scripts/gen_config_reference.py from the configuration classes",
        "     (glmav_observer.estimation.constants_table) and",
        "     benchmarks/results/constants_sensitivity.json: edit those, then run the script -->",
        "",
        f"The {len(rows)} tuning constants of the estimation, one row each: where it is",
        "set (a `service.toml` key, or only in the code), its value, unit, the kind of its",
        "source and its reason. Source kinds: **statistic** (a property of a distribution: a",
        "gate's false-alarm rate), **physics** (of the vehicle, its sensors or its motion),",
        "**requirement** (a bound of the project, e.g. isolation within 0.5 s) and",
        "**measured** (read off data, which the reason names). "
        + ", ".join(f"{n} {k}" for k, n in counts.items())
        + ".",
        "",
        "A constant justified only by a measurement on the tuning corpus",
        "(`tests/data/ardupilot_sitl`) has its sensitivity measured: the corpus figures with",
        "it at ×0.5 and ×2 of its value (benchmarks/constants_sensitivity.py,",
        "[the table](../benchmarks/constants_sensitivity.md)). The held-out flights",
        "(`tests/data/ardupilot_sitl_heldout`) are never used to set a constant.",
        "",
    ]
    section = ""
    for row in rows:
        cls = row.name.split(".")[0] if row.name[0].isupper() else "module constants"
        if cls != section:
            section = cls
            toml = TOML_SECTIONS.get(cls)
            where = f" (`[{toml}]`)" if toml else ""
            out += [
                *([""] if out[-1] else []),
                f"## {cls}{where}",
                "",
                "| name | service.toml | value | unit | source | reason |",
                "|---|---|---|---|---|---|",
            ]
        field = row.name.rsplit(".", 1)[1]
        toml = TOML_SECTIONS.get(cls)
        key = f"{toml}.{field}" if toml else None
        if cls == "EstimatorConfig" and field == "gamma":
            key = "estimation.gamma_full"  # one key per configuration (gamma_<name>)
        setting = f"`{key}`" if key is not None and key in read else "—"
        reason = row.reason.reason
        if row.name in sens:
            reason += ". " + sensitivity_text(sens[row.name], base)
        elif row.reason.sensitivity:
            reason += ". Sensitivity: **not measured** (run benchmarks/constants_sensitivity.py)"
        value = _toml_value(row.value) if row.value is not None else "None"
        out.append(
            f"| `{row.name.split('.', 1)[1] if cls != 'module constants' else row.name}` "
            f"| {setting} | `{_cell(value)}` | {_cell(row.reason.unit)} "
            f"| {row.reason.source} | {_cell(reason)} |"
        )
    return "\n".join(out).rstrip() + "\n"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def render_cli() -> str:
    """Every command's ``--help``, as the user sees it at 100 columns."""
    from glmav_observer.cli import build_parser

    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal's width
    parser = build_parser()
    out = [
        "# Command-line reference",
        "",
        "<!-- generated by scripts/gen_config_reference.py from the CLI's parsers -->",
        "",
        "`glmav-observer COMMAND --help` prints the same text. The simulator has its own:",
        "`glmav-sitl --help`. Exit code 2 means a mistake in the command line or the",
        "configuration: the message names the option, file or key, and the reason.",
        "",
        "## glmav-observer",
        "",
        "```",
        parser.format_help().rstrip(),
        "```",
        "",
    ]
    for name, sub in _subparsers(parser).items():
        out += [f"## glmav-observer {name}", "", "```", sub.format_help().rstrip(), "```", ""]
    return "\n".join(out).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--check", action="store_true", help="exit 1 if the page is out of date")
    args = ap.parse_args(argv)
    stale = 0
    pages = ((OUT, render()), (CLI_OUT, render_cli()), (CONSTANTS_OUT, render_constants()))
    for path, page in pages:
        name = path.relative_to(REPO)
        if args.check:
            current = path.read_text(encoding="utf-8") if path.exists() else ""
            if current != page:
                print(
                    f"{name} is out of date: run python scripts/gen_config_reference.py",
                    file=sys.stderr,
                )
                stale = 1
        else:
            path.write_text(page, encoding="utf-8")
            print(f"wrote {name}")
    return stale


if __name__ == "__main__":
    sys.exit(main())
