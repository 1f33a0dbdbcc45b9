"""Shared pieces of the benchmarks: timing with medians, tables, JSON, machine facts."""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def machine() -> dict[str, Any]:
    """A short description of the machine the numbers come from."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def time_per_call_s(fn: Callable[[], object], *, number: int, repeats: int = 7) -> dict[str, float]:
    """Median, min and max over ``repeats`` of the mean time of ``number`` calls (s)."""
    fn()  # warm-up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - t0) / number)
    return {
        "median_s": statistics.median(samples),
        "min_s": min(samples),
        "max_s": max(samples),
        "repeats": float(repeats),
        "number": float(number),
    }


def goal(name: str, measured: float, target: float, *, higher_is_better: bool) -> dict[str, Any]:
    met = measured >= target if higher_is_better else measured <= target
    return {
        "goal": name,
        "measured": measured,
        "target": target,
        "higher_is_better": higher_is_better,
        "met": bool(met),
    }


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """A Markdown table of ``rows`` (same keys each), floats with 4 significant digits."""
    if not rows:
        return "(no rows)"
    keys = list(rows[0])

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(cell(r.get(k, "")) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def format_goals(goals: Sequence[dict[str, Any]]) -> str:
    rows = [
        {
            "goal": g["goal"],
            "measured": g["measured"],
            "target": ("≥ " if g["higher_is_better"] else "≤ ") + f"{g['target']:.4g}",
            "met": "yes" if g["met"] else "**no**",
        }
        for g in goals
    ]
    return format_table(rows)


def git_head() -> str:
    """The commit the benchmarks run at (``+dirty`` with uncommitted changes), or ""."""
    root = Path(__file__).resolve().parents[1]

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, check=True
        ).stdout

    try:
        head = git("rev-parse", "--short", "HEAD").strip()
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return ""
    return head + ("+dirty" if dirty.strip() else "")


def write_result(result: dict[str, Any]) -> Path:
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    result = {**result, "machine": machine(), "unix_time": time.time(), "git_head": git_head()}
    path = RESULTS_DIR / f"{result['name']}.json"
    path.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path


def main_for(module: ModuleType, argv: Sequence[str] | None = None) -> int:
    """The ``__main__`` of a benchmark module: run, print the table, write JSON."""
    parser = argparse.ArgumentParser(description=module.__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer repeats (smoke run)")
    parser.add_argument(
        "--label", default="", help="stored with the result, e.g. 'before (a845e63)'"
    )
    add_arguments = getattr(module, "add_arguments", None)  # a module's own options
    if add_arguments is not None:
        add_arguments(parser)
    args = vars(parser.parse_args(argv))
    label = args.pop("label")
    result = module.run(**args)
    if label:
        result["label"] = label
    print(module.to_markdown(result))
    path = write_result(result)
    print(f"\nwrote {path}", file=sys.stderr)
    return 0
