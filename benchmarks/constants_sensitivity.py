"""The tuning corpus's figures with one constant at ×0.5 and ×2 of its value.

Issue 32, "Every constant with its reason": a constant justified only by a measurement on
the tuning corpus (``sensitivity=True`` in its :class:`~glmav_observer.estimation.reasons.
Reason`), and the FDI thresholds the issue names (``gate_sigma``, ``noise_ratio_threshold``,
``k_isolate``), are each set to ×0.5 and ×2 of their value and the corpus is replayed
(``tests/data/ardupilot_sitl``, the eight tuning flights; never the held-out set):

- the eight flights as they are (``benchmarks.corpus``'s flight rows): the worst `full`
  RMSE of the three clean flights (n, e), the axis isolations outside the fault windows
  (+3 s), the largest switch jump;
- every injected velocity fault kind on every axis at 85 s of ``f_coax_clean`` (the
  flight where the aiding engages; ``benchmarks.corpus``'s case rows, 15 cases; one log
  only: a variant then costs ~1.5 min on the shared machine): the faults isolated
  right within 0.5 s, other isolations, the largest jump, and the `active` estimate's
  error on the lost axis 10 s after the onset (median and largest: the dead reckoning or
  the aiding, the figure the aero constants move).

One process, in sequence (the machine is shared). ``--quick``: the flight ``a_quad_wind``
and the cases of ``f_coax_clean`` only (a smoke run). The figures are what
docs/reference/constants.md shows next to each measured constant; nothing is tuned on
them here (a constant is not changed because of this table without a reason of its own).

    python -m benchmarks.constants_sensitivity [--quick]
    # writes results/constants_sensitivity.json, docs/benchmarks/constants_sensitivity.md
"""

from __future__ import annotations

import contextlib
import dataclasses
import statistics
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from benchmarks.common import format_table, main_for
from benchmarks.corpus import CLEAN, DATA, KINDS, LENGTH_S, _flight_row, _logs, _row, _windows

DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "constants_sensitivity.md"
FACTORS = (0.5, 2.0)
ONSET_S = 85.0
CASE_LOGS = ("f_coax_clean",)
#: The constants measured: (class, field, element of a tuple field or None). Those flagged
#: ``sensitivity`` in their reason must all be here (tests/unit/scripts/
#: test_gen_constants_reference.py checks it); the three FDI thresholds the issue names too.
CONSTANTS: tuple[tuple[str, str, int | None], ...] = (
    ("FdiConfig", "sigma_velocity_mps", None),
    ("FdiConfig", "gate_sigma", None),
    ("FdiConfig", "noise_ratio_threshold", None),
    ("FdiConfig", "k_isolate", None),
    ("ImuMonitorConfig", "floor_mps2", None),
    ("DragModelConfig", "prior_sigma_theta", 0),
    ("DragModelConfig", "changing_outliers", None),
    ("DragModelConfig", "changing_window_s", None),
    ("AidedAxisConfig", "sigma_v_meas_mps", None),
    ("AidedAxisConfig", "stale_nees_max", None),
    ("AidedAxisConfig", "scatter_max", None),
    ("aiding", "RETURN_TIME_S", None),
    ("EstimatorConfig", "gamma_full_max", None),
)


def constant_name(cls: str, name: str, element: int | None) -> str:
    """The name a constant has in docs/reference/constants.md (``Class.field``, a tuple
    element as ``Class.field[i]``, a module constant as ``module.NAME``)."""
    return f"{cls}.{name}" + ("" if element is None else f"[{element}]")


def _scaled(value: Any, factor: float) -> Any:
    if isinstance(value, bool):
        raise TypeError("a flag has no ×0.5")
    if isinstance(value, int):
        return max(1, round(value * factor))
    return value * factor


@contextlib.contextmanager
def varied(cls: str, name: str, element: int | None, factor: float) -> Iterator[Any]:
    """Inside: the service built with the constant at ``factor`` of its value; yields the
    ServiceConfig to replay with. FDI settings go through the configuration; the drag
    model's and the aided axis's (not configurable) by wrapping their constructors in
    ``glmav_observer.estimation.aiding``, the module constant by setting it, an
    ``[estimation]`` setting through the configuration."""
    from glmav_observer import config as config_mod
    from glmav_observer.estimation import aiding
    from glmav_observer.estimation.aero import AidedAxisConfig, DragModelConfig

    svc = config_mod.ServiceConfig()
    est = svc.estimation
    if cls in ("FdiConfig", "ImuMonitorConfig"):
        fdi = est.fdi
        if cls == "FdiConfig":
            fdi = dataclasses.replace(fdi, **{name: _scaled(getattr(fdi, name), factor)})
        else:
            imu = dataclasses.replace(fdi.imu, **{name: _scaled(getattr(fdi.imu, name), factor)})
            fdi = dataclasses.replace(fdi, imu=imu)
        yield dataclasses.replace(svc, estimation=dataclasses.replace(est, fdi=fdi))
        return
    if cls == "EstimatorConfig":
        yield dataclasses.replace(
            svc, estimation=dataclasses.replace(est, **{name: _scaled(getattr(est, name), factor)})
        )
        return
    if cls == "aiding":
        old = getattr(aiding, name)
        setattr(aiding, name, _scaled(old, factor))
        try:
            yield svc
        finally:
            setattr(aiding, name, old)
        return

    new = _value(cls, name, element, factor)

    def change(cfg: Any) -> Any:
        """``cfg`` with the constant at its varied value (set, not scaled: idempotent)."""
        v = new
        if element is not None:
            v = tuple(new if i == element else x for i, x in enumerate(getattr(cfg, name)))
        return dataclasses.replace(cfg, **{name: v})

    model, axis = aiding.DragModel, aiding.AidedAxis
    if cls == "DragModelConfig":

        def make_model(cfg: Any = None) -> Any:
            return model(change(cfg or DragModelConfig()))

        aiding.DragModel = make_model  # type: ignore[assignment,misc]
    elif cls == "AidedAxisConfig":

        def make_axis(*args: Any, **kwargs: Any) -> Any:
            *rest, cfg = args
            return axis(*rest, change(cfg or AidedAxisConfig()), **kwargs)

        aiding.AidedAxis = make_axis  # type: ignore[assignment,misc]
    else:
        raise ValueError(f"unknown class {cls!r}")
    try:
        yield svc
    finally:
        aiding.DragModel, aiding.AidedAxis = model, axis  # type: ignore[misc]


def figures(svc: Any, logs: tuple[str, ...], flights: list[str]) -> dict[str, Any]:
    """The corpus figures of one configuration (module docstring)."""
    from glmav_testkit.fault_replay import VelocityFault, replay, replay_cases

    rows = []
    for name in flights:
        r = replay(DATA / f"{name}.tlog.xz", svc)
        rows.append(_flight_row(name, r, [(a, b + 3.0) for a, b in _windows(name)]))
    cases = []
    for name in logs:
        faults = [
            VelocityFault(axis, kind, ONSET_S, ONSET_S + LENGTH_S, size)  # type: ignore[arg-type]
            for axis in range(3)
            for kind, size in KINDS
        ]
        results = replay_cases(DATA / f"{name}.tlog.xz", [(f,) for f in faults], svc)
        cases += [_row(name, f, r) for f, r in zip(faults, results, strict=True)]
    clean = [f for f in rows if f["log"] in CLEAN and f["log"] != "h_quad_gps_glitch"]
    lost = [c["lost_err_10s"] for c in cases if c["lost_err_10s"] is not None]
    return {
        "worst_clean_full_rmse_mps": max((max(f["full"][:2]) for f in clean), default=None),
        "isolations_outside_windows": sum(f["axis_isolations_outside_windows"] for f in rows),
        "isolated_in_time": sum(
            c["isolated"] and c["delay_s"] is not None and c["delay_s"] <= 0.5 for c in cases
        ),
        "n_cases": len(cases),
        "extra_isolations": sum(c["extra_isolations"] for c in cases),
        "max_jump_mps": max([c["max_jump_mps"] for c in cases] + [f["max_jump_mps"] for f in rows]),
        "lost_err_10s_median_mps": round(statistics.median(lost), 4) if lost else None,
        "lost_err_10s_max_mps": round(max(lost), 4) if lost else None,
    }


def run(
    quick: bool = False,
    progress: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True),
) -> dict[str, Any]:
    flights = list(CLEAN[:1]) if quick else _logs(DATA)
    logs = CASE_LOGS
    from glmav_observer.config import ServiceConfig

    progress("baseline")
    base = figures(ServiceConfig(), logs, flights)
    rows = []
    for cls, name, element in CONSTANTS:
        for factor in FACTORS:
            progress(f"{constant_name(cls, name, element)} x{factor:g}")
            with varied(cls, name, element, factor) as svc:
                value = _value(cls, name, element, factor)
                rows.append(
                    {
                        "constant": constant_name(cls, name, element),
                        "factor": factor,
                        "value": value,
                        **figures(svc, logs, flights),
                    }
                )
    result = {
        "name": "constants_sensitivity",
        "quick": quick,
        "flights": flights,
        "case_logs": list(logs),
        "onset_s": ONSET_S,
        "baseline": base,
        "rows": rows,
    }
    write_doc(result)
    return result


def _value(cls: str, name: str, element: int | None, factor: float) -> Any:
    """The constant's value at ``factor`` (for the table)."""
    from glmav_observer.estimation import aiding
    from glmav_observer.estimation.aero import AidedAxisConfig, DragModelConfig
    from glmav_observer.estimation.fdi_types import FdiConfig
    from glmav_observer.estimation.imu_monitor import ImuMonitorConfig
    from glmav_observer.estimation.vehicle import EstimatorConfig

    if cls == "aiding":
        return _scaled(getattr(aiding, name), factor)
    default = {
        "EstimatorConfig": EstimatorConfig(),
        "FdiConfig": FdiConfig(),
        "ImuMonitorConfig": ImuMonitorConfig(),
        "DragModelConfig": DragModelConfig(),
        "AidedAxisConfig": AidedAxisConfig(),
    }[cls]
    v = getattr(default, name)
    return _scaled(v if element is None else v[element], factor)


_COLUMNS = {
    "isolated_in_time": "isolated ≤ 0.5 s",
    "extra_isolations": "other isolations",
    "isolations_outside_windows": "flight isolations outside windows",
    "worst_clean_full_rmse_mps": "worst clean `full` RMSE n/e (m/s)",
    "max_jump_mps": "largest jump (m/s)",
    "lost_err_10s_median_mps": "lost axis +10 s median (m/s)",
    "lost_err_10s_max_mps": "lost axis +10 s max (m/s)",
}


def _cells(fig: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, title in _COLUMNS.items():
        v = fig[k]
        out[title] = f"{v}/{fig['n_cases']}" if k == "isolated_in_time" else v
    return out


def to_markdown(result: dict[str, Any]) -> str:
    base = result["baseline"]
    table = [{"constant": "(all at their values)", "×": "1", "value": "", **_cells(base)}]
    for r in result["rows"]:
        table.append(
            {"constant": f"`{r['constant']}`", "×": f"{r['factor']:g}", "value": r["value"], **_cells(r)}
        )  # fmt: skip
    lines = [
        "# Constants: sensitivity on the tuning corpus",
        "",
        "<!-- written by benchmarks/constants_sensitivity.py -->",
        "",
        "Each constant justified only by a measurement on the tuning corpus, and the FDI",
        "thresholds issue 32 names, at ×0.5 and ×2 of its value, everything else at its",
        "value; the eight tuning flights of `tests/data/ardupilot_sitl` replayed as they",
        "are, and every injected velocity fault (bias 0.5 and 1 m/s, freeze, NaN, noise) on",
        f"every axis at {result['onset_s']:g} s of {', '.join(result['case_logs'])}",
        f"({base['n_cases']} cases). The held-out flights are not used. Columns:",
        "injected faults isolated right within 0.5 s; other isolations in those cases;",
        "axis isolations outside the flights' fault windows (+3 s); the worst `full` RMSE",
        "(n, e) of the clean flights; the largest switch jump; the `active` estimate's",
        "error on the lost axis 10 s after the onset (median and largest over the cases).",
        "docs/reference/constants.md lists every constant with its reason.",
        "",
        "Quick run (a smoke test, not the table)." if result["quick"] else "",
        "",
        format_table(table),
        "",
    ]
    return "\n".join(lines)


def write_doc(result: dict[str, Any]) -> None:
    if not result["quick"]:
        DOC.write_text(to_markdown(result), encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main_for(sys.modules[__name__], sys.argv[1:]))
