"""Golden replays: a fresh replay of every case of ``glmav_testkit.golden`` against its
file in tests/data/golden (README there). The guard for estimator refactors: a change
that is meant to leave the arithmetic alone must leave every decision and every
(decimated) estimate where it was.

A deliberate change of the estimate re-baselines in its own commit:
``python -m glmav_testkit.golden --update [--only NAME]``, with the before/after figures
it prints in the commit message.
"""

from __future__ import annotations

import functools
from typing import Any

import pytest

from glmav_observer.records import VelocityRecord
from glmav_testkit import golden

#: Decisions: kinds, axes, configurations, reasons and times compare exactly (times are
#: sample times the estimator copies, never computes); ``jump_mps`` (and an accelerometer
#: event's estimated bias) is arithmetic: within 1e-9 m/s, far below anything physical and
#: far above nothing, while the arithmetic is unchanged (the replay is deterministic:
#: regenerated, the goldens are bit for bit the same). A compiled core may loosen this to
#: 1e-6 m/s, saying why in the commit that does.
DECISION_TOL_MPS = 1e-9
#: Estimates: the same record times and health / lost-axis strings, velocity and σ of the
#: lost axis within 1e-9 m/s, for the same reason: the same operations in the same order
#: give the same doubles. A deliberate change of the estimate re-baselines the goldens in
#: its own commit with before/after figures; a compiled core (other operation order, FMA)
#: may loosen this to 1e-6 m/s with the reason stated.
ESTIMATE_TOL_MPS = 1e-9


@functools.cache
def _fresh(log: str) -> dict[str, dict[str, Any]]:
    """Every case of one log, replayed once (the fault cases share the clean prefix)."""
    return {c.name: g for c, g in golden.replay_group(golden.groups()[log])}


def _fail(case: golden.GoldenCase, what: str, differences: list[str]) -> str:
    return (
        f"{case.name}: the {what} differ from {case.golden_path.name} "
        f"({len(differences)} lines):\n  "
        + "\n  ".join(differences[:40])
        + "\nIf the change is deliberate, re-baseline in its own commit: "
        f"python -m glmav_testkit.golden --update --only {case.name}"
    )


@pytest.mark.parametrize("case", golden.CASES, ids=lambda c: c.name)
def test_replay_matches_its_golden(case: golden.GoldenCase) -> None:
    expected = golden.load(case.golden_path)
    fresh = _fresh(case.log)[case.name]
    # what was replayed: the same log, faults, vehicle and decimation (exact)
    head = golden.compare_settings(expected, fresh)
    assert not head, _fail(case, "case's settings", head)
    # decisions identical; jump_mps within DECISION_TOL_MPS (1e-9: the arithmetic is
    # unchanged, so the same doubles; see the constant)
    d = golden.compare_decisions(expected, fresh, jump_tol_mps=DECISION_TOL_MPS)
    assert not d, _fail(case, "decisions", d)
    # estimates: same times and strings; v_ned_mps and σ within ESTIMATE_TOL_MPS (1e-9:
    # unchanged arithmetic; a deliberate change re-baselines, a compiled core may loosen
    # to 1e-6 with its reason)
    e = golden.compare_estimates(expected, fresh, tol_mps=ESTIMATE_TOL_MPS)
    assert not e, _fail(case, "estimates", e)


def test_golden_files_are_the_cases() -> None:
    """No golden without its case, no case without its golden (a renamed case leaves none
    behind)."""
    on_disk = {p.name for p in golden.GOLDEN_DIR.glob("*.json.gz")}
    assert on_disk == {c.golden_path.name for c in golden.CASES}
    # together they stay small (the task's budget: 3 MB)
    assert sum((golden.GOLDEN_DIR / n).stat().st_size for n in on_disk) <= 3_000_000


def _rec(config: str, t: float, sysid: int = 1) -> VelocityRecord:
    return VelocityRecord(sysid, config, t, (0.0, 0.0, 0.0), (t, 0.0, 0.0), None, "ok", 0)


def test_decimation_keeps_each_streams_first_record_and_then_one_per_due_time() -> None:
    ts = [0.004 + 0.04 * k for k in range(12)]  # 25 Hz from 0.004 s
    recs = [_rec(c, t) for t in ts for c in ("full", "active")]
    recs.insert(5, _rec("aided", 0.09))  # a stream that starts later starts at its first
    kept = golden.decimate(recs, 10.0)
    full = [r.t_boot_s for r in kept if r.config == "full"]
    # first (0.004), then the first at or after 0.1, 0.2, 0.3, 0.4 (next_due from the kept t)
    assert full == [ts[0], ts[3], ts[5], ts[8], ts[10]], full
    assert [r.t_boot_s for r in kept if r.config == "active"] == full
    assert [r.t_boot_s for r in kept if r.config == "aided"] == [0.09]
    # streams of another vehicle are their own
    other = golden.decimate([_rec("full", 0.0, 1), _rec("full", 0.05, 2)], 10.0)
    assert len(other) == 2
