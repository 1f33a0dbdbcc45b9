"""Wind in earth axes (NED): constant + discrete 1-cosine gusts + turbulence.

- 1-cosine gust (the discrete gust shape of MIL-F-8785C / FAR 25):
  ``w(t) = A/2 (1 - cos(2 pi (t - t0) / T))`` for ``t0 <= t <= t0 + T``.
- Turbulence: per axis a first-order Gauss-Markov process (the Dryden spectrum's
  dominant pole, ``tau = L / V``), discretised exactly:
  ``w_{k+1} = a w_k + sigma sqrt(1 - a^2) n_k``, ``a = exp(-dt / tau)``, so its
  stationary standard deviation is ``sigma`` at any update rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Gust:
    t_start_s: float
    duration_s: float
    amplitude_ned_mps: tuple[float, float, float]


@dataclass(frozen=True)
class WindConfig:
    constant_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gusts: tuple[Gust, ...] = ()
    turbulence_sigma_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turbulence_time_constant_s: float = 1.0


@dataclass
class WindModel:
    """Evaluate the wind at sim time ``t_s``; call :meth:`update` once per control tick."""

    config: WindConfig
    rng: np.random.Generator
    _turb: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    _t_last_s: float | None = None
    _turbulent: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        sig = self.config.turbulence_sigma_mps
        self._turbulent = any(s > 0.0 for s in sig)
        if self._turbulent:
            # start in the stationary distribution
            self._turb = [
                s * float(n) for s, n in zip(sig, self.rng.standard_normal(3), strict=True)
            ]

    def update(self, t_s: float) -> tuple[float, float, float]:
        """Advance the turbulence to ``t_s`` and return the total wind (NED, m/s)."""
        cfg = self.config
        sig = cfg.turbulence_sigma_mps
        if self._turbulent and self._t_last_s is not None:
            dt = t_s - self._t_last_s
            if dt > 0.0:
                a = math.exp(-dt / cfg.turbulence_time_constant_s)
                b = math.sqrt(1.0 - a * a)
                n = self.rng.standard_normal(3)
                self._turb = [
                    a * w + s * b * float(e) for w, s, e in zip(self._turb, sig, n, strict=True)
                ]
        self._t_last_s = t_s
        wn, we, wd = cfg.constant_ned_mps
        for g in cfg.gusts:
            if g.t_start_s <= t_s <= g.t_start_s + g.duration_s:
                k = 0.5 * (1.0 - math.cos(2.0 * math.pi * (t_s - g.t_start_s) / g.duration_s))
                wn += k * g.amplitude_ned_mps[0]
                we += k * g.amplitude_ned_mps[1]
                wd += k * g.amplitude_ned_mps[2]
        return (wn + self._turb[0], we + self._turb[1], wd + self._turb[2])
