"""``glmav-observer check``: the printed figures are the observer's, and they are right."""

from __future__ import annotations

import math

import pytest

from glmav_observer.cli import main
from glmav_observer.commands.check import run_check


def _rows(text: str) -> dict[tuple[str, str], list[float]]:
    rows = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 9 and parts[0] in ("exact", "small_angle"):
            rows[(parts[0], parts[1])] = [float(p) for p in parts[2:]]
    return rows


def test_check_command_prints_the_decay_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--duration", "2"]) == 0
    rows = _rows(capsys.readouterr().out)
    assert len(rows) == 8  # 2 E forms × 4 configurations
    for config, gamma in (("full", 12.0), ("c1", 90.0), ("c2", 70.0), ("c3", 70.0)):
        hz, g, rate, t1, lost1, lost_end, meas_end = rows[("exact", config)]
        assert hz == 1000.0
        assert g == gamma
        # exact decay at γ, fitted above the 1 kHz hold floor: within 2 % (observed ≤ 1.3 %)
        assert abs(rate / gamma - 1) < 0.02
        # 1 % of the initial error after ln(100)/γ (+ one 1 ms step, + hold floor effects 2 %)
        assert abs(t1 - math.log(100) / gamma) <= 0.02 * math.log(100) / gamma + 1e-3
        assert meas_end < 2e-3  # hold floor ≈ Δt(|V̇| + |ω||V|) ≈ 5e-3 worst, 1e-3 typical
        if config != "full":
            # the lost axis does not converge (Fig. 6 claim fails) and holds still: 1 s of
            # drift at 1 kHz ≤ Δt(|V̈| + |ω||V̇|)/2·1 s + Δt|ω||V| ≈ 4.6e-3 (test_observer (b))
            assert abs(lost1) > 1.0
            assert abs(lost_end - lost1) < 4.6e-3


def test_check_small_angle_e_fails_at_the_papers_attitude() -> None:
    """With (48)'s φ0 = 1.3 rad, far outside assumption 1, the small-angle E makes the body
    estimate wrong by metres per second even on the measured axes."""
    rows = run_check(duration_s=1.0, rate_hz=500.0, e_forms=("small_angle",))
    assert all(r["meas_err_end_mps"] > 0.5 for r in rows)
