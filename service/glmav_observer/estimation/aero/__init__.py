"""Self-calibrating aerodynamic aiding of a lost earth velocity axis (issue 13).

Four modules by concept:

- :mod:`.model`: :class:`DragModel`, the per-body-axis drag fit learnt while every axis is
  healthy, its own tests, and the pseudo-measurement of a lost axis;
- :mod:`.aided`: :class:`AidedAxis`, the lost axis's one-state filter, and the rules
  that keep it from being worse than dead reckoning (measured axes inconsistent with the
  IMU; pseudo-measurements inconsistent with the dead reckoning, or scattering beyond
  their σ; an estimate that would be less certain than the dead reckoning);
- :mod:`.control`: :class:`~.control.ControlMapping`, the swash-plate cyclic regressors
  (C1) from ``SERVO_OUTPUT_RAW``, the model's optional control term
  (``DragModelConfig(control=True)``: then ``learn`` and ``update_from_model`` take
  ``control=(ρ_x, ρ_y)``);
- :mod:`.floor`: the best lost-axis error any estimator can reach through drag in
  turbulence (an oracle Kalman filter's Riccati recursion; not used by the estimator,
  it says which of issue 13's bounds a wind allows).

Use from the estimator (per vehicle)::

    model = DragModel()
    # every velocity measurement while n, e, d are all healthy (f averaged over the
    # measurement interval, E the body→NED rotation, v the measured NED velocity):
    model.learn(t_s, f_mean_body_mps2, E, v_ned_mps)
    # at the fault on axis L (0 n, 1 e, 2 d): hand over the last value and its σ
    axis = AidedAxis(L, v0_mps=v_meas[L], sigma0_mps=sigma_meas, t0_s=t_s)
    # every IMU sample: the earth-frame acceleration, all three axes (E Γ less the bias)
    axis.propagate(dt_s, a_ned_mps2)
    # every velocity sample (f averaged over the interval, v_meas the NED measurement,
    # its L entry ignored): checks the measured axes, makes and fuses the pseudo-measurement
    axis.update_from_model(model, f_mean_body_mps2, E, v_meas)
    # report axis.state() -> AidedState(v_mps, sigma_mps, aided, why)

Nothing else is needed: the model is not learnt while an axis is lost, and a new
:class:`AidedAxis` is made at each new loss.
"""

from glmav_observer.estimation.aero.aided import AidedAxis, AidedAxisConfig, AidedState
from glmav_observer.estimation.aero.model import (
    N_PARAM,
    DragModel,
    DragModelConfig,
    PseudoMeasurement,
    Trust,
)

__all__ = [
    "N_PARAM",
    "AidedAxis",
    "AidedAxisConfig",
    "AidedState",
    "DragModel",
    "DragModelConfig",
    "PseudoMeasurement",
    "Trust",
]
