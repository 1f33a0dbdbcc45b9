"""One-sample IMU shock rejection (pure).

A gun-launched vehicle's IMU sees shocks, and a CRC-valid frame can carry one corrupt
value within the plausible range (:data:`glmav_observer.ingest.convert.IMU_MAX_F_MPS2`).
Integrated over a 20 ms hold, one 1000 m/s² sample is a 20 m/s velocity step. A sample
whose specific force differs from the last accepted one by more than the spike threshold
is held out; if the next sample agrees with it (the level really changed, e.g. at launch)
that next sample is accepted, so a real step costs one sample of delay.

Threshold: max(``floor_mps2``, ``k_sigma`` × the running RMS of ‖Δf‖ between accepted
samples), so a vibrating IMU (ArduPilot SITL with SIM_ACC1_RND = 5: ‖Δf‖ RMS ≈ 12 m/s²)
raises its own bar.
"""

from __future__ import annotations

import math

Vec3 = tuple[float, float, float]


class Despiker:
    """Holds out isolated specific-force spikes (module docstring)."""

    def __init__(self, floor_mps2: float = 40.0, k_sigma: float = 8.0, tau_samples: int = 100):
        self.floor_mps2 = floor_mps2
        self.k_sigma = k_sigma
        self._k = 1.0 / tau_samples
        self._last: Vec3 | None = None
        self._candidate: Vec3 | None = None
        self._ms_diff = 0.0

    def noise_var_mps2(self) -> float:
        """σ_f² per axis: E‖Δf‖² = 2 · 3 σ_f² for white noise on three axes."""
        return self._ms_diff / 6.0

    def threshold_mps2(self) -> float:
        return max(self.floor_mps2, self.k_sigma * math.sqrt(self._ms_diff))

    def filter(self, f_body_mps2: Vec3) -> Vec3 | None:
        """The sample to use, or None when ``f_body_mps2`` is held out as a spike."""
        last = self._last
        if last is None:
            self._last = f_body_mps2
            return f_body_mps2
        d = math.dist(f_body_mps2, last)
        thr = self.threshold_mps2()
        cand = self._candidate
        self._candidate = None
        if d > thr and (cand is None or math.dist(f_body_mps2, cand) > thr):
            self._candidate = f_body_mps2
            return None
        if d <= thr:  # a step confirmed by this sample does not teach the noise level
            self._ms_diff += self._k * (d * d - self._ms_diff)
        self._last = f_body_mps2
        return f_body_mps2
