"""A GPS loss and a silent measurement stream on ArduPilot's SITL telemetry: the axes that
rest on dead reckoning are flagged in every record from the first evidence, with a σ that
covers the error, and the published estimate stays as good as the autopilot's own.

``b_quad_gps_off``: ``SIM_GPS1_ENABLE=0`` at 78.679 s for 10 s. ``a_quad_wind``, with its
``LOCAL_POSITION_NED`` removed for 10 s (a silent outage of the velocity stream).
"""

from __future__ import annotations

import json
import lzma
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.gps_bridge import GpsBridgeConfig
from glmav_observer.estimation.vehicle import EstimatorConfig
from glmav_observer.evaluation import interpolate_truth
from glmav_observer.ingest.framing import FrameCounters, iter_tlog
from glmav_observer.publish.rerun import TIMELINE, read_recording
from glmav_observer.records import HealthRecord, Record, TruthRecord, VelocityRecord
from glmav_testkit.sinks import MemorySink

DATA = Path(__file__).resolve().parents[2] / "data" / "ardupilot_sitl"
BIN = Path(sys.executable).parent


def _messages(name: str) -> list[tuple[Any, float]]:
    data = lzma.decompress((DATA / f"{name}.tlog.xz").read_bytes())
    return [(r.msg, r.t_host_us * 1e-6) for r in iter_tlog(data, FrameCounters())]


def _run(messages: list[tuple[Any, float]], bridge: bool = True) -> tuple[Service, list[Record]]:
    """The messages through a service (``bridge``: the GPS bridge on); it and its records."""
    sink = MemorySink()
    est = EstimatorConfig(gps_bridge=GpsBridgeConfig(enabled=bridge))
    service = Service(ServiceConfig(request_rates=False, estimation=est), [sink])
    for msg, t in messages:
        service.feed_message(msg, t, "log")
    service.close()
    return service, sink.records


def _replay(messages: list[tuple[Any, float]], bridge: bool = True) -> list[Record]:
    return _run(messages, bridge)[1]


def _series(records: list[Record], config: str) -> list[VelocityRecord]:
    return [r for r in records if type(r) is VelocityRecord and r.config == config]


def _truth(records: list[Record]) -> tuple[np.ndarray, np.ndarray]:
    tr = [r for r in records if type(r) is TruthRecord]
    return np.array([r.t_boot_s for r in tr]), np.array([r.v_ned_mps for r in tr])


def _rmse(t: np.ndarray, v: np.ndarray, tt: np.ndarray, vt: np.ndarray) -> np.ndarray:
    ok, truth = interpolate_truth(t, tt, vt)
    return np.sqrt(np.mean((v[ok] - truth[ok]) ** 2, axis=0))


@pytest.fixture(scope="module")
def gps_loss() -> tuple[list[Record], float, float]:
    side = json.loads((DATA / "b_quad_gps_off.json").read_text())
    f = side["faults"][0]
    return (
        _replay(_messages("b_quad_gps_off")),
        f["start_time_boot_ms"] / 1e3,
        f["end_time_boot_ms"] / 1e3,
    )


def _first_gps_loss_evidence(name: str, after_s: float) -> float:
    """The time of the first GPS_RAW_INT without a 3D fix after ``after_s``."""
    t_last = 0.0
    for msg, _ in _messages(name):
        if hasattr(msg, "time_boot_ms"):
            t_last = msg.time_boot_ms * 1e-3
        if msg.get_type() == "GPS_RAW_INT" and msg.fix_type < 3 and t_last > after_s:
            return t_last
    raise AssertionError("no GPS loss in the log")


def test_gps_loss_flags_both_horizontal_axes_at_the_first_evidence(
    gps_loss: tuple[list[Record], float, float],
) -> None:
    records, t_on, t_off = gps_loss
    t_evidence = _first_gps_loss_evidence("b_quad_gps_off", t_on - 1.0)
    # the fix drops 0.4 s after the GPS is disabled (ArduPilot's GPS driver timeout)
    assert t_on < t_evidence < t_on + 1.0
    active = _series(records, "active")
    flagged = [r for r in active if {"n", "e"} <= set(r.dead_reckoned_axes)]
    # flagged at the first active record after the evidence: one IMU period (20 ms) and
    # the 1 ms between the GPS message's stamp and the next IMU sample
    assert flagged[0].t_boot_s - t_evidence < 0.03
    # ... every record until the fix is back (3D again at t_off + 0.44 s), no isolation
    during = [r for r in active if t_evidence + 0.03 <= r.t_boot_s < t_off]
    assert during and all({"n", "e"} <= set(r.dead_reckoned_axes) for r in during)
    assert all(r.health == "dead_reckoning" and r.sigma_ned_mps is not None for r in during)
    assert all(r.lost_axis is None and r.source_config == "full" for r in during)
    # σ grows from the anchor's (FdiConfig.sigma_velocity_mps, 0.04 m/s) with the age of
    # the loss (drift.drift_sigma_ned_mps): 0.30 m/s at 9.6 s
    s = [r.sigma_ned_mps[0] for r in during if r.sigma_ned_mps is not None]
    assert s[0] == pytest.approx(0.04, abs=1e-3) and s[-1] > 0.25
    health = [
        r for r in records if type(r) is HealthRecord and t_evidence + 0.5 < r.t_boot_s < t_off
    ]
    assert health and all(h.axis_state["n"] == "unaided" for h in health)
    # aided again 1 s after the fix is back: nothing flagged
    after = [r for r in active if t_off + 1.5 <= r.t_boot_s < t_off + 10.0]
    assert after and not any(r.dead_reckoned_axes for r in after)


def test_gps_loss_estimate_is_as_good_as_the_autopilots(
    gps_loss: tuple[list[Record], float, float],
) -> None:
    records, t_on, t_off = gps_loss
    tt, vt = _truth(records)
    meas = [r for r in records if r.__class__.__name__ == "MeasurementRecord"]
    tm = np.array([r.t_boot_s for r in meas])  # type: ignore[attr-defined]
    vm = np.array([r.v_ned_mps for r in meas])  # type: ignore[attr-defined]
    active = _series(records, "active")
    ta = np.array([r.t_boot_s for r in active])
    va = np.array([r.v_ned_mps for r in active])
    for a, b in ((t_on, t_off), (t_off, t_off + 10.0)):
        ka, km = (ta >= a) & (ta < b), (tm >= a) & (tm < b)
        ours = _rmse(ta[ka], va[ka], tt, vt)
        autopilot = _rmse(tm[km], vm[km], tt, vt)
        # during the loss the active horizontal axes are the autopilot's velocity carried
        # to the IMU's times (measured 0.2078/0.0406 against 0.2061/0.0407: +1 %). After
        # it (measured 0.0851/0.0404 against 0.0830/0.0401: +2.6 %, +0.7 %) the autopilot
        # resets its velocity to the GPS's in one sample (north 0.375 m/s), and the record
        # built at that sample's IMU time comes before it; no gain closes that
        # (docs/field-failures.md). Bound: the measured ratio with 3 % to spare
        ratio = (1.05, 1.05) if a == t_on else (1.06, 1.04)
        assert ours[0] <= ratio[0] * autopilot[0], (a, ours, autopilot)
        assert ours[1] <= ratio[1] * autopilot[1], (a, ours, autopilot)


def _late_reset(reset_delay_s: float) -> tuple[list[tuple[Any, float]], float]:
    """b_quad_gps_off with the autopilot's velocity reset at the GPS's return moved
    ``reset_delay_s`` later (an autopilot that re-converges after its flags say aided):
    the jump between its last sample before the fix and its first after (north −0.375,
    east +0.088 m/s) is undone on the samples of that delay. Returns the messages and
    the first fix's time."""
    messages = _messages("b_quad_gps_off")
    side = json.loads((DATA / "b_quad_gps_off.json").read_text())
    t_fix = _first_gps_fix(messages, side["faults"][0]["end_time_boot_ms"] / 1e3)
    lp = [m for m, _ in messages if m.get_type() == "LOCAL_POSITION_NED"]
    i = next(k for k, m in enumerate(lp) if m.time_boot_ms * 1e-3 >= t_fix - 0.05)
    dn, de = lp[i - 1].vx - lp[i].vx, lp[i - 1].vy - lp[i].vy
    assert abs(dn) > 0.3  # (the reset is there: north 0.375 m/s)
    for m in lp[i:]:
        if m.time_boot_ms * 1e-3 >= t_fix + reset_delay_s:
            break
        m.vx += dn
        m.vy += de
    return messages, t_fix


def _first_gps_fix(messages: list[tuple[Any, float]], after_s: float) -> float:
    """The time of the first GPS_RAW_INT with a 3D fix after ``after_s``."""
    t_last = 0.0
    for msg, _ in messages:
        if hasattr(msg, "time_boot_ms"):
            t_last = msg.time_boot_ms * 1e-3
        if msg.get_type() == "GPS_RAW_INT" and msg.fix_type >= 3 and t_last > after_s:
            return t_last
    raise AssertionError("no fix after the loss")


def test_the_gps_velocity_bridges_an_autopilot_that_resets_late() -> None:
    """The autopilot resets 0.4 s after the GPS's first fix: the bridge carries the GPS's
    velocity until it agrees, and its FDI does not take the late reset for a fault."""
    messages, t_fix = _late_reset(0.4)
    out = {}
    for bridge in (True, False):
        service, records = _run(messages, bridge)
        vest = next(iter(service.estimators.values()))
        tt, vt = _truth(records)
        active = _series(records, "active")
        ta = np.array([r.t_boot_s for r in active])
        va = np.array([r.v_ned_mps for r in active])
        windows = []
        for a, b in ((t_fix, t_fix + 1.0), (t_fix, t_fix + 10.0)):
            k = (ta >= a) & (ta < b)
            windows.append(_rmse(ta[k], va[k], tt, vt))
        out[bridge] = (windows, vest.faults, vest.counters["gps_bridge_starts"])
    meas = [r for r in records if r.__class__.__name__ == "MeasurementRecord"]
    tm = np.array([r.t_boot_s for r in meas])  # type: ignore[attr-defined]
    vm = np.array([r.v_ned_mps for r in meas])  # type: ignore[attr-defined]
    km = (tm >= t_fix) & (tm < t_fix + 10.0)
    autopilot = _rmse(tm[km], vm[km], tt, vt)
    (w1, w10), faults, starts = out[True]
    (n1, n10), faults_none, _ = out[False]
    assert starts == 1 and faults == []
    # without the bridge the FDI, warmed up on the level before the late reset, takes it
    # for a bias on north and isolates it (measured: at 1.5 s, the end of its warm-up)
    assert [f.axis for f in faults_none] == ["n"]
    # measured north (m/s): first second 0.081 with the bridge, 0.263 without; 10 s 0.092
    # with, 0.208 without, the autopilot 0.119 (the replay is deterministic). ArduPilot's
    # SITL GPS velocity is nearly exact (0.004 m/s at its best lag): a real receiver's
    # gives less; the bounds ask for half the measured gain
    assert w1[0] <= 0.5 * n1[0], (w1, n1)
    assert w10[0] <= 0.9 * min(n10[0], autopilot[0]), (w10, n10, autopilot)
    assert w10[1] <= 1.05 * autopilot[1], (w10, autopilot)


def test_a_gps_whose_velocity_agrees_with_the_autopilots_starts_no_bridge(
    gps_loss: tuple[list[Record], float, float],
) -> None:
    """b_quad_gps_off as recorded: ArduPilot resets its velocity at the GPS's first fix,
    so the GPS's velocity agrees with it there (within start_sigma σ_gps) and nothing is
    bridged: the estimate is the one without a bridge."""
    with_bridge, _, _ = gps_loss
    without = _replay(_messages("b_quad_gps_off"), bridge=False)
    a = [r.v_ned_mps for r in _series(with_bridge, "active")]
    b = [r.v_ned_mps for r in _series(without, "active")]
    assert len(a) > 4000 and a == b


@pytest.fixture(scope="module")
def outage() -> tuple[list[Record], float, float]:
    t_on, t_off = 95.0, 105.0
    kept = [
        (m, t)
        for m, t in _messages("a_quad_wind")
        if not (m.get_type() == "LOCAL_POSITION_NED" and t_on <= m.time_boot_ms * 1e-3 < t_off)
    ]
    return _replay(kept), t_on, t_off


def test_outage_flags_every_axis_from_the_first_missed_period(
    outage: tuple[list[Record], float, float],
) -> None:
    records, t_on, t_off = outage
    meas_t = [
        r.t_boot_s
        for r in records
        if r.__class__.__name__ == "MeasurementRecord"  # type: ignore[attr-defined]
    ]
    t_last = max(t for t in meas_t if t < t_on)
    t_back = min(t for t in meas_t if t >= t_off)
    active = _series(records, "active")
    # the stream is at 25 Hz: a measurement is overdue 1.5 intervals (60 ms) after the
    # last, flagged at the next IMU sample (≤ 20 ms later)
    gap = [r for r in active if t_last + 0.06 + 0.021 <= r.t_boot_s < t_back]
    assert len(gap) > 400  # 10 s at ArduPilot's 50 Hz
    assert all(r.dead_reckoned_axes == ("n", "e", "d") for r in gap)
    assert all(r.health == "dead_reckoning" and r.sigma_ned_mps is not None for r in gap)
    before = [r for r in active if t_last - 1.0 <= r.t_boot_s <= t_last + 0.05]
    assert before and not any(r.dead_reckoned_axes for r in before)
    # active within its 2σ 95 % of the time, per axis (a Gaussian error: 95.4 %)
    tt, vt = _truth(records)
    t = np.array([r.t_boot_s for r in gap])
    v = np.array([r.v_ned_mps for r in gap])
    sig = np.array([r.sigma_ned_mps for r in gap])
    ok, truth = interpolate_truth(t, tt, vt)
    inside = np.abs(v[ok] - truth[ok]) <= 2.0 * sig[ok]
    assert (inside.mean(axis=0) >= 0.95).all(), inside.mean(axis=0)


@pytest.mark.timeout(240)
def test_outage_sigma_reaches_the_rerun_recording(tmp_path: Path) -> None:
    """The outage's σ per axis is plotted: ``replay --rrd`` of the log without its
    LOCAL_POSITION_NED for 10 s, read back."""
    t_on, t_off = 95.0, 105.0
    tlog, rrd, jsonl = tmp_path / "outage.tlog", tmp_path / "o.rrd", tmp_path / "o.jsonl"
    data = lzma.decompress((DATA / "a_quad_wind.tlog.xz").read_bytes())
    with tlog.open("wb") as f:
        for r in iter_tlog(data, FrameCounters()):
            m = r.msg
            if m.get_type() == "LOCAL_POSITION_NED" and t_on <= m.time_boot_ms * 1e-3 < t_off:
                continue
            f.write(r.t_host_us.to_bytes(8, "big") + m.get_msgbuf())
    subprocess.run(
        [str(BIN / "glmav-observer"), "replay", str(tlog), "--no-progress", "--rrd", str(rrd),
         "--out", str(jsonl)],
        check=True, capture_output=True,
    )  # fmt: skip
    rows = [json.loads(line) for line in jsonl.read_text().splitlines()]
    active = [r for r in rows if r.get("config") == "active" and r["sigma_ned_mps_n"] is not None]
    # the file holds every active record: the flagged ones span the outage (10 s at 50 Hz)
    assert len(active) > 400
    assert all(r["dead_reckoned_axes"] == ["n", "e", "d"] for r in active)
    rec = read_recording(rrd)
    for a in "ned":
        col = rec[f"/vehicle/1/active/sigma_ned_mps/{a}"]
        # the recording keeps every active record (a file, no live decimation)
        assert [v[0] for v in col["Scalars:scalars"]] == [r[f"sigma_ned_mps_{a}"] for r in active]
        np.testing.assert_allclose(
            col[TIMELINE], [r["t_boot_s"] for r in active], rtol=0, atol=1e-9
        )  # (vehicle times pass through int64 nanoseconds)
