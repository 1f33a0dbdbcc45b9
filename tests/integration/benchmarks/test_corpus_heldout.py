"""The held-out ArduPilot SITL corpus (``tests/data/ardupilot_sitl_heldout``) and what the
corpus benchmark measures on it: the flights are there, differ from the tuning set, carry
truth, the autopilot's velocity, the IMUs and their fault windows; the best-fit lag the
benchmark prints finds a known delay."""

from __future__ import annotations

import json
import math
from collections import Counter
from types import SimpleNamespace

import pytest
from benchmarks.corpus import DATA, HELDOUT, best_fit_lag_s, held_rmse

from glmav_observer.ingest.framing import iter_tlog
from glmav_observer.records import TruthRecord, VelocityRecord
from glmav_testkit.fault_replay import RecordCollector, Series, read_log_bytes

FLIGHTS = sorted(p.name.split(".")[0] for p in HELDOUT.glob("*.tlog.xz"))


def test_the_held_out_set_is_ten_flights_or_more_and_not_the_tuning_set() -> None:
    tuning = {p.name.split(".")[0] for p in DATA.glob("*.tlog.xz")}
    assert len(FLIGHTS) >= 10
    assert not tuning & set(FLIGHTS)
    sides = [json.loads((HELDOUT / f"{n}.json").read_text()) for n in FLIGHTS]
    assert all(s["result"] == "ok" for s in sides)
    # diversity the issue asks for: several frames, winds 0-8 m/s, two IMU rates
    assert {s["vehicle"] for s in sides} >= {"quad", "hexa", "octa", "coax"}
    assert {s["imu_hz"] for s in sides} == {25.0, 50.0}
    winds = [
        next((p["value"] for p in s["environment_params"] if p["name"] == "SIM_WIND_SPD"), 0.0)
        for s in sides
    ]
    assert min(winds) == 0.0 and max(winds) >= 6.0
    # the whole folder stays small enough to live in the repository
    size = sum(p.stat().st_size for p in HELDOUT.iterdir())
    assert size < 8.5e6, f"{size / 1e6:.1f} MB"  # the budget: about 8 MB


@pytest.mark.parametrize("name", FLIGHTS)
def test_each_flight_has_truth_the_autopilot_three_imus_and_its_windows(name: str) -> None:
    side = json.loads((HELDOUT / f"{name}.json").read_text())
    counts: Counter[str] = Counter()
    t_max_s = 0.0
    for rec in iter_tlog(read_log_bytes(HELDOUT / f"{name}.tlog.xz")):
        counts[rec.msg.get_type()] += 1
        t_max_s = max(t_max_s, getattr(rec.msg, "time_boot_ms", 0) * 1e-3)
    for msg in ("SIM_STATE", "LOCAL_POSITION_NED", "ATTITUDE", "RAW_IMU"):
        assert counts[msg] > 1000, (msg, counts[msg])
    if side["fault"].startswith("acc"):
        # the accelerometer flights keep all three IMUs (which one is wrong), the others
        # the first only (RAW_IMU; the folder's size)
        assert counts["SCALED_IMU2"] == counts["SCALED_IMU3"] == counts["RAW_IMU"]
    # IMU at the recorded rate: at least 80 s of pattern (plus take-off) at imu_hz, and
    # no more than the whole log at imu_hz (+5 % for ArduPilot's scheduling)
    assert 80 * side["imu_hz"] <= counts["RAW_IMU"] <= 1.05 * side["imu_hz"] * t_max_s
    w0, w1 = side["pattern_window_time_boot_ms"]
    for f in side["faults"]:
        assert w0 <= f["start_time_boot_ms"] < f["end_time_boot_ms"] <= w1


def _collector(delay_s: float) -> RecordCollector:
    """Truth at 50 Hz, an estimate at 25 Hz equal to the truth ``delay_s`` earlier."""

    def v(t: float) -> tuple[float, float, float]:
        return (3 * math.sin(0.9 * t), 2 * math.cos(1.3 * t), 0.5 * math.sin(2.1 * t))

    c = RecordCollector()
    for k in range(50 * 60):
        t = 0.02 * k
        c.write(TruthRecord(1, t, (0, 0, 0), v(t), (0, 0, 0), None, k))
    for k in range(25 * 58):
        t = 1.0 + 0.04 * k + 0.003  # not on the truth's grid
        c.write(VelocityRecord(1, "full", t, (0, 0, 0), v(t - delay_s), None, "ok", k))
    return c


@pytest.mark.parametrize("delay_s", [0.0, 0.010, 0.025, 0.047])
def test_best_fit_lag_finds_a_known_delay(delay_s: float) -> None:
    r = SimpleNamespace(collector=_collector(delay_s), skip_s=0.0)
    lag = best_fit_lag_s(r, "full")
    # 1 ms grid; linear interpolation of the 50 Hz truth of a signal this smooth (the
    # fastest term 2.1 rad/s: curvature error < 0.5*0.02²/4*2.1²*0.5 ≈ 1e-4 m/s) moves the
    # minimum by far less than a grid step
    assert lag == pytest.approx(delay_s, abs=0.0011)
    assert best_fit_lag_s(r, "active") is None  # no such series


def test_autopilot_held_at_the_estimates_instants() -> None:
    """``held_rmse``: the autopilot's velocity as its consumer has it at full's instants.
    Truth v_n(t) = t m/s; the autopilot exact at 10 Hz; full at 50 Hz. Held, the error at
    a record 0, 20, 40, 60 or 80 ms after the latest autopilot sample is that age (1 m/s²
    of acceleration), each age equally often: RMSE √(mean of the squared ages) = √0.0024
    m/s; east and down constant: 0."""
    c = RecordCollector()
    for k in range(1001):  # truth at 100 Hz over 10 s
        c.truth.t_s.append(k / 100)
        c.truth.v_ned_mps.append((k / 100, 0.0, 0.0))
    m = c.series.setdefault("measurement", Series())
    for k in range(101):
        m.t_s.append(k / 10)
        m.v_ned_mps.append((k / 10, 0.0, 0.0))
    full = c.series.setdefault("full", Series())
    for k in range(500):  # 0 .. 9.98 s: every age 100 times
        full.t_s.append(k / 50)
        full.v_ned_mps.append((k / 50, 0.0, 0.0))
    r = SimpleNamespace(collector=c, skip_s=0.0)
    held = held_rmse(r)
    assert held is not None
    # float time stamps (k/50 against k/10) put an age off by at most 1e-15 s
    assert held[0] == pytest.approx(math.sqrt(0.0024), abs=1e-12)
    assert held[1] == 0.0 and held[2] == 0.0
    assert held_rmse(r, "active") is None  # no such series
