"""benchmarks.constants_sensitivity's stand-ins build what the aiding asks for."""

from __future__ import annotations

from benchmarks.constants_sensitivity import varied

from glmav_observer.estimation import aiding
from glmav_observer.estimation.aero import AidedAxisConfig, DragModelConfig


def test_varied_aided_axis_keeps_the_aidings_keywords() -> None:
    """Inside ``varied`` the aiding's AidedAxis is the benchmark's stand-in; it must take
    the arguments ``LostAxisAiding.start`` passes (the drift rate is a keyword) and give
    the axis the varied constant, and the class is put back on exit."""
    base = AidedAxisConfig().sigma_v_meas_mps
    original = aiding.AidedAxis
    with varied("AidedAxisConfig", "sigma_v_meas_mps", None, 2.0):
        axis = aiding.AidedAxis(1, 0.0, 0.1, 5.0, AidedAxisConfig(), drift_rate_mps2=0.3)
        # ×2 of the default, exactly (a float doubled is exact)
        assert axis.config.sigma_v_meas_mps == 2.0 * base
        assert axis.drift_rate_mps2 == 0.3
    assert aiding.AidedAxis is original


def test_varied_drag_model_is_built_with_the_varied_value() -> None:
    """The same for the drag model's constructor (held-out validation included)."""
    base = DragModelConfig().holdout_s
    with varied("DragModelConfig", "holdout_s", None, 0.5):
        model = aiding.DragModel(None)
        # ×0.5 of the default, exactly (halving is exact)
        assert model.config.holdout_s == 0.5 * base
