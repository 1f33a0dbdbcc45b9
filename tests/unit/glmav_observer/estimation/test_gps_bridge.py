"""The GPS bridge (estimation/gps_bridge.py): the lag it learns, the trust it gives, B1,
its gate, and its hand back to the autopilot's velocity, on exact synthetic signals."""

from __future__ import annotations

import itertools
import math

import pytest

from glmav_observer.estimation.gps_bridge import GpsBridge, GpsBridgeConfig

#: the synthetic vehicle: v(t) = (V sin ωt, V cos ωt), so A(t) = v(t) − v(0) exactly
V_MPS, OMEGA_RADPS = 2.0, 1.0
MEAS_HZ, GPS_HZ = 25.0, 5.0


def _v(t: float) -> tuple[float, float]:
    return (V_MPS * math.sin(OMEGA_RADPS * t), V_MPS * math.cos(OMEGA_RADPS * t))


#: an accelerometer bias (body = earth here: E = I), m/s², and B = ∫E dt = t I
BIAS = (0.2, -0.1, 0.0)


def _a_int(t: float) -> list[float]:
    """A = ∫(v̇ + b) dt: the integral of what a biased accelerometer reads."""
    v, v0 = _v(t), _v(0.0)
    return [v[0] - v0[0] + BIAS[0] * t, v[1] - v0[1] + BIAS[1] * t, 0.0]


def _b_int(t: float) -> list[float]:
    return [t, 0.0, 0.0, 0.0, t, 0.0, 0.0, 0.0, t]


def _note(bridge: GpsBridge, t: float, bias: tuple[float, float, float] = BIAS) -> None:
    """The estimator's note at a measurement: A, B and the bias the fit found."""
    bridge.note(t, _a_int(t), _b_int(t), bias)


def _learn(bridge: GpsBridge, lag_s: float, t_end_s: float, stuck: bool = False) -> float:
    """Measurements at 25 Hz noted, GPS samples at 5 Hz learnt from (``full`` = truth);
    returns the last time."""
    t = 0.0
    k = 0
    while t < t_end_s:
        k += 1
        t = k / MEAS_HZ
        _note(bridge, t)
        if k % round(MEAS_HZ / GPS_HZ) == 0:
            v_gps = (0.0, 0.0) if stuck else _v(t - lag_s)
            bridge.learn(t, v_gps, _v(t))
    return t


def test_the_lag_is_learnt_to_the_grids_step() -> None:
    bridge = GpsBridge(GpsBridgeConfig())
    assert bridge.lag_s == 0.2  # the prior until lag_min_samples
    _learn(bridge, 0.13, 30.0)
    # A is linear between the 25 Hz notes (40 ms apart): at ω = 1 rad/s its chord error
    # is V ω² Δt²/8 = 0.4 mm/s, far below what one 10 ms step of lag moves (V ω 0.01 =
    # 20 mm/s): the grid point nearest the true lag wins
    assert bridge.lag_s == pytest.approx(0.13, abs=1e-9)
    assert bridge.trusted


def test_a_gps_stuck_at_zero_while_the_vehicle_moves_is_never_trusted() -> None:
    bridge = GpsBridge(GpsBridgeConfig())
    t = _learn(bridge, 0.13, 30.0, stuck=True)
    assert not bridge.trusted
    bridge.on_gps(
        t, (0.0, 0.0), sigma_gps_mps=None, start=True, v_est=(0.0, 0.0), sigma_est_mps=0.3
    )
    assert not bridge.active and bridge.starts == 0


def test_a_hovering_vehicle_proves_nothing_and_is_not_trusted() -> None:
    bridge = GpsBridge(GpsBridgeConfig())
    t = 0.0
    for k in range(1, 800):
        t = k / MEAS_HZ
        bridge.note(t, [0.0, 0.0, 0.0], [0.0] * 9, (0.0, 0.0, 0.0))
        if k % 5 == 0:
            bridge.learn(t, (0.0, 0.0), (0.0, 0.0))
    # a perfect residual, but a velocity spread of 0 < excite_sigma · σ_gps
    assert not bridge.trusted


#: the autopilot's velocity when the GPS returns: its dead reckoning 0.3 m/s off north
AP_OFF_MPS = 0.3


def _started(lag_s: float = 0.13) -> tuple[GpsBridge, float]:
    bridge = GpsBridge(GpsBridgeConfig())
    t = _learn(bridge, lag_s, 30.0)
    # σ_gps shown: the synthetic GPS is exact, so the floor, 0.02; the autopilot 0.3 off is
    # beyond start_sigma σ_gps (0.08) and inside the gate 5 √(0.3² + 0.02²) = 1.5
    assert bridge.sigma_shown_mps == GpsBridgeConfig().sigma_floor_mps
    v = _v(t)
    bridge.on_gps(
        t, _v(t - lag_s), sigma_gps_mps=None, start=True, v_est=(v[0] + AP_OFF_MPS, v[1]),
        sigma_est_mps=0.3,
    )  # fmt: skip
    assert bridge.active and bridge.starts == 1
    return bridge, t


def _step(bridge: GpsBridge, t: float, k: int) -> None:
    """The estimator's calls at a measurement: A noted; a GPS sample every 5th."""
    _note(bridge, t)
    if k % 5 == 0:
        bridge.on_gps(
            t, _v(t - 0.13), sigma_gps_mps=None, start=False, v_est=_v(t), sigma_est_mps=0.03
        )


def test_b1_is_the_gps_velocity_carried_to_now_by_the_imu() -> None:
    bridge, t_g = _started()
    # (B1): y(t) = v_gps(t_g) + A(t) − A(t_g − L), with v_gps(t_g) = v(t_g − L): exactly
    # v(t), up to A's linear interpolation at t_g − L (0.4 mm/s, test above)
    for k in (1, 2, 3):
        t = t_g + k / MEAS_HZ
        _note(bridge, t)
        truth = _v(t)
        y = bridge.measurement(t, (truth[0] + AP_OFF_MPS, truth[1]), aided=True)
        assert y is not None
        assert abs(y[0] - truth[0]) < 1e-3 and abs(y[1] - truth[1]) < 1e-3, (y, truth)


def test_no_bridge_when_the_autopilot_already_agrees_with_the_gps() -> None:
    bridge = GpsBridge(GpsBridgeConfig())
    t = _learn(bridge, 0.13, 30.0)
    v = _v(t)
    # 0.05 m/s off: within start_sigma σ_gps (0.08): the autopilot snapped back already
    bridge.on_gps(
        t, _v(t - 0.13), sigma_gps_mps=None, start=True, v_est=(v[0] + 0.05, v[1]),
        sigma_est_mps=0.3,
    )  # fmt: skip
    assert not bridge.active and bridge.not_needed == 1


def test_a_gps_sample_far_from_the_banks_estimate_does_not_start_it() -> None:
    bridge = GpsBridge(GpsBridgeConfig())
    t = _learn(bridge, 0.13, 30.0)
    # gate: 5 √(0.03² + 0.02²) = 0.18 m/s; the GPS says 1 m/s more
    v = _v(t - 0.13)
    bridge.on_gps(
        t, (v[0] + 1.0, v[1]), sigma_gps_mps=None, start=True, v_est=_v(t), sigma_est_mps=0.03
    )
    assert not bridge.active and bridge.rejected == 1


def test_the_autopilot_agreeing_ends_it_with_the_offset_decaying_and_no_step() -> None:
    cfg = GpsBridgeConfig()
    bridge, t_g = _started()
    out: list[tuple[float, tuple[float, float]]] = []
    k = 0
    t_agree = t_g + 0.4  # the autopilot resets 0.4 s after the fix: then 0.05 off
    while True:
        k += 1
        t = t_g + k / MEAS_HZ
        _step(bridge, t, k)
        truth = _v(t)
        off = AP_OFF_MPS if t < t_agree else 0.05
        y = bridge.measurement(t, (truth[0] + off, truth[1]), aided=True)
        if y is None:
            break
        out.append((t, (y[0] - truth[0], y[1] - truth[1])))
        assert k < 200, "never handed back"
    # B1 (= truth) until the reset; then the offset B1 − autopilot (−0.05) decays to 0
    # over blend_s: the error goes from 0 to the autopilot's 0.05 linearly
    before = [e for t, e in out if t < t_agree]
    assert before and max(abs(e[0]) for e in before) < 1e-3
    t_end = out[-1][0]
    assert t_end - t_agree == pytest.approx(cfg.blend_s, abs=2.0 / MEAS_HZ)
    errs = [e[0] for _, e in out]
    steps = [abs(b - a) for a, b in itertools.pairwise(errs)]
    # 0.05 m/s over 1 s at 25 Hz: 2 mm/s per sample, never a step
    assert max(steps) <= 0.05 / (cfg.blend_s * MEAS_HZ) + 1e-3, max(steps)


def test_an_autopilot_not_yet_aided_is_never_agreement() -> None:
    bridge, t_g = _started()
    for k in range(1, 100):  # 4 s, GPS samples on time
        t = t_g + k / MEAS_HZ
        _step(bridge, t, k)
        truth = _v(t)
        y = bridge.measurement(t, truth, aided=False)
        assert y is not None and abs(y[0] - truth[0]) < 1e-3
    assert bridge.bridging


def test_a_silent_gps_ends_the_bridge_after_its_timeout_and_the_blend() -> None:
    cfg = GpsBridgeConfig()
    bridge, t_g = _started()
    ended = None
    for k in range(1, 200):
        t = t_g + k / MEAS_HZ
        _note(bridge, t)
        truth = _v(t)
        if bridge.measurement(t, (truth[0] + AP_OFF_MPS, truth[1]), True) is None:
            ended = t
            break
    assert ended is not None
    assert ended - t_g == pytest.approx(cfg.gps_timeout_s + cfg.blend_s, abs=2.0 / MEAS_HZ)


def test_the_receivers_own_accuracy_replaces_the_shown_sigma() -> None:
    bridge = GpsBridge(GpsBridgeConfig())
    t = _learn(bridge, 0.13, 30.0)
    v = _v(t)
    # the autopilot 0.3 m/s off: beyond 4 × the shown 0.02, but within 4 × the
    # receiver's 0.1 (vel_acc): that GPS cannot tell, so no bridge
    bridge.on_gps(
        t, _v(t - 0.13), sigma_gps_mps=0.1, start=True, v_est=(v[0] + AP_OFF_MPS, v[1]),
        sigma_est_mps=0.3,
    )  # fmt: skip
    assert not bridge.active and bridge.not_needed == 1


def test_b1_takes_the_fitted_accelerometer_bias_out_as_the_bank_does() -> None:
    """Without the bias in force, B1 drifts by b · (t − (t_g − L)) (0.2 m/s² over 0.25 s:
    0.05 m/s); with it, B1 is the velocity; a refit of the bias between the anchor and
    now applies to the interval only (ΔB b̂), never to B's whole history (B ≈ 30 s here:
    that would be 6 m/s)."""
    bridge, t_g = _started()
    t = t_g + 0.12
    _note(bridge, t)
    truth = _v(t)
    y = bridge.measurement(t, (truth[0] + AP_OFF_MPS, truth[1]), aided=False)
    assert y is not None and abs(y[0] - truth[0]) < 1e-3
    b_refit = (0.25, -0.1, 0.0)  # the fit moves while the bridge runs
    t2 = t + 0.04
    _note(bridge, t2, b_refit)
    truth = _v(t2)
    y = bridge.measurement(t2, (truth[0] + AP_OFF_MPS, truth[1]), aided=False)
    assert y is not None
    # error: (b − b_refit) · (t2 − (t_g − L)) = −0.05 · 0.29 s ≈ 0.015 m/s at most
    assert abs(y[0] - truth[0]) < 0.02, (y, truth)
    _note(bridge, t2 + 0.04, (0.0, 0.0, 0.0))  # a bias the fit no longer holds: not taken out
    truth = _v(t2 + 0.04)
    y = bridge.measurement(t2 + 0.04, (truth[0] + AP_OFF_MPS, truth[1]), aided=False)
    assert y is not None and abs(y[0] - truth[0]) == pytest.approx(0.2 * 0.33, abs=0.01)


def test_a_restart_ends_the_bridge_and_keeps_what_was_learnt() -> None:
    """After a reboot the vehicle's time starts again near 0 and the bank's integrals
    from 0: the history goes, the lag and the trust stay, and learning goes on at once
    (not only once the new clock passes the old one)."""
    bridge, _ = _started()
    lag = bridge.lag_s
    bridge.restart()
    assert not bridge.active and bridge.trusted and bridge.lag_s == lag
    assert bridge.learn_due(1.0)
    # the first GPS sample after the reboot, before any integral is noted: nothing to
    # carry it with, so no bridge (and no error)
    bridge.on_gps(
        1.0, (5.0, 0.0), sigma_gps_mps=None, start=True, v_est=(0.0, 0.0), sigma_est_mps=0.3
    )
    assert not bridge.active
