"""The swash-plate cyclic regressors of the drag model, from the actuator outputs.

On a coaxial helicopter like the paper's GLMAV the horizontal body-frame specific force is
dominated by the lower rotor's tilted thrust, not by drag (``equations.md`` eq. 5):

    T_x = −β sin δcy cos δcx Ω2²,   T_y = −β sin δcx Ω2²

so with the cyclic command known the drag row (A1) of :mod:`.model` gains one term per
horizontal body axis j, linear in an unknown gain b_j (≈ β/m, learnt with the rest):

    f_j = … + b_j ρ_j,   ρ_x = −sin δcy cos δcx (Ω2/Ω_ref)²,   ρ_y = −sin δcx (Ω2/Ω_ref)²  (C1)

Ω_ref = 100 rad/s only scales ρ to order one (b in m/s²; the default GLMAV's
β/m · Ω_ref² = 2.21e-5 / 0.2 · 1e4 = 1.1 m/s²).

The angles and the rotor speed come from ``SERVO_OUTPUT_RAW``
(:class:`~glmav_observer.ingest.samples.ControlSample`) through a linear map per channel,
value = (pwm − pwm_zero) · per_us, given by ``[estimation.aero_control]``
(:class:`ControlMapping`; the defaults are glmav-sitl's, ``glmav_sitl/mavlink/servo.py``:
Ω = (pwm − 1000) · omega_max/1000, δ = (pwm − 1500) · swash_limit/500 with omega_max
320 rad/s and swash_limit 0.26 rad). A channel reading 0 (unused) or a control older than
``max_age_s`` gives no regressor: the model then neither learns nor predicts from that
sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Ω_ref of (C1), rad/s
OMEGA_REF_RADPS = 100.0


@dataclass(frozen=True, slots=True)
class ControlMapping:
    """Which SERVO_OUTPUT_RAW channel (1-based) carries Ω2 (the lower rotor, whose thrust
    the swash-plate tilts), δcx and δcy, and their linear maps (module docstring)."""

    omega2_channel: int = 2
    omega2_pwm_zero_us: float = 1000.0
    omega2_radps_per_us: float = 0.32
    dcx_channel: int = 3
    dcx_pwm_zero_us: float = 1500.0
    dcx_rad_per_us: float = 0.26 / 500.0
    dcy_channel: int = 4
    dcy_pwm_zero_us: float = 1500.0
    dcy_rad_per_us: float = 0.26 / 500.0
    #: a held control older than this (vehicle s) is not used: 5 periods of a 50 Hz stream
    max_age_s: float = 0.1

    def regressors(self, servo_pwm_us: tuple[int, ...]) -> tuple[float, float] | None:
        """(ρ_x, ρ_y) of (C1) from one SERVO_OUTPUT_RAW, or None when a channel is unused
        (0) or absent."""
        chans = (self.omega2_channel, self.dcx_channel, self.dcy_channel)
        if max(chans) > len(servo_pwm_us) or min(chans) < 1:
            return None
        pw, px, py = (servo_pwm_us[c - 1] for c in chans)
        if pw <= 0 or px <= 0 or py <= 0:
            return None
        omega2 = (pw - self.omega2_pwm_zero_us) * self.omega2_radps_per_us
        dcx = (px - self.dcx_pwm_zero_us) * self.dcx_rad_per_us
        dcy = (py - self.dcy_pwm_zero_us) * self.dcy_rad_per_us
        w2 = (omega2 / OMEGA_REF_RADPS) ** 2
        return (-math.sin(dcy) * math.cos(dcx) * w2, -math.sin(dcx) * w2)
