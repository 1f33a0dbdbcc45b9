"""The axis monitor's ramp rule (withdrawing a residual isolation) on constructed data."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from glmav_observer.estimation.fdi_axis import AxisMonitor
from glmav_observer.estimation.fdi_reference import ReferenceFit
from glmav_observer.estimation.fdi_types import FdiConfig
from glmav_observer.records import FaultEvent

RAMP_LIMIT_MPS2 = FdiConfig().tuning.ramp_limit_mps2
RAMP_WINDOW_S = FdiConfig().tuning.ramp_window_s


def _isolated_axis(residual: Callable[[float], float], rate_hz: float = 10.0) -> AxisMonitor:
    """An axis isolated (bias) at t = 0 whose residual against the dead reckoning then
    follows ``residual`` over RAMP_WINDOW_S, at ``rate_hz``, with 0.05 m/s of noise."""
    cfg = FdiConfig()
    ax = AxisMonitor("n", 0, cfg, ReferenceFit(cfg))
    ax.fault = FaultEvent("n", "bias", 0.0)
    rng = np.random.default_rng(3)
    n = round(RAMP_WINDOW_S * rate_hz) + 1
    for k in range(n):
        t = k / rate_hz
        ax._ramp.append((t, residual(t) + float(rng.normal(0.0, 0.05))))
    return ax


def test_a_residual_that_ramps_after_an_isolation_is_the_imus_path() -> None:
    """A lost attitude: g·δθ ≈ 1 m/s² on n (a 6° tilt). Over 1 s at 10 Hz with σ 0.05 the
    slope's σ is 0.05/√(Σ(t − t̄)²) = 0.05/0.96 ≈ 0.05 m/s²: 1 m/s² is far beyond 0.5 + 3σ;
    0.3 m/s² (an accelerometer bias the fit can leave) is below it."""
    assert _isolated_axis(lambda t: 0.5 + 1.0 * t).ramping(RAMP_WINDOW_S)
    assert not _isolated_axis(lambda t: 0.5 + 0.3 * t).ramping(RAMP_WINDOW_S)
    assert RAMP_LIMIT_MPS2 == 0.5  # the numbers above assume it


def test_a_bias_that_ends_is_a_step_not_a_ramp() -> None:
    """A 1 m/s bias removed mid-window: a line through it has slope ≈ 1.5 m/s² (it
    withdrew 26 injected isolations at their end before the step model was compared);
    the single-step fit explains it better."""
    assert not _isolated_axis(lambda t: 1.0 if t < 0.5 else 0.0).ramping(RAMP_WINDOW_S)
    assert not _isolated_axis(lambda t: 0.0 if t < 0.5 else 1.0).ramping(RAMP_WINDOW_S)


def test_a_noisy_measurement_is_not_withdrawn_on_a_chance_ramp() -> None:
    """A noise fault (σ 0.5 m/s at 10 Hz) can draw a steep line over 1 s by chance; the
    measurement's own second differences are then far above their healthy level
    (6σ² = 1.5 against 6 · 0.05² = 0.015), and a noisy measurement is never the IMU's
    ramp."""
    ax = _isolated_axis(lambda t: 0.5 + 1.0 * t)
    assert ax.ramping(RAMP_WINDOW_S)  # smooth (no second differences recorded yet)
    ax._d2y_sq.extend([1.5] * len(ax._ramp))
    assert not ax.ramping(RAMP_WINDOW_S)
