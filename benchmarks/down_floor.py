"""The down axis of a clean flight against its floor: the IMU the link carries (issue 29).

Between two of the autopilot's velocity samples (``LOCAL_POSITION_NED``, 18 Hz on
ArduPilot's SITL), the estimate is carried by the IMU messages the link carries. ArduPilot
sends ``RAW_IMU``/``SCALED_IMU`` at 50 Hz as **snapshots** of its accelerometer, not the
delta velocities its own EKF integrates at 400 Hz, so the vibration of the vertical
specific force enters the carried estimate as a random walk the autopilot's own estimate
does not have. Its size over one velocity interval T, with snapshots every h and a
snapshot noise σ_a (the spread of the vertical specific force about its 1 s mean):

    σ_walk = σ_a · h · √(T / h)

and the floor of the published down axis is √(autopilot² + σ_walk²): the autopilot's
own error, which the estimate cannot beat at its samples, and the walk between them.
For each flight of the tuning corpus: the service's ``full`` down RMSE against truth
(SIM_STATE), the autopilot's own, σ_a, T and h measured on the log, the floor, and the
ratios to the autopilot (issue 29 asked ≤ 1.1×).

Not a floor after all: since the bank follows the measurement's ramp over each step
(docs/design/observer-notes.md), the estimate is below it on a_quad_wind and g_heli_clean
(`full / floor` 0.90 and 0.96): the bank is pulled back to the measurement within ~1/γ
and does not carry the walk over a whole interval. The table stays as the measurement of
what the snapshots add; docs/field-failures.md says what is left open on the down axis.
"""

from __future__ import annotations

import lzma
import math
import statistics
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import format_table, git_head, goal, machine, main_for
from glmav_observer.ingest.framing import iter_tlog
from glmav_testkit.fault_replay import replay

CORPUS = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardupilot_sitl"
#: the flights with a velocity-relevant autopilot fault are left out (as the corpus's
#: clean-flight rows do): GPS off, GPS noise, GPS glitch, an accelerometer bias
CLEAN = ("a_quad_wind", "e_quad_vib", "f_coax_clean", "g_heli_clean")
#: the window of the "1 s mean" the snapshot spread is taken about (samples at 50 Hz)
MEAN_WINDOW = 50
G0 = 9.80665


def _imu_and_lpn(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t_imu, z, t_y = [], [], []
    for rec in iter_tlog(data):
        m = rec.msg
        name = m.get_type()
        if name == "RAW_IMU":
            t_imu.append(m.time_usec * 1e-6)
            z.append(m.zacc * G0 / 1000.0)  # ArduPilot: mg
        elif name == "LOCAL_POSITION_NED":
            t_y.append(m.time_boot_ms * 1e-3)
    return np.array(t_imu), np.array(z), np.array(t_y)


def _flight(name: str, tmp: Path) -> dict[str, Any]:
    data = lzma.decompress((CORPUS / f"{name}.tlog.xz").read_bytes())
    path = tmp / f"{name}.tlog"
    path.write_bytes(data)
    t_imu, z, t_y = _imu_and_lpn(data)
    airborne = (t_imu > t_imu[0] + 60.0) & (t_imu < t_imu[-1] - 5.0)  # the pattern's span
    zz = z[airborne]
    mean = np.convolve(zz, np.ones(MEAN_WINDOW) / MEAN_WINDOW, mode="same")
    sigma_a = float((zz - mean)[MEAN_WINDOW:-MEAN_WINDOW].std())
    h = float(np.median(np.diff(t_imu)))
    interval = float(np.median(np.diff(t_y)))
    walk = sigma_a * h * math.sqrt(interval / h)
    r = replay(path)
    full = r.rmse_ned_mps["full"]
    ap = r.rmse_ned_mps["measurement"]
    assert full is not None and ap is not None
    floor = math.hypot(ap[2], walk)
    return {
        "flight": name,
        "full_down_mps": full[2],
        "autopilot_down_mps": ap[2],
        "sigma_a_mps2": sigma_a,
        "imu_h_ms": h * 1e3,
        "lpn_T_ms": interval * 1e3,
        "walk_mps": walk,
        "floor_mps": floor,
        "full / autopilot": full[2] / ap[2],
        "floor / autopilot": floor / ap[2],
        "full / floor": full[2] / floor,
    }


def run(quick: bool = False) -> dict[str, Any]:
    names = CLEAN[:2] if quick else CLEAN
    with tempfile.TemporaryDirectory() as tmp:
        rows = [_flight(n, Path(tmp)) for n in names]
    worst = max(r["full / floor"] for r in rows)
    return {
        "name": "down_floor",
        "machine": machine(),
        "git_head": git_head(),
        "quick": quick,
        "rows": rows,
        "goals": [
            goal(
                "clean flights: `full` down RMSE / its floor, worst",
                worst,
                1.1,
                higher_is_better=False,
            ),
            goal(
                "clean flights: the floor / the autopilot's down RMSE, median (issue 29 asked "
                "<= 1.1x of `full`)",
                statistics.median(r["floor / autopilot"] for r in rows),
                1.1,
                higher_is_better=False,
            ),
        ],
    }


def to_markdown(result: dict[str, Any]) -> str:
    return (
        "### The down axis against its floor (down_floor)\n\n"
        "Command: `python -m benchmarks.down_floor` — the clean flights of the tuning "
        "corpus; floor = √(autopilot² + (σ_a·h·√(T/h))²) (module docstring).\n\n"
        + "\n\n".join([format_table(result["rows"])])
    )


if __name__ == "__main__":
    raise SystemExit(main_for(__import__(__name__)))
