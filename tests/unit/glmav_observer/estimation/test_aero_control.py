"""SERVO_OUTPUT_RAW -> ControlSample -> the cyclic regressors (C1) -> the drag model's control
term (estimation/aero/control.py, model.py ``control``); the config table."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as dialect

from glmav_observer.config import ConfigError, parse_config
from glmav_observer.estimation.aero import DragModel, DragModelConfig
from glmav_observer.estimation.aero.control import ControlMapping
from glmav_observer.frames import e_exact
from glmav_observer.ingest.framing import FrameDecoder
from glmav_observer.ingest.pipeline import Ingest, IngestConfig
from glmav_observer.ingest.samples import ControlSample


def _decoded(msg: Any) -> Any:
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    (out,) = FrameDecoder(datagram=True).feed(bytes(msg.pack(mav)))
    return out


def test_servo_output_raw_becomes_a_control_sample_at_the_vehicles_latest_time() -> None:
    ing = Ingest(IngestConfig(control_samples=True))
    att = dialect.MAVLink_attitude_message(2500, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    ing.on_message(_decoded(att), 0.0)
    # time_usec 7 s is ignored (a uint32 that wraps): stamped with the latest time, 2.5 s
    servo = dialect.MAVLink_servo_output_raw_message(
        7_000_000, 0, 1600, 1625, 1500, 1750, 0, 0, 0, 0
    )
    (s,) = ing.on_message(_decoded(servo), 0.0)
    assert isinstance(s, ControlSample)
    assert s.t_boot_s == 2.5 and s.sysid == 1
    assert s.servo_pwm_us[:5] == (1600, 1625, 1500, 1750, 0) and len(s.servo_pwm_us) == 16


def test_regressors_of_the_default_map() -> None:
    m = ControlMapping()
    # Ω2 = 625 µs · 0.32 = 200 rad/s, δcx = 0, δcy = 250 · 0.26/500 = 0.13 rad
    rho = m.regressors((1600, 1625, 1500, 1750) + (0,) * 12)
    assert rho is not None
    assert rho[0] == pytest.approx(-math.sin(0.13) * 4.0, rel=1e-12)  # (Ω2/100)² = 4
    assert rho[1] == 0.0
    assert m.regressors((1600, 0, 1500, 1750)) is None  # an unused channel: no regressor
    assert m.regressors((1600, 1625)) is None  # channels absent


def test_the_control_term_is_learnt_and_used() -> None:
    """f_j = b ρ_j − k u_j (no wind): learnt from varied samples, b and k come out and the
    lost axis is recovered from f and ρ."""
    rng = np.random.default_rng(4)
    b, k = 1.1, 0.4
    model = DragModel(DragModelConfig(control=True))
    for i in range(3000):
        yaw = 0.002 * i
        E = e_exact(np.array([0.0, 0.0, yaw]))
        v = rng.normal(0.0, 1.5, 3) * np.array([1.0, 1.0, 0.1])
        u = E.T @ v
        rho = (float(rng.normal(0.0, 0.3)), float(rng.normal(0.0, 0.3)))
        f = np.array([b * rho[0] - k * u[0], b * rho[1] - k * u[1], -9.8])
        f[:2] += rng.normal(0.0, 0.03, 2)
        model.learn(0.04 * i, f, E, v, rho)
    assert model.n_no_control == 0
    # 3000 samples at σ_f 0.03 m/s²: σ(b) ~ 0.03/(0.3·√3000) ≈ 0.002; 0.02 is 10σ
    assert model.theta[:, 5] == pytest.approx([b, b], abs=0.02)
    assert model.k_per_s == pytest.approx([k, k], abs=0.02)
    assert model.trust().ok
    E = e_exact(np.array([0.0, 0.0, 0.3]))
    v = np.array([1.0, -0.5, 0.0])
    rho = (0.2, -0.1)
    u = E.T @ v
    f = np.array([b * rho[0] - k * u[0], b * rho[1] - k * u[1], -9.8])
    pm = model.pseudo_measurement(f, E, v, 0, control=rho)
    assert pm is not None
    # noise-free input: the error is the coefficients' (σ ≈ 0.03/0.4/√(3000/…) ≪ 0.05)
    assert abs(pm.v_mps - 1.0) < 0.05 and pm.sigma_mps < 0.2
    # without its control the model neither predicts nor learns
    assert model.pseudo_measurement(f, E, v, 0) is None
    n = model.n_learned
    model.learn(200.0, f, E, v, None)
    assert model.n_learned == n and model.n_no_control == 1


def test_config_table_off_by_default_and_checked() -> None:
    assert parse_config({}).estimation.aero_control is None
    on = parse_config({"estimation": {"aero_control": {"enabled": True, "dcx_channel": 5}}})
    assert on.estimation.aero_control == ControlMapping(dcx_channel=5)
    with pytest.raises(ConfigError, match=r"must be in \[1, 16\]") as info:
        parse_config({"estimation": {"aero_control": {"omega2_channel": 17}}}, "my.toml")
    assert info.value.key == "estimation.aero_control.omega2_channel"
    # the stream can be asked for like the others (not by default)
    assert "SERVO_OUTPUT_RAW" not in parse_config({}).ingest.rates_hz
    asked = parse_config({"rates": {"hz": {"SERVO_OUTPUT_RAW": 50.0}}})
    assert asked.ingest.rates_hz["SERVO_OUTPUT_RAW"] == 50.0
