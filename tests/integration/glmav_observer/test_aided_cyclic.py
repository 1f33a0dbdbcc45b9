"""The ``aided`` estimate with the swash-plate cyclic regressors (issue 13, glmav-sitl).

glmav-sitl flies the paper's coaxial GLMAV, whose horizontal specific force is mostly the
lower rotor's tilted thrust (equations.md eq. 5), not drag. With SERVO_OUTPUT_RAW mapped
to the cyclic regressors (``[estimation.aero_control]``, estimation/aero/control.py) the
model learns that force too. A climbing turn (still air, seed 2; one 100 Hz IMU stream,
50 Hz attitude, 10 Hz truth: a fifth of the default messages, for the test's time) is
flown for 57 s, the north measurement is frozen from 25 s for 30 s and the service isolates
it; the aided north is scored against SIM_STATE beside the dead reckoning the service
publishes as ``active`` with ``[estimation] aero_active = false`` (by default ``active``
is the aided estimate: tests/integration/glmav_observer/test_aided.py), with and without
the channel map (the control experiment: the same service, the drag model alone).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.aero.control import ControlMapping
from glmav_observer.estimation.vehicle import EstimatorConfig
from glmav_observer.evaluation import interpolate_truth
from glmav_observer.ingest.framing import FrameCounters, iter_tlog
from glmav_testkit.fault_replay import FaultInjector, VelocityFault
from glmav_testkit.sinks import AidedSink

T_ON_S = 25.0
LOSS_S = 30.0
DURATION_S = 57.0
#: one IMU stream (RAW_IMU and SCALED_IMU would only be superseded), 100 Hz
RATES_HZ = {
    "raw_imu": 0.0,
    "scaled_imu": 0.0,
    "highres_imu": 100.0,
    "attitude": 50.0,
    "sim_state": 10.0,
}


@pytest.fixture(scope="module")
def tlog(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    from glmav_sitl.runner import run
    from glmav_sitl.scenario import load_scenario

    path = tmp_path_factory.mktemp("cyclic") / "climbing-turn.tlog"
    sc = load_scenario("climbing-turn")
    sc = dataclasses.replace(sc, rates_hz={**sc.rates_hz, **RATES_HZ})
    run(sc, [], duration_s=DURATION_S, speed="max", seed=2, tlog_path=path)
    return path.read_bytes()


def _fly(data: bytes, control: ControlMapping | None) -> tuple[AidedSink, Service]:
    sink = AidedSink()
    cfg = ServiceConfig(estimation=EstimatorConfig(aero_control=control, aero_active=False))
    service = Service(cfg, [sink])
    injector = FaultInjector([VelocityFault(0, "freeze", T_ON_S, T_ON_S + LOSS_S)])
    for rec in iter_tlog(data, FrameCounters()):
        injector.apply(rec.msg)
        service.feed_message(rec.msg, rec.t_host_us * 1e-6, "log")
    service.close()
    return sink, service


def _errors(sink: AidedSink) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, aided north error, dead-reckoned north error, aided σ) over the loss."""
    t = np.array([r.t_boot_s for r in sink.aided])
    tt = np.array([r.t_boot_s for r in sink.truth])
    vt = np.array([r.v_ned_mps for r in sink.truth])
    ok, v_truth = interpolate_truth(t, tt, vt)
    aided_n = np.array([r.v_ned_mps[0] for r in sink.aided])
    dr_n = np.array([sink.active[r.t_boot_s].v_ned_mps[0] for r in sink.aided])
    sigma = np.array([r.sigma_lost_mps for r in sink.aided], dtype=float)
    return t[ok], aided_n[ok] - v_truth[ok, 0], dr_n[ok] - v_truth[ok, 0], sigma[ok]


def _rms(e: np.ndarray) -> float:
    return math.sqrt(float(np.mean(e**2)))


def test_the_cyclic_regressors_aid_the_lost_axis_on_the_glmav(tlog: bytes) -> None:
    sink, service = _fly(tlog, ControlMapping())
    est = service.estimators[1]
    assert est.aiding is not None
    model = est.aiding.model
    # the SERVO_OUTPUT_RAW stream reached the model: it has the control term and never had
    # to skip a sample for want of a fresh control (50 Hz stream, 0.1 s max age)
    assert model.config.control and model.n_no_control == 0
    assert model.n_learned > 500  # ~20 s at 30 Hz before the loss (measured 689)
    # b_j ≈ β/m · Ω_ref² = 1.1 m/s² on the default vehicle (control.py); measured 0.78 and
    # 0.69: the command leads the swash-plate (10 ms) and Ω2 (50 ms motor lag), and the
    # constant c shares the trim. Within a factor 2 (the physics, not a tuned number)
    assert np.all((model.theta[:, 5] > 0.55) & (model.theta[:, 5] < 2.2)), model.theta[:, 5]
    assert sink.aided, "no aided estimate published"
    t, e_ai, e_dr, sigma = _errors(sink)
    assert T_ON_S < t[0] < T_ON_S + 1.0 and t[-1] <= T_ON_S + LOSS_S + 3.0
    assert {r.lost_axis for r in sink.aided} == {"n"}
    # measured at this commit: RMSE over the 30 s loss 0.064 (aided) vs 0.114 m/s (dead
    # reckoning); last 10 s 0.051 vs 0.116; worst 0.175 vs 0.289 (+10 s: 0.094 vs 0.120);
    # aided 95 % of the time; 2σ covers 100 %. Asserted: a quarter off the dead reckoning
    # (a model that does nothing gives the same number; measured 44 % off), over the
    # whole loss and its last 10 s (the error does not grow), the 60 s bound
    # (0.3 m/s) at every instant, σ coverage (95 %)
    assert _rms(e_ai) <= 0.75 * _rms(e_dr), (_rms(e_ai), _rms(e_dr))
    late = t > t[-1] - 10.0
    assert _rms(e_ai[late]) <= 0.75 * _rms(e_dr[late]), (_rms(e_ai[late]), _rms(e_dr[late]))
    assert np.abs(e_ai).max() <= 0.3
    assert np.mean([r.health == "aided" for r in sink.aided]) > 0.5
    assert np.mean(np.abs(e_ai) <= 2.0 * sigma) >= 0.95
    # the measured axes are the hand-over configuration's, untouched
    for r in sink.aided[:: max(1, len(sink.aided) // 50)]:
        assert r.v_ned_mps[1:] == sink.active[r.t_boot_s].v_ned_mps[1:]

    # the control experiment: without the channel map the same service has the drag model
    # alone, which on this flight never trusts itself (measured: aided 0 % of the loss,
    # RMSE 0.114 = the dead reckoning's): the gain above is the cyclic regressors'
    plain, service0 = _fly(tlog, None)
    est0 = service0.estimators[1]
    assert est0.aiding is not None and not est0.aiding.model.config.control
    _, e_ai0, e_dr0, _ = _errors(plain)
    assert _rms(e_dr0) == pytest.approx(_rms(e_dr))  # the same dead reckoning
    assert _rms(e_ai) <= 0.75 * _rms(e_ai0), (_rms(e_ai), _rms(e_ai0))
