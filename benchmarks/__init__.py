"""Runnable benchmarks: each ``bench_*.py`` prints a table, writes JSON to ``results/``.

Convention: a benchmark module provides ``run(quick: bool = False) -> dict`` (JSON-able,
with at least ``"name"``, ``"rows"`` (list of dicts) and ``"goals"`` (list of
``{"goal": str, "measured": float, "target": float, "met": bool}``)) and
``to_markdown(result: dict) -> str``; under ``__main__`` it calls
:func:`benchmarks.common.main_for`.
"""
