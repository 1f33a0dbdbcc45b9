"""Scenarios load, validate, and the controller flies them (in-process, no sockets)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from glmav_sitl.config import data_path
from glmav_sitl.scenario import load_scenario, scenario_names
from glmav_sitl.simulator import Simulator, TruthState
from glmav_toml import ConfigError

EXPECTED = {
    "hover",
    "cruise",
    "climbing-turn",
    "gusts",
    "launch",
    "paper",
    "fault-dropout",
    "fault-freeze",
    "fault-bias",
    "fault-noise",
    "fault-accel-bias",
}


def _fly(name: str, duration_s: float, every_s: float = 0.1, **kw: object) -> list[TruthState]:
    sim = Simulator(load_scenario(name), **kw)  # type: ignore[arg-type]
    out = [sim.truth()]
    every = round(every_s / sim.dt_s)
    for _ in range(round(duration_s / sim.dt_s)):
        sim.step()
        if sim.n_steps % every == 0:
            out.append(sim.truth())
    return out


def test_all_scenarios_ship_and_load() -> None:
    assert set(scenario_names()) >= EXPECTED
    for name in scenario_names():
        sc = load_scenario(name)
        assert sc.name == name and sc.duration_s > 0


def test_hover_closed_loop_holds_altitude_60s_noise_free() -> None:
    # the controller flies on truth; noise does not enter the flight, so this is noise-free
    tr = _fly("hover", 60.0)
    dz = max(abs(t.p_ned_m[2] + 10.0) for t in tr)
    assert dz < 0.1  # issue: within 0.1 m for 60 s
    assert max(math.hypot(t.p_ned_m[0], t.p_ned_m[1]) for t in tr) < 0.1


def test_cruise_reaches_5mps_and_holds_altitude() -> None:
    tr = _fly("cruise", 25.0)
    late = [t for t in tr if t.t_s >= 15.0]
    # 5 m/s commanded north; after the integrator has settled (10 s), within 0.1 m/s
    assert all(abs(t.v_ned_mps[0] - 5.0) < 0.1 for t in late)
    assert all(abs(t.v_ned_mps[1]) < 0.1 and abs(t.p_ned_m[2] + 20.0) < 0.3 for t in late)
    # the drag of eqs (6)-(8) at 5 m/s needs a nose-down tilt of ~0.3 rad
    assert -0.4 < late[-1].euler_rad[1] < -0.2


def test_climbing_turn_tracks_speed_climb_and_turn_rate() -> None:
    tr = _fly("climbing-turn", 20.0)
    late = [t for t in tr if t.t_s >= 10.0]
    for t in late:
        assert math.hypot(t.v_ned_mps[0], t.v_ned_mps[1]) == pytest.approx(3.0, abs=0.15)
        assert -t.v_ned_mps[2] == pytest.approx(1.0, abs=0.1)
    # heading turns at 0.3 rad/s: yaw rate in earth axes ~ r cos(phi) cos(theta) ~ 0.3
    yaw = np.unwrap([t.euler_rad[2] for t in late])
    rate = (yaw[-1] - yaw[0]) / (late[-1].t_s - late[0].t_s)
    assert rate == pytest.approx(0.3, abs=0.01)


def test_gusts_scenario_holds_position_within_bounds() -> None:
    tr = _fly("gusts", 40.0)
    err = [math.dist(t.p_ned_m, (0.0, 0.0, -20.0)) for t in tr if t.t_s > 3.0]
    # 4 m/s side gust and 0.8 m/s turbulence; the position loop (1/s) keeps it within ~2 m
    assert max(err) < 2.5
    winds = [t.wind_ned_mps for t in tr]
    # the side gust peaks at 4 m/s east at t = 11 s (plus turbulence of sigma 0.8)
    at11 = next(w for t, w in zip(tr, winds, strict=True) if t.t_s >= 11.0)
    assert 4.0 - 3 * 0.8 < at11[1] < 4.0 + 3 * 0.8


def test_launch_ballistic_climb_spin_up_and_hover() -> None:
    tr = _fly("launch", 20.0)
    before = [t for t in tr if t.t_s <= 1.2]
    # ballistic: rotors stopped, decelerating faster than g (drag adds to weight)
    assert all(t.rotor_radps == (0.0, 0.0) for t in before)
    v1 = next(t for t in tr if t.t_s >= 1.0)
    assert -25.0 + 9.81 * 1.0 < v1.v_ned_mps[2] < 0.0  # slowed by more than g in 1 s
    hold = next(t for t in tr if t.t_s >= 1.2).p_ned_m
    end = tr[-1]
    assert math.dist(end.p_ned_m, hold) < 0.5  # transition to hover at the 1.2 s point
    assert max(abs(v) for v in end.v_ned_mps) < 0.05
    # rotors end at the hover trim (within 1 %)
    sim = Simulator(load_scenario("launch"))
    assert end.rotor_radps[0] == pytest.approx(sim.trim_rotor_radps[0], rel=0.01)


def test_paper_scenario_starts_at_eq_48() -> None:
    sim = Simulator(load_scenario("paper"))
    t0 = sim.truth()
    assert sim.dt_s == 1e-4
    assert t0.p_ned_m == (0.0, 1.0, 1.0)
    assert t0.v_body_mps == (2.0, -1.3, 1.3)
    assert t0.euler_rad == pytest.approx((1.3, 0.3, 0.2), abs=1e-12)
    assert t0.omega_body_radps == (0.1, 0.2, 0.1)
    assert sim.sensor_config.noise is False and sim.sensor_config.bias is False


def test_faults_are_parsed(tmp_path: Path) -> None:
    sc = load_scenario("fault-dropout")
    (f,) = sc.faults
    assert (f.sensor, f.axis, f.kind, f.t_start_s, f.t_end_s) == (
        "velocity",
        "d",
        "dropout",
        20.0,
        40.0,
    )
    (a,) = load_scenario("fault-accel-bias").faults
    assert (a.sensor, a.kind, a.vector) == ("accel", "accel_bias", (0.3, -0.2, 0.1))


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        (
            'kind = "dropout"',
            'kind = "explode"',
            r"faults\[0\]\.kind: must be one of dropout, .*got 'explode'",
        ),
        ('axis = "d"', 'axis = "z"', r"faults\[0\]\.axis"),
        (
            "duration_s = 60.0",
            "duration_s = -1.0",
            r"duration_s: must be in \(0, 1e\+06\], got -1\.0",
        ),
        (
            "duration_s = 60.0",
            "duration_s = 60.0\nspeed = 3",
            r"speed: unknown key \(known: .*duration_s",
        ),
        ("speed_mps = 3.0", 'speed_mps = "fast"', r"setpoints\[1\]\.speed_mps: expected a number"),
    ],
)
def test_bad_scenario_names_file_key_and_reason(
    tmp_path: Path, old: str, new: str, match: str
) -> None:
    text = data_path("scenarios", "fault-dropout.toml").read_text(encoding="utf-8")
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(ConfigError, match=match) as e:
        load_scenario(p)
    assert str(p) in str(e.value)


def test_unknown_scenario_name_lists_the_known_ones() -> None:
    with pytest.raises(ConfigError, match=r"unknown scenario 'nope' .*hover"):
        load_scenario("nope")


def test_same_flight_whatever_the_sensor_faults() -> None:
    a = _fly("fault-dropout", 25.0, every_s=5.0)
    sc = replace(load_scenario("fault-dropout"), faults=())
    sim = Simulator(sc)
    sim.run_for(25.0)
    assert a[-1].p_ned_m == sim.truth().p_ned_m
