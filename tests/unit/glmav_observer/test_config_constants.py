"""The constants issue 32 exposed in ``service.toml``: ``[fdi] overdue_intervals``,
``[fdi.imu]`` (the redundant-IMU monitor) and ``[fdi.despike]`` (IMU shock rejection).
Each key: an accepted value reaches the part that uses it and changes what it does; a bad
value is an error naming the key (exit 2 from the command line)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from glmav_observer.cli import main
from glmav_observer.config import ConfigError, parse_config
from glmav_observer.estimation.despike import Despiker
from glmav_observer.estimation.drift import drift_sigma_ned_mps
from glmav_observer.estimation.fdi_types import DespikeConfig, FdiConfig
from glmav_observer.estimation.imu_monitor import ImuConsistency, ImuMonitorConfig
from glmav_observer.estimation.vehicle import VehicleEstimator


def _fdi(doc: dict[str, Any]) -> FdiConfig:
    return parse_config({"fdi": doc}, "t.toml").estimation.fdi


# ------------------------------------------------------------------ [fdi.imu]
def _imu_events(
    cfg: ImuMonitorConfig,
    *,
    n_imus: int = 3,
    bias: Callable[[float], float] = lambda t: 0.3 if 10.0 <= t < 20.0 else 0.0,
    lag_s: float = 0.0,
) -> list[tuple[str, int | None, float]]:
    """IMUs at 50 Hz on one airframe (σ 0.02 m/s² per axis, seeded), the last one biased
    on x by ``bias(t)``, its samples ``lag_s`` older than IMU 1's; 30 s. The events as
    (kind, instance, t_detect rounded to 0.01 s)."""
    mon = ImuConsistency(cfg)
    rng = np.random.default_rng(1)
    out = []
    for k in range(1500):
        t = k * 0.02
        for inst in range(2, n_imus + 1):
            b = bias(t) if inst == n_imus else 0.0
            n = rng.normal(0.0, 0.02, 3)
            mon.secondary(inst, t - lag_s, (n[0] + b, n[1], -9.81 + n[2]))
        n = rng.normal(0.0, 0.02, 3)
        out += [
            (e.kind, e.instance, round(e.t_detect_s, 2))
            for e in mon.primary(t, (n[0], n[1], -9.81 + n[2]))
        ]
    return out


def test_imu_monitor_defaults_see_a_step_on_the_third_imu() -> None:
    """The reference the cases below differ from: a 0.3 m/s² step on IMU 3 at 10 s (2×
    the floor, ~50σ of a window's mean) is published a window later (0.5 s), named, and
    its end once the deviation stayed below half the threshold for a window."""
    ev = _imu_events(ImuMonitorConfig())
    assert ev[0] == ("onset", 3, 10.5)
    assert ev[1][:2] == ("end", 3) and 20.5 <= ev[1][2] <= 21.5
    assert len(ev) == 2


ramp = lambda t: 0.0 if t < 10.0 else min(0.1 * (t - 10.0), 0.5)  # noqa: E731


@pytest.mark.parametrize(
    ("key", "value", "kwargs", "expect"),
    [
        # a window of 1 s: published 1 s after the onset, not 0.5 s
        ("window_s", 1.0, {}, lambda ev: ev[0] == ("onset", 3, 11.0)),
        # a floor above the 0.3 m/s² step: nothing
        ("floor_mps2", 0.4, {}, lambda ev: ev == []),
        # 100σ of a window's mean (0.028/√25 · 100 = 0.57 m/s²): above the step, nothing
        ("k_sigma", 100.0, {}, lambda ev: ev == []),
        # a 0.1 m/s²/s ramp: a 60 s baseline sees it, a 0.5 s one follows it (lag 0.05)
        ("baseline_tau_s", 0.5, {"bias": ramp}, lambda ev: ev == []),
        # secondary samples 15 ms older than IMU 1's: compared at 0.1 s, dropped at 0.01
        ("max_age_s", 0.01, {"lag_s": 0.015}, lambda ev: ev == []),
        # two IMUs, nobody to blame: published naming none after the timeout (3 s -> 6 s)
        ("resolve_timeout_s", 6.0, {"n_imus": 2}, lambda ev: ev[0] == ("onset", None, 16.0)),
        # a 0.5 s window holds 25 samples: 100 are never there
        ("min_samples", 100, {}, lambda ev: ev == []),
        # a window never spans all of window_s (its oldest sample leaves at window_s)
        ("min_fill", 1.0, {}, lambda ev: ev == []),
        # an end below 1 % of the threshold: the noise of a window's mean never gets there
        ("end_fraction", 0.01, {}, lambda ev: [e[0] for e in ev] == ["onset"]),
    ],
)
def test_an_fdi_imu_key_changes_the_monitor(
    key: str, value: float, kwargs: dict[str, Any], expect: Callable[[list[Any]], bool]
) -> None:
    cfg = _fdi({"imu": {key: value}}).imu
    assert getattr(cfg, key) == value
    est = VehicleEstimator(1, parse_config({"fdi": {"imu": {key: value}}}).estimation)
    assert est.imus is not None and est.imus.cfg == cfg  # the estimator's monitor uses it
    if key == "resolve_timeout_s":
        assert _imu_events(ImuMonitorConfig(), **kwargs)[0] == ("onset", None, 13.0)
    if key == "baseline_tau_s":
        assert _imu_events(ImuMonitorConfig(), **kwargs)[0][:2] == ("onset", 3)
    if key == "max_age_s":
        assert _imu_events(ImuMonitorConfig(), **kwargs)[0] == ("onset", 3, 10.5)
    assert expect(_imu_events(cfg, **kwargs))


# ------------------------------------------------------------------ [fdi.despike]
def _spike_held(cfg: DespikeConfig, sigma_mps2: float, n: int, spike_mps2: float) -> bool:
    """After ``n`` IMU samples of white noise σ per axis (seeded), is a sample
    ``spike_mps2`` off gravity on x held out?"""
    d = Despiker(cfg.floor_mps2, cfg.k_sigma, cfg.tau_samples)
    rng = np.random.default_rng(2)
    for _ in range(n):
        x, y, z = rng.normal(0.0, sigma_mps2, 3)
        d.filter((x, y, z - 9.81))
    return d.filter((spike_mps2, 0.0, -9.81)) is None


@pytest.mark.parametrize(
    ("key", "value", "case", "held_default", "held"),
    [
        # a clean IMU: a 50 m/s² step is above the 40 floor, below a 60 one
        ("floor_mps2", 60.0, (0.0, 5, 50.0), True, False),
        # a vibrating IMU (σ 5: ‖Δf‖ RMS ≈ 12): 8 RMS ≈ 98 passes a 50 step, 1 RMS holds it
        ("k_sigma", 1.0, (5.0, 300, 50.0), False, True),
        # after 30 noisy samples a 100-sample memory has learnt ~26 % of the noise (bar
        # ≈ 51), a 10-sample one all of it (bar ≈ 98): a 70 step is held, then passes
        ("tau_samples", 10, (5.0, 30, 70.0), True, False),
    ],
)
def test_an_fdi_despike_key_changes_the_spike_threshold(
    key: str, value: float, case: tuple[float, int, float], held_default: bool, held: bool
) -> None:
    cfg = _fdi({"despike": {key: value}}).despike
    assert getattr(cfg, key) == value
    est = VehicleEstimator(1, parse_config({"fdi": {"despike": {key: value}}}).estimation)
    assert est.despike.floor_mps2 == cfg.floor_mps2 and est.despike.k_sigma == cfg.k_sigma
    assert _spike_held(DespikeConfig(), *case) is held_default
    assert _spike_held(cfg, *case) is held


# ------------------------------------------------------------------ [fdi] overdue_intervals
def test_overdue_intervals_sets_when_a_late_stream_is_flagged() -> None:
    """A 10 Hz stream 0.2 s after its last sample (2 intervals): overdue at 1.5 intervals
    (every axis flagged, σ from the last sample), not yet at 3."""
    late = (FdiConfig(), 0.2, [None, None, None], 0.0, 0.1)
    assert all(s is not None for s in drift_sigma_ned_mps(*late))
    cfg = _fdi({"overdue_intervals": 3.0})
    assert cfg.overdue_intervals == 3.0
    assert drift_sigma_ned_mps(cfg, *late[1:]) == [None, None, None]


# ------------------------------------------------------------------ bad values
BAD = [
    ({"overdue_intervals": 0.5}, "fdi.overdue_intervals", r"\[1, 1000\]"),
    ({"imu": {"window_s": 0.0}}, "fdi.imu.window_s", r"\(0, 60\]"),
    ({"imu": {"floor_mps2": -0.1}}, "fdi.imu.floor_mps2", r"\(0, 10000\]"),
    ({"imu": {"k_sigma": 0.0}}, "fdi.imu.k_sigma", r"\(0, 100\]"),
    ({"imu": {"baseline_tau_s": 0.0}}, "fdi.imu.baseline_tau_s", r"\(0, 86400\]"),
    ({"imu": {"max_age_s": 20.0}}, "fdi.imu.max_age_s", r"\(0, 10\]"),
    ({"imu": {"resolve_timeout_s": -1.0}}, "fdi.imu.resolve_timeout_s", r"\[0, 600\]"),
    ({"imu": {"min_samples": 1}}, "fdi.imu.min_samples", r"\[2, 100000\]"),
    ({"imu": {"min_fill": 1.5}}, "fdi.imu.min_fill", r"\(0, 1\]"),
    ({"imu": {"end_fraction": 0.0}}, "fdi.imu.end_fraction", r"\(0, 1\]"),
    ({"imu": {"windows": 1.0}}, "fdi.imu.windows", "unknown key"),
    ({"despike": {"floor_mps2": 0.0}}, "fdi.despike.floor_mps2", r"\(0, 10000\]"),
    ({"despike": {"k_sigma": "8"}}, "fdi.despike.k_sigma", "expected a number"),
    ({"despike": {"tau_samples": 0}}, "fdi.despike.tau_samples", r"\[1, 1000000\]"),
]


@pytest.mark.parametrize(("doc", "key", "reason"), BAD)
def test_a_bad_value_names_the_key(doc: dict[str, Any], key: str, reason: str) -> None:
    with pytest.raises(ConfigError, match=reason) as info:
        parse_config({"fdi": doc}, "my.toml")
    assert info.value.key == key and info.value.file == "my.toml"


def _toml(doc: dict[str, Any]) -> str:
    """``doc`` (one level of sub-tables under [fdi]) as TOML."""
    lines, subs = ["[fdi]"], []
    for k, v in doc.items():
        if isinstance(v, dict):
            subs += [f"[fdi.{k}]", *(f"{kk} = {vv!r}".replace("'", '"') for kk, vv in v.items())]
        else:
            lines.append(f"{k} = {v!r}")
    return "\n".join(lines + subs) + "\n"


@pytest.mark.parametrize(("doc", "key", "reason"), BAD)
def test_a_bad_value_exits_2_naming_the_key(
    doc: dict[str, Any], key: str, reason: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(_toml(doc), encoding="utf-8")
    log = tmp_path / "x.tlog"
    log.write_bytes(b"")
    assert main(["replay", str(log), "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and key in err and "Traceback" not in err
