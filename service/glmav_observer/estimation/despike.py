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
from dataclasses import dataclass

from glmav_observer.estimation.reasons import const

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class DespikeConfig:
    """The spike threshold (``[fdi.despike]`` of ``configs/service.toml``)."""

    floor_mps2: float = const(
        40.0, unit="m/s²", source="physics",
        reason="the smallest ‖Δf‖ between successive IMU samples held out as a spike: "
        "4 g, beyond a multirotor's manoeuvre between two samples (< 1 g at 50 Hz) and "
        "below a shock's or a corrupt value's (hundreds of m/s²); raise it for a vehicle "
        "whose IMU sees larger steps (a launch)",
    )  # fmt: skip
    k_sigma: float = const(
        8.0, unit="σ", source="statistic",
        reason="or this many RMS of ‖Δf‖ between accepted samples, if larger: a vibrating "
        "IMU raises its own bar (ArduPilot SITL SIM_ACC1_RND = 5: ‖Δf‖ RMS ≈ 12 m/s²); "
        "white noise exceeds 8 RMS practically never (‖Δf‖²/2σ² ~ χ²₃ > 192: 2e-41)",
    )  # fmt: skip
    tau_samples: int = const(
        100, unit="samples", source="physics",
        reason="memory of the running ‖Δf‖ RMS: 2 s at 50 Hz, fast against a change of "
        "vibration (throttle), slow against one spike",
    )  # fmt: skip


class Despiker:
    """Holds out isolated specific-force spikes (module docstring)."""

    def __init__(self, cfg: DespikeConfig | None = None) -> None:
        c = cfg or DespikeConfig()
        self.floor_mps2 = c.floor_mps2
        self.k_sigma = c.k_sigma
        self._k = 1.0 / c.tau_samples
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
