"""Observer bank speed: one bank update (4 configurations) vs a filterpy KalmanFilter step,
and the batched bank (100 vehicles × 4 configurations) in configuration-updates per second.

Baseline measured in the same run: filterpy ``KalmanFilter(dim_x=3, dim_z=3)``
``predict()`` + ``update(z)``, the 3-state velocity filter a Python user would write.
Inputs cycle through 1000 samples of the exact-kinematics scenario of ``glmav-observer
check`` so that no step repeats the previous one's values.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks.common import format_goals, format_table, goal, main_for, time_per_call_s
from glmav_observer.commands.check import exact_kinematics_scenario
from glmav_observer.estimation.bank import BatchedBank, ObserverBank
from glmav_observer.estimation.observer import gamma_body_mps2, zoh_step
from glmav_observer.frames import e_exact

N_VEHICLES = 100
N_SAMPLES = 1000


def _filterpy_step() -> Any:
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=3, dim_z=3)
    kf.F = np.eye(3)
    kf.H = np.eye(3)
    kf.R = np.eye(3) * 0.05**2
    kf.Q = np.eye(3) * 1e-4
    rng = np.random.default_rng(0)
    zs = list(rng.normal(size=(N_SAMPLES, 3)))
    it = iter(range(10**12))

    def step() -> None:
        kf.predict()
        kf.update(zs[next(it) % N_SAMPLES])

    return step


def run(quick: bool = False) -> dict[str, Any]:
    number = 2000 if quick else 20000
    repeats = 3 if quick else 9
    sc = exact_kinematics_scenario(np.arange(N_SAMPLES) * 0.004)
    samples = [
        (sc.euler_rad[k], sc.omega_body_radps[k], sc.f_body_mps2[k], sc.v_ned_mps[k])
        for k in range(N_SAMPLES)
    ]
    rows: list[dict[str, Any]] = []

    kf_t = time_per_call_s(_filterpy_step(), number=number, repeats=repeats)
    rows.append({"case": "filterpy KalmanFilter predict+update (3 states, 3 meas.)",
                 "median_us": kf_t["median_s"] * 1e6, "per_config_update_us": float("nan")})  # fmt: skip

    bank = ObserverBank()
    it = iter(range(10**12))

    def bank_step() -> None:
        e, w, f, y = samples[next(it) % N_SAMPLES]
        bank.step(0.004, e, w, f, y)

    bank_t = time_per_call_s(bank_step, number=number, repeats=repeats)
    rows.append({"case": "ObserverBank.step, 4 configs, fixed Δt (250 Hz)",
                 "median_us": bank_t["median_s"] * 1e6,
                 "per_config_update_us": bank_t["median_s"] * 1e6 / 4})  # fmt: skip

    rng = np.random.default_rng(1)
    dts = list(0.004 + rng.uniform(-2e-4, 2e-4, size=N_SAMPLES))
    bank_j = ObserverBank()

    def bank_step_jitter() -> None:
        k = next(it) % N_SAMPLES
        e, w, f, y = samples[k]
        bank_j.step(dts[k], e, w, f, y)

    jit_t = time_per_call_s(bank_step_jitter, number=number, repeats=repeats)
    rows.append({"case": "ObserverBank.step, 4 configs, jittered Δt (φ recomputed)",
                 "median_us": jit_t["median_s"] * 1e6,
                 "per_config_update_us": jit_t["median_s"] * 1e6 / 4})  # fmt: skip

    E = e_exact(sc.euler_rad)
    G = gamma_body_mps2(sc.f_body_mps2, sc.euler_rad)
    x1 = np.zeros(3)
    m1 = np.array([True, True, False])

    def pure_step() -> None:
        k = next(it) % N_SAMPLES
        zoh_step(x1, sc.omega_body_radps[k], G[k], E[k], sc.v_ned_mps[k], m1, 90.0, 0.004,
                 orthogonal_e=True)  # fmt: skip

    pure_t = time_per_call_s(pure_step, number=max(number // 4, 500), repeats=repeats)
    rows.append({"case": "zoh_step (numpy, 1 config, with validation)",
                 "median_us": pure_t["median_s"] * 1e6,
                 "per_config_update_us": pure_t["median_s"] * 1e6})  # fmt: skip

    bb = BatchedBank(N_VEHICLES)
    idx = rng.integers(0, N_SAMPLES, size=(N_SAMPLES // 10, N_VEHICLES))
    batches = [
        (sc.euler_rad[i], sc.omega_body_radps[i], sc.f_body_mps2[i], sc.v_ned_mps[i]) for i in idx
    ]

    def batched_step() -> None:
        e, w, f, y = batches[next(it) % len(batches)]
        bb.step(0.004, e, w, f, y)

    b_t = time_per_call_s(batched_step, number=max(number // 40, 50), repeats=repeats)
    per_cfg = b_t["median_s"] / (4 * N_VEHICLES)
    rows.append({"case": f"BatchedBank.step, {N_VEHICLES} vehicles × 4 configs",
                 "median_us": b_t["median_s"] * 1e6, "per_config_update_us": per_cfg * 1e6})  # fmt: skip

    ratio = bank_t["median_s"] / kf_t["median_s"]
    ratio_j = jit_t["median_s"] / kf_t["median_s"]
    goals = [
        goal("bank step / filterpy step (fixed Δt)", ratio, 0.5, higher_is_better=False),
        goal("bank step / filterpy step (jittered Δt)", ratio_j, 0.5, higher_is_better=False),
        goal("batched config-updates per second", 1.0 / per_cfg, 1e6, higher_is_better=True),
    ]
    return {
        "name": "bench_observer",
        "quick": quick,
        "rows": rows,
        "goals": goals,
        "timings": {
            "filterpy": kf_t,
            "bank": bank_t,
            "bank_jitter": jit_t,
            "zoh_step": pure_t,
            "batched": b_t,
        },
    }


def to_markdown(result: dict[str, Any]) -> str:
    return (
        "### Observer bank (bench_observer)\n\n"
        "Medians over repeats of the mean time per call; one core.\n\n"
        + format_table(result["rows"])
        + "\n\n"
        + format_goals(result["goals"])
    )


if __name__ == "__main__":
    import sys

    sys.exit(main_for(sys.modules[__name__]))
