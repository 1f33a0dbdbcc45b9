"""A vehicle taken over mid-fault continues from the last state its owner published
(``VehicleEstimator.seed``, ``fleet.handover.seed_from_state``; ``serve --claim``).

The synthetic flight of test_vehicle_synthetic (exact kinematics, 250 Hz IMU with a body
accelerometer bias, 30 Hz velocity with σ 0.05 m/s) with a 0.5 m/s bias on the measured
east velocity from 5 s. Estimator A (the owner) flies it all; its last records at 7 s are
what its state queryable answers (as JSON, as on Zenoh). B is seeded with them and fed
only from 7 s + the takeover gap (the new owner hears nothing in between); C starts cold
at the same time, as the service did before.
"""

from __future__ import annotations

import json
import math

import pytest

from glmav_observer.estimation.seed import SEED_MAX_AGE_S
from glmav_observer.estimation.vehicle import EstimatorConfig, VehicleEstimator
from glmav_observer.fleet.handover import HandoverError, seed_from_state
from glmav_observer.publish.zenoh_keys import encode_json
from glmav_observer.records import HealthRecord, Record, VelocityRecord
from glmav_testkit.synthetic_flight import FAULTS, flight, truth

T_FAULT_S = 5.0
T_KILL_S = 7.0
T_END_S = 13.0
GAP_S = 0.8  # a takeover: the router drops the tokens, the next claim turn (0.5 s), ...
E = 1  # the east axis (the fault's)


def _state(records: list[Record]) -> dict[str, object]:
    """What ZenohSink.state_payload answers: the latest record of each kind, as JSON."""
    velocity: dict[str, object] = {}
    health = None
    for r in records:
        if isinstance(r, VelocityRecord):
            velocity[r.config] = r.to_dict()
        elif isinstance(r, HealthRecord):
            health = r.to_dict()
    payload = {"schema": "glmav.state/1", "sysid": 1, "velocity": velocity, "health": health}
    out: dict[str, object] = json.loads(encode_json(payload))
    return out


def _run_from(est: VehicleEstimator, t0: float) -> list[Record]:
    out: list[Record] = []
    for s in flight(T_END_S, seed=5, fault=FAULTS["bias"](E, T_FAULT_S)):
        if s.t_boot_s >= t0:
            out.extend(est.on_sample(s))
    return out


def _active(records: list[Record]) -> list[VelocityRecord]:
    return [r for r in records if isinstance(r, VelocityRecord) and r.config == "active"]


def _err_e(r: VelocityRecord) -> float:
    return r.v_ned_mps[E] - float(truth(r.t_boot_s)[0][E])


@pytest.fixture(scope="module")
def owner() -> list[Record]:
    return _run_from(VehicleEstimator(1, EstimatorConfig()), 0.0)


def test_the_new_owner_continues_the_isolation_and_the_dead_reckoning(
    owner: list[Record],
) -> None:
    before = [r for r in owner if r.t_boot_s <= T_KILL_S]
    state = _state(before)
    seed = seed_from_state(state)
    # the owner had isolated the east bias and handed over to c3 before the kill
    assert [(f.axis, f.kind) for f in seed.isolated] == [("e", "bias")]
    assert seed.active_config == "c3"
    assert seed.reference_fit is not None
    t1 = T_KILL_S + GAP_S
    b = VehicleEstimator(1, EstimatorConfig())
    b.seed(seed)
    new = _run_from(b, t1)
    assert b.seed_outcome == "continued"
    assert b.seed_age_s is not None
    # applied at the first sample with attitude and IMU: within one ATTITUDE period (0.01 s)
    assert b.seed_age_s == pytest.approx(t1 - seed.t_boot_s, abs=0.011)
    health = [r for r in new if isinstance(r, HealthRecord)]
    first = health[0]
    # the isolation goes on: same fault event (its detection time is the owner's)
    assert first.axis_state["e"] == "faulty" and first.active_config == "c3"
    assert [(f.axis, f.kind, f.t_detect_s) for f in first.isolated_faults] == [
        (f.axis, f.kind, f.t_detect_s) for f in seed.isolated
    ]
    # the reference fit goes on from the owner's b̂, δψ̂, d̂ (published to JSON's precision)
    assert first.reference_fit is not None
    fit0 = seed.reference_fit
    assert first.reference_fit.accel_bias_body_mps2 == pytest.approx(
        fit0.accel_bias_body_mps2, abs=1e-9
    )
    assert first.reference_fit.heading_error_rad == pytest.approx(fit0.heading_error_rad, abs=1e-9)
    # the dead-reckoned east axis starts from the owner's last active estimate: its error
    # at the first record is the owner's error then minus the velocity change over the gap
    # (the new owner has no IMU for the gap: the analysis of SEED_MAX_AGE_S)
    act_a = _active(before)[-1]
    act_b = _active(new)
    dv_gap = float(truth(act_b[0].t_boot_s)[0][E] - truth(act_a.t_boot_s)[0][E])
    # (0.002: the first record comes after one IMU step of ≤ 4 ms, |V̇| ≤ 0.4 m/s² here)
    assert _err_e(act_b[0]) == pytest.approx(_err_e(act_a) - dv_gap, abs=0.002)
    # ... and then dead-reckons like the owner would have: over the next 3 s B's east error
    # stays within the owner's own error plus that offset, and 0.05 m/s for the lost
    # axis's heading correction restarting at the takeover (δψ̂ · ∫a over 3 s)
    a_after = {round(r.t_boot_s, 4): r for r in _active(owner) if r.t_boot_s > t1}
    worst = 0.0
    for r in act_b:
        ra = a_after.get(round(r.t_boot_s, 4))
        if ra is not None:
            worst = max(worst, abs(_err_e(r)) - abs(_err_e(ra)))
    print(f"gap {GAP_S} s: dv_gap {dv_gap:+.3f} m/s; B - A east error, worst {worst:.3f} m/s")
    assert worst <= abs(dv_gap) + 0.05, (worst, dv_gap)
    assert all(r.health == "dead_reckoning" and r.source_config == "c3" for r in act_b)
    # the measured axes converge again at γ (c3's 70/s: 1/γ = 14 ms): after 0.2 s their
    # worst error is the owner's own over the same time
    late = [r for r in act_b if r.t_boot_s > t1 + 0.2]
    late_a = [r for r in a_after.values() if r.t_boot_s > t1 + 0.2]
    for j in (0, 2):
        err_b = max(abs(r.v_ned_mps[j] - float(truth(r.t_boot_s)[0][j])) for r in late)
        err_a = max(abs(r.v_ned_mps[j] - float(truth(r.t_boot_s)[0][j])) for r in late_a)
        print(f"axis {j}: worst error after 0.2 s, B {err_b:.3f}, A {err_a:.3f} m/s")
        assert err_b <= err_a + 0.01, (j, err_b, err_a)


def test_a_cold_start_mid_fault_takes_the_biased_measurement(owner: list[Record]) -> None:
    """What the takeover did before: from the measurement, the bias unknown (warm-up)."""
    c = VehicleEstimator(1, EstimatorConfig())
    act = _active(_run_from(c, T_KILL_S + GAP_S))
    first_s = [r for r in act if r.t_boot_s < T_KILL_S + GAP_S + 1.0]
    # the 0.5 m/s bias, within the measurement noise and the γ transient (0.1 m/s)
    assert min(abs(_err_e(r)) for r in first_s[len(first_s) // 2 :]) > 0.4
    assert c.seed_outcome is None and c.active_config == "full"


def test_a_state_older_than_the_bound_starts_cold(owner: list[Record]) -> None:
    state = _state([r for r in owner if r.t_boot_s <= T_KILL_S])
    b = VehicleEstimator(1, EstimatorConfig())
    b.seed(seed_from_state(state))
    _run_from(b, T_KILL_S + SEED_MAX_AGE_S + 0.5)
    assert b.seed_outcome is not None and b.seed_outcome.startswith("too old"), b.seed_outcome
    assert b.counters["estimator_seed_rejected"] == 1
    assert b.seed_age_s is not None and b.seed_age_s > SEED_MAX_AGE_S
    assert b.active_config == "full"  # nothing carried over


def test_a_new_owner_behind_the_state_waits_for_it(owner: list[Record]) -> None:
    """The new owner reads its link later than the old one published (a backlog on a
    loaded machine): samples older than the state are covered by it and wait; a stream
    more than SEED_MAX_AGE_S behind is a clock reset: cold start."""
    state = _state([r for r in owner if r.t_boot_s <= T_KILL_S])
    seed = seed_from_state(state)
    b = VehicleEstimator(1, EstimatorConfig())
    b.seed(seed)
    new = _run_from(b, T_KILL_S - 0.3)
    assert b.seed_outcome == "continued"
    # applied at the first attitude/IMU sample at or after the state (ATTITUDE: 10 ms)
    assert b.seed_age_s is not None and 0.0 <= b.seed_age_s <= 0.011, b.seed_age_s
    assert b.counters["estimator_seed_wait_samples"] > 0
    assert min(r.t_boot_s for r in _active(new)) >= seed.t_boot_s
    assert b.active_config == "c3"
    c = VehicleEstimator(1, EstimatorConfig())
    c.seed(seed)
    _run_from(c, T_KILL_S - SEED_MAX_AGE_S - 1.0)
    assert c.seed_outcome is not None and "ahead of the stream" in c.seed_outcome
    assert c.counters["estimator_seed_rejected"] == 1


def test_a_state_without_an_active_estimate_is_refused() -> None:
    with pytest.raises(HandoverError, match="active estimate"):
        seed_from_state({"velocity": {}, "health": None})
    bad = {"velocity": {"active": {"t_boot_s": 1.0, "v_ned_mps": [1.0, "x", 0.0]}}}
    with pytest.raises(HandoverError, match="not a number"):
        seed_from_state(bad)
    assert math.isnan(seed_from_state({"velocity": {"active": {
        "t_boot_s": 1.0, "v_ned_mps": [None, 0.0, 0.0]}}}).v_ned_mps["active"][0])  # fmt: skip


def _forged(state: dict[str, object], v_ned_mps: list[float]) -> dict[str, object]:
    """The state with every estimate replaced by ``v_ned_mps`` and north "isolated" (the
    rogue peer of issue 31 D1: 40, -40, 15 m/s against a true ~0.5 m/s)."""
    forged = json.loads(json.dumps(state))
    for rec in forged["velocity"].values():
        rec["v_ned_mps"] = list(v_ned_mps)
    forged["health"]["isolated_faults"] = [
        {"axis": "n", "kind": "bias", "t_detect_s": T_KILL_S - 1.0, "t_onset_s": None}
    ]
    forged["health"]["active_config"] = "c1"
    return forged


def test_a_forged_state_is_dropped_at_the_first_measurement(owner: list[Record]) -> None:
    state = _state([r for r in owner if r.t_boot_s <= T_KILL_S])
    t1 = T_KILL_S + GAP_S
    b = VehicleEstimator(1, EstimatorConfig())
    b.seed(seed_from_state(_forged(state, [40.0, -40.0, 15.0])))
    new = _run_from(b, t1)
    assert b.counters["estimator_seeded"] == 1
    assert b.counters["estimator_seed_disagreed"] == 1
    assert b.seed_outcome is not None and b.seed_outcome.startswith("disagreed"), b.seed_outcome
    act = _active(new)
    # the first measurement (30 Hz: within 34 ms of the seed) drops it: no estimate after
    # it is further than the cold start's warm-up from the truth (0.5 m/s east bias +
    # the γ transient, test_a_cold_start_mid_fault_takes_the_biased_measurement)
    t_first_meas = t1 + 1.0 / 30.0 + 0.001
    later = [r for r in act if r.t_boot_s > t_first_meas]
    assert later
    worst = max(
        abs(r.v_ned_mps[j] - float(truth(r.t_boot_s)[0][j])) for r in later for j in range(3)
    )
    assert worst < 1.0, worst
    assert b.active_config == "full"  # the forged isolation of north is gone


def test_a_true_state_passes_the_check(owner: list[Record]) -> None:
    """The genuine hand-over mid-fault (east biased by 0.5 m/s, 0.8 s gap) is inside the
    gate: 5σ with σ = sqrt(0.05² + 0.03² + (1 m/s² · (0.8 + 0.5) s)²) = 1.3 m/s."""
    state = _state([r for r in owner if r.t_boot_s <= T_KILL_S])
    b = VehicleEstimator(1, EstimatorConfig())
    b.seed(seed_from_state(state))
    _run_from(b, T_KILL_S + GAP_S)
    assert b.seed_outcome == "continued"
    assert b.counters["estimator_seed_disagreed"] == 0
    assert b.active_config == "c3"
