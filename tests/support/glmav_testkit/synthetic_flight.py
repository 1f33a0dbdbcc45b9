"""A synthetic flight with exact kinematics for the vehicle estimator's tests (no simulator).

The flight: NED velocity V(t) = (2 + 0.5 sin 0.7t, 0.8 sin 0.5t, 0.3 sin 0.9t) m/s,
attitude φ = 0.1 sin 0.6t, θ = −0.08 + 0.05 sin 0.4t, ψ = 0.3 + 0.2 sin 0.2t rad; the
IMU reads f = Eᵀ(V̇ − g e_d) + b + noise at 250 Hz with b = (0.15, −0.1, 0.12) m/s² in
body axes (the design's turn-on σ 0.2 m/s²) and noise 4e-3·√250 m/s²; ω from the
Euler rates (exact kinematics); ATTITUDE at 100 Hz; LOCAL_POSITION_NED at 30 Hz with
σ 0.05 m/s per axis (design.md defaults); truth at 50 Hz. ``FAULTS`` and
:func:`freeze` make velocity faults of one axis.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np

from glmav_observer.ingest.samples import (
    AttitudeSample,
    ImuSample,
    ImuSource,
    Sample,
    TruthSample,
    VelocitySample,
)

G = 9.81
BIAS_BODY = np.array([0.15, -0.1, 0.12])


def truth(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    v = np.array([2 + 0.5 * math.sin(0.7 * t), 0.8 * math.sin(0.5 * t), 0.3 * math.sin(0.9 * t)])
    vd = np.array([0.35 * math.cos(0.7 * t), 0.4 * math.cos(0.5 * t), 0.27 * math.cos(0.9 * t)])
    eul = np.array(
        [0.1 * math.sin(0.6 * t), -0.08 + 0.05 * math.sin(0.4 * t), 0.3 + 0.2 * math.sin(0.2 * t)]
    )
    eul_d = np.array([0.06 * math.cos(0.6 * t), 0.02 * math.cos(0.4 * t), 0.04 * math.cos(0.2 * t)])
    return v, vd, eul, eul_d


def _E(eul: np.ndarray) -> np.ndarray:
    f, t, p = eul
    sf, cf, st, ct, sp, cp = (
        math.sin(f), math.cos(f), math.sin(t), math.cos(t), math.sin(p), math.cos(p)
    )  # fmt: skip
    return np.array(
        [
            [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
            [-st, sf * ct, cf * ct],
        ]
    )


Fault = Callable[[float, np.ndarray], np.ndarray]


def flight(
    duration_s: float,
    seed: int = 1,
    fault: Fault | None = None,
    accel_bias_step: tuple[float, np.ndarray] | None = None,
) -> Iterator[Sample]:
    """Samples in time order (integer µs clock so that rates interleave exactly).

    ``accel_bias_step`` = (t, Δb): the accelerometer's body-frame bias steps by Δb at t.
    """
    rng = np.random.default_rng(seed)
    sig_f = 4e-3 * math.sqrt(250)
    for k in range(int(duration_s * 1000) + 1):  # 1 kHz grid of ms ticks
        t = k / 1000.0
        v, vd, eul, eul_d = truth(t)
        E = _E(eul)
        if k % 4 == 0:  # IMU 250 Hz
            f = E.T @ (vd - np.array([0, 0, G])) + BIAS_BODY + rng.normal(0, sig_f, 3)
            if accel_bias_step is not None and t >= accel_bias_step[0]:
                f = f + accel_bias_step[1]
            fi, th = eul[0], eul[1]
            Winv = np.array(
                [
                    [1, 0, -math.sin(th)],
                    [0, math.cos(fi), math.sin(fi) * math.cos(th)],
                    [0, -math.sin(fi), math.cos(fi) * math.cos(th)],
                ]
            )
            w = Winv @ eul_d
            yield ImuSample(1, t, tuple(f), tuple(w), ImuSource.HIGHRES_IMU)  # type: ignore[arg-type]
        if k % 10 == 0:  # ATTITUDE 100 Hz
            e = eul + rng.normal(0, 0.005, 3)
            yield AttitudeSample(1, t, tuple(e), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
        if k % 33 == 0:  # LOCAL_POSITION_NED ~30 Hz
            y = v + rng.normal(0, 0.05, 3)
            if fault is not None:
                y = fault(t, y)
            yield VelocitySample(1, t, (0.0, 0.0, 0.0), tuple(y))  # type: ignore[arg-type]
        if k % 20 == 0:  # truth 50 Hz
            yield TruthSample(1, t, tuple(eul), tuple(v))  # type: ignore[arg-type]


def _noise(j: int, t0: float, rng: np.random.Generator) -> Fault:
    """A noise burst of sigma 0.5 m/s on axis j from t0."""
    return lambda t, y: y + ((np.arange(3) == j) * rng.normal(0, 0.5, 3) if t >= t0 else 0.0)


FAULTS: dict[str, Callable[[int, float], Fault]] = {
    "dropout": lambda j, t0: lambda t, y: np.where((np.arange(3) == j) & (t >= t0), np.nan, y),
    # 0.5 m/s (the corpus's smaller bias): the bias test's threshold is 5 s, s >= 0.05 m/s
    # here (the measurement's σ), so 0.25-0.3 m/s: a 0.3 m/s step would sit at the edge
    "bias": lambda j, t0: lambda t, y: y + (0.5 * (np.arange(3) == j) if t >= t0 else 0.0),
    "noise": lambda j, t0: _noise(j, t0, np.random.default_rng(7)),
}


def freeze(j: int, t0: float) -> Fault:
    held: list[float] = []

    def f(t: float, y: np.ndarray) -> np.ndarray:
        if t < t0:
            return y
        if not held:
            held.append(float(y[j]))
        y = y.copy()
        y[j] = held[0]
        return y

    return f
