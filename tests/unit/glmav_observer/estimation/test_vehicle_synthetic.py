"""The vehicle estimator on a synthetic flight with exact kinematics (no simulator).

The flight: NED velocity V(t) = (2 + 0.5 sin 0.7t, 0.8 sin 0.5t, 0.3 sin 0.9t) m/s,
attitude φ = 0.1 sin 0.6t, θ = −0.08 + 0.05 sin 0.4t, ψ = 0.3 + 0.2 sin 0.2t rad; the
IMU reads f = Eᵀ(V̇ − g e_d) + b + noise at 250 Hz with b = (0.15, −0.1, 0.12) m/s² in
body axes (the design's turn-on σ 0.2 m/s²) and noise 4e-3·√250 m/s²; ω from the
Euler rates (exact kinematics); ATTITUDE at 100 Hz; LOCAL_POSITION_NED at 30 Hz with
σ 0.05 m/s per axis (design.md defaults).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from glmav_observer.estimation.vehicle import EstimatorConfig, Vec3, VehicleEstimator
from glmav_observer.evaluation import TruthScorer
from glmav_observer.ingest.samples import (
    AidingSample,
    ImuSample,
    Sample,
    VelocitySample,
)
from glmav_observer.records import Record, VelocityRecord
from glmav_testkit.synthetic_flight import FAULTS, flight, freeze, truth


def run(
    samples: Iterator[Sample], cfg: EstimatorConfig | None = None
) -> tuple[VehicleEstimator, list[Record]]:
    est = VehicleEstimator(1, cfg or EstimatorConfig())
    recs: list[Record] = []
    for s in samples:
        recs.extend(est.on_sample(s))
    return est, recs


def scored_rmse(recs: list[Record], config: str = "active") -> Vec3 | None:
    """RMSE of ``config`` against the truth records, as the service scores it (from 3 s)."""
    scorer = TruthScorer(skip_s=3.0)
    for r in recs:
        scorer.add(r)
    return scorer.rmse().get(config)


def test_healthy_flight_active_rmse_and_no_isolation() -> None:
    est, recs = run(flight(30.0))
    rmse = scored_rmse(recs)
    assert rmse is not None
    # bound 0.1 m/s per axis (issue); the analysis gives ~0.02 (γ_full = 12, σ_y 0.05)
    assert max(rmse) < 0.05, rmse
    assert est.faults == []
    assert est.switches == []


def _active(recs: list[Record]) -> list[VelocityRecord]:
    return [r for r in recs if isinstance(r, VelocityRecord) and r.config == "active"]


@pytest.mark.parametrize("kind", ["dropout", "freeze", "bias", "noise"])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_each_fault_isolated_switched_without_jump(kind: str, axis: int) -> None:
    t0 = 6.0  # after the FDI warm-up (vetting delay 0.6 s + bias fit 1.5 s)
    fault = freeze(axis, t0) if kind == "freeze" else FAULTS[kind](axis, t0)
    est, recs = run(flight(11.5, seed=3 + axis, fault=fault))
    assert len(est.faults) >= 1, est.counters
    ev = est.faults[0]
    assert ev.axis == "ned"[axis]
    assert ev.kind == kind
    assert 0.0 <= ev.t_detect_s - t0 <= 0.5  # issue: isolated within 0.5 s
    sw = est.switches[0]
    assert sw.to_config == ("c2", "c3", "c1")[axis]
    assert sw.jump_mps is not None and sw.jump_mps <= 0.05, sw
    # the measured axes stay as good as in healthy flight (bound of the issue, 0.1 m/s)
    rmse = scored_rmse(recs)
    assert rmse is not None
    assert max(r for i, r in enumerate(rmse) if i != axis) < 0.1, rmse
    # the lost axis is dead-reckoned: 5 s after the switch its error is within 3 sigma of
    # the uncertainty the record reports (sigma grows with the bias uncertainty x time)
    t_check = round(sw.t_boot_s + 5.0, 3)
    rec = next(r for r in _active(recs) if r.t_boot_s >= t_check)
    v_true = truth(rec.t_boot_s)[0]
    assert rec.sigma_lost_mps is not None
    assert abs(rec.v_ned_mps[axis] - v_true[axis]) <= 3.0 * rec.sigma_lost_mps


@pytest.mark.parametrize("spike_mps", [1.0, -3.0, 10.0])
def test_one_outlier_does_not_switch(spike_mps: float) -> None:
    """Hysteresis: a single wild sample is gated out of `full` and isolates nothing."""
    hit: list[float] = []

    def spike(t: float, y: np.ndarray) -> np.ndarray:
        if t >= 5.0 and not hit:
            hit.append(t)
            return y + np.array([spike_mps, 0.0, 0.0])
        return y

    est, recs = run(flight(8.0, seed=9, fault=spike))
    assert hit  # the outlier was sent
    assert est.faults == []
    assert est.switches == []
    # gated: the active estimate never moves by the outlier (30 Hz samples, gamma 12:
    # an ungated 1 m/s sample would move `full` by ~0.3 m/s)
    err = [
        abs(r.v_ned_mps[0] - truth(r.t_boot_s)[0][0])
        for r in _active(recs)
        if 4.9 < r.t_boot_s < 5.5
    ]
    assert max(err) < 0.1  # healthy error ~0.02 (3 sigma 0.07)


def test_recovery_after_the_axis_is_healthy_again() -> None:
    """A dropout from 4 s to 5 s: isolated, then `full` again ~recovery_s after it ends."""
    fault = lambda t, y: np.where((np.arange(3) == 2) & (4.0 <= t < 5.0), np.nan, y)  # noqa: E731
    est, _ = run(flight(9.0, seed=2, fault=fault))
    assert [f.kind for f in est.faults] == ["dropout"]
    assert [s.to_config for s in est.switches] == ["c1", "full"]
    back = est.switches[1]
    # recovery_s = 2 s of healthy samples, counted once the noise test has a full window
    # again (13 residuals at 30 Hz = 0.43 s)
    assert 5.0 + 2.0 <= back.t_boot_s <= 5.0 + 2.0 + 0.45 + 0.05
    assert back.jump_mps is not None and back.jump_mps <= 0.05


def test_recovery_after_a_long_fault_is_not_taken_for_a_bias() -> None:
    """Regression (found by the demo on the SITL): a freeze of n from 6 s to 14 s while the
    accelerometer bias steps by 0.08 m/s² (body x) makes the dead reckoning of n drift by
    ~0.6 m/s. The recovered axis must be re-anchored on the measurement, not compared with
    the drifted prediction (which isolated it again as a 0.6 m/s 'bias' 0.5 s later and
    switched with a 0.7 m/s jump)."""
    frozen = freeze(0, 6.0)
    fault = lambda t, y: frozen(t, y) if t < 14.0 else y  # noqa: E731
    step = (6.0, np.array([0.08, 0.0, 0.0]))
    est, recs = run(flight(20.0, seed=4, fault=fault, accel_bias_step=step))
    assert [(f.axis, f.kind) for f in est.faults] == [("n", "freeze")]
    assert [s.to_config for s in est.switches] == ["c2", "full"]
    back = est.switches[1]
    # recovery_s = 2 s after the freeze ends (+ the noise test's 0.43 s window refill)
    assert 14.0 + 2.0 <= back.t_boot_s <= 14.0 + 2.0 + 0.45 + 0.05
    assert back.jump_mps is not None and back.jump_mps <= 0.05
    # the drift was real (else this test proves nothing): the dead-reckoned n was off by
    # more than 3x the bias threshold (0.18 m/s) just before the switch back
    before = [r for r in _active(recs) if back.t_boot_s - 0.1 <= r.t_boot_s < back.t_boot_s]
    drift = max(abs(r.v_ned_mps[0] - truth(r.t_boot_s)[0][0]) for r in before)
    assert drift > 0.5, drift
    # back on `full`, the error decays at gamma_full = 12 1/s: after 1 s it is e^-12 of the
    # drift plus the healthy error (~0.02 m/s, 3 sigma 0.07)
    after = [r for r in _active(recs) if r.t_boot_s >= back.t_boot_s + 1.0]
    assert max(abs(r.v_ned_mps[0] - truth(r.t_boot_s)[0][0]) for r in after) < 0.1


def _with_imu_shock(samples: Iterator[Sample], t_s: float, f_mps2: float) -> Iterator[Sample]:
    """The first IMU sample at or after t_s reads f_mps2 on every axis (a shock)."""
    done = False
    for s in samples:
        if not done and isinstance(s, ImuSample) and s.t_boot_s >= t_s:
            done = True
            f = (f_mps2, -f_mps2, f_mps2)
            yield ImuSample(s.sysid, s.t_boot_s, f, s.omega_body_radps, s.source)
            continue
        yield s


@pytest.mark.parametrize("f_mps2", [150.0, 1999.0])
def test_one_imu_shock_isolates_nothing_and_is_forgotten_within_1_s(f_mps2: float) -> None:
    """Issue #12: one CRC-valid HIGHRES_IMU sample with |f| below the implausible limit
    (2000 m/s²). Before the despiker, 1999 m/s² held for 4 ms was an 8 m/s step in the
    FDI's integral: a false bias on every axis that never cleared."""
    est, recs = run(_with_imu_shock(flight(9.0, seed=5), 5.0, f_mps2))
    _, ref = run(flight(9.0, seed=5))
    assert est.faults == [] and est.switches == []
    assert est.counters["imu_spike_held"] == 1
    # 1 s later the active estimate is within 0.1 m/s of the run without the shock (issue);
    # held out, the shock costs one 4 ms hold of the previous sample: ~1e-3 m/s
    got = {r.t_boot_s: r.v_ned_mps for r in _active(recs) if r.t_boot_s >= 6.0}
    want = {r.t_boot_s: r.v_ned_mps for r in _active(ref) if r.t_boot_s >= 6.0}
    assert got.keys() == want.keys()
    assert max(max(abs(a - b) for a, b in zip(got[t], want[t], strict=True)) for t in got) <= 0.1


def test_a_missing_stream_is_not_an_axis_fault() -> None:
    """No LOCAL_POSITION_NED for 0.7 s (a late burst on a loaded link looks the same): every
    configuration dead-reckons, nothing is isolated, nothing switches."""

    def drop(samples: Iterator[Sample]) -> Iterator[Sample]:
        for s in samples:
            if isinstance(s, VelocitySample) and 5.0 <= s.t_boot_s < 5.7:
                continue
            yield s

    est, recs = run(drop(flight(9.0, seed=6)))
    assert est.faults == [] and est.switches == []
    assert est.counters["measurement_missing"] == 1
    rmse = scored_rmse(recs)
    assert rmse is not None and max(rmse) < 0.05  # 0.7 s of dead reckoning costs ~0.01 m/s


def test_an_accelerometer_bias_step_isolates_no_velocity_axis() -> None:
    """Issue #12 item 3: a 0.5 m/s² body-x accelerometer bias step at 6 s shows on every
    earth axis as a ramp; it is reported as ``accel_bias`` with its estimated change and
    isolates no velocity axis."""
    step = (6.0, np.array([0.5, 0.0, 0.0]))
    est, _ = run(flight(14.0, seed=8, accel_bias_step=step))
    assert [f.kind for f in est.faults if f.axis != "body"] == []
    events = [f for f in est.faults if f.kind == "accel_bias"]
    assert len(events) >= 1
    ev = events[0]
    assert ev.bias_body_mps2 is not None
    # found within 1.5 s, change time within 0.5 s of the truth (0.6 s vetting delay
    # + 0.3 s for a 0.5 m/s² ramp to reach the 0.15 m/s threshold)
    assert 6.0 <= ev.t_detect_s <= 7.5
    assert ev.t_onset_s is not None and abs(ev.t_onset_s - 6.0) <= 0.5
    # mostly along body x (the attitude is within 0.15 rad of level, heading ~0.3 rad)
    bx, by, bz = ev.bias_body_mps2
    assert bx > 0.2 and abs(bx) > 2.0 * max(abs(by), abs(bz)), ev.bias_body_mps2
    assert est.switches == []


def test_aided_is_the_dead_reckoning_when_the_drag_model_is_not_trusted() -> None:
    """This flight has no drag (f = Eᵀ(V̇ − g e_d) + b): the model's own tests refuse it, so
    the ``aided`` estimate published while e is isolated is the active one to the bit, says
    ``dead_reckoning``, and is published only while an axis is lost."""
    est, recs = run(flight(25.0, fault=FAULTS["bias"](1, 12.0)))
    aided = [r for r in recs if isinstance(r, VelocityRecord) and r.config == "aided"]
    active = {r.t_boot_s: r for r in recs if isinstance(r, VelocityRecord) and r.config == "active"}
    sw = est.switches[0]
    assert sw.to_config == "c3" and aided
    assert aided[0].t_boot_s >= sw.t_boot_s
    assert {r.health for r in aided} == {"dead_reckoning"}
    assert {r.source_config for r in aided} == {"c3"} and {r.lost_axis for r in aided} == {"e"}
    assert len(est.switches) == 1  # the bias lasts to the end: aided to the last step
    assert aided[-1].t_boot_s == max(active)
    for r in aided:
        assert r.v_ned_mps == active[r.t_boot_s].v_ned_mps


def _gps_loss(
    samples: Iterator[Sample], t_lost: float, t_back: float, t_snap: float, drift_mps: float
) -> Iterator[Sample]:
    """GPS_RAW_INT's fix lost at ``t_lost`` and back at ``t_back``; the autopilot's north
    velocity is ``drift_mps`` off from ``t_lost`` until it resets at ``t_snap`` (a 3D fix
    from the start: a GPS that never had one flags nothing)."""
    sent = [False, False, False]
    for s in samples:
        for k, (t_ev, fix) in enumerate(((0.0, True), (t_lost, False), (t_back, True))):
            if not sent[k] and s.t_boot_s >= t_ev:
                sent[k] = True
                yield AidingSample(1, t_ev, "GPS_RAW_INT", fix, None, "" if fix else "gps_fix_1")
        if isinstance(s, VelocitySample) and t_lost <= s.t_boot_s < t_snap:
            v = s.v_ned_mps
            yield VelocitySample(s.sysid, s.t_boot_s, s.position_ned_m, (v[0] + drift_mps, *v[1:]))
        else:
            yield s


@pytest.mark.parametrize("follow_s", [1.0, 0.0])
def test_active_follows_the_autopilots_reset_after_it_is_aided_again(follow_s: float) -> None:
    """The autopilot resets its velocity 0.1 s after its GPS's fix is back (ArduPilot:
    0.37 m/s in one sample): ``active`` follows it at once (``readmit_follow_s``), where
    ``full``'s filter alone would smear the step over 1/γ."""
    t_back, t_snap = 12.0, 12.1
    cfg = EstimatorConfig(readmit_follow_s=follow_s)
    _, recs = run(_gps_loss(flight(14.0, seed=5), 8.0, t_back, t_snap, 0.3), cfg)
    after = [r for r in _active(recs) if t_snap + 0.03 <= r.t_boot_s < t_snap + 0.1]
    assert after
    err = max(abs(r.v_ned_mps[0] - truth(r.t_boot_s)[0][0]) for r in after)
    if follow_s > 0.0:
        # the reset measurement, carried by the IMU: its own noise (σ 0.05 m/s), so within
        # 3σ (measured 0.067)
        assert err < 0.15, err
    else:
        # filtered: the step decays at γ_full (e^(−γ t)); measured 0.245 at 30 ms
        assert err > 0.2, err
