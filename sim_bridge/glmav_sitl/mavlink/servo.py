"""The actuator outputs as ``SERVO_OUTPUT_RAW`` (what a real GLMAV autopilot streams).

The simulator's commanded input u = (Ω1, Ω2, δcx, δcy) (``dynamics/model.py``: rotor
speeds in rad/s, swash-plate cyclic angles in rad; the physics clips them to
[0, ``omega_max``] and [−``swash_limit``, ``swash_limit``] and follows them with first-order
lags) is mapped linearly to PWM microseconds, ranges from the vehicle file:

=======  =====  ==========================================  =====================
channel  input  PWM (µs)                                    resolution (1 µs)
=======  =====  ==========================================  =====================
1        Ω1     1000 + 1000 Ω1 / omega_max                  omega_max / 1000
2        Ω2     1000 + 1000 Ω2 / omega_max                  omega_max / 1000
3        δcx    1500 + 500 δcx / swash_limit                swash_limit / 500
4        δcy    1500 + 500 δcy / swash_limit                swash_limit / 500
=======  =====  ==========================================  =====================

Values are rounded to the nearest µs and saturated to [1000, 2000] (the clip of the
physics); channels 5-8 are 0 (unused). The default vehicle (omega_max 320 rad/s,
swash_limit 0.26 rad) resolves 0.32 rad/s and 0.52 mrad.
"""

from __future__ import annotations

from collections.abc import Sequence

from glmav_sitl.params import VehicleParams

PWM_MIN_US = 1000
PWM_MAX_US = 2000
PWM_MID_US = 1500


def _pwm(x: float) -> int:
    v = round(x)
    return PWM_MIN_US if v < PWM_MIN_US else (PWM_MAX_US if v > PWM_MAX_US else v)


def servo_pwm_us(u: Sequence[float], params: VehicleParams) -> tuple[int, int, int, int]:
    """Channels 1-4 (µs) of the commanded input ``u`` = (Ω1, Ω2, δcx, δcy) (module table)."""
    k_rotor = (PWM_MAX_US - PWM_MIN_US) / params.omega_max
    k_swash = (PWM_MAX_US - PWM_MID_US) / params.swash_limit
    return (
        _pwm(PWM_MIN_US + k_rotor * u[0]),
        _pwm(PWM_MIN_US + k_rotor * u[1]),
        _pwm(PWM_MID_US + k_swash * u[2]),
        _pwm(PWM_MID_US + k_swash * u[3]),
    )
