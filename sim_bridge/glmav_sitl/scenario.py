"""Simulator settings (``sitl.toml``) and scenarios (``scenarios/NAME.toml``), validated.

A scenario names its initial state, how the vehicle is flown (closed loop with
time-tagged setpoints, or open-loop actuator inputs), the wind, the sensor profile
(``ideal`` or ``autopilot``, see :mod:`glmav_sitl.sensors.autopilot`), sensor noise
switches, stream rates and scheduled sensor faults. See ``glmav_sitl/data/scenarios/*.toml``
for commented examples; every key is checked (unknown keys are errors).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from glmav_sitl.config import (
    ConfigError,
    check_keys,
    data_path,
    get_bool,
    get_float,
    get_str,
    get_table,
    get_vec,
    load_toml,
)
from glmav_sitl.wind import Gust, WindConfig

# MAVLink streams the simulator emits and their message ids
STREAM_IDS: dict[str, int] = {
    "heartbeat": 0,
    "raw_imu": 27,
    "scaled_imu": 26,
    "highres_imu": 105,
    "attitude": 30,
    "local_position_ned": 32,
    "sim_state": 108,
}


@dataclass(frozen=True)
class ImuConfig:
    gyro_noise_density: float = 3.4e-4  # rad/s/sqrt(Hz)
    accel_noise_density: float = 4e-3  # m/s^2/sqrt(Hz)
    gyro_bias_sigma: float = 8.7e-3  # rad/s, turn-on
    accel_bias_sigma: float = 0.2  # m/s^2, turn-on
    gyro_bias_random_walk: float = 3.9e-5  # rad/s^2/sqrt(Hz)
    accel_bias_random_walk: float = 6e-3  # m/s^3/sqrt(Hz)
    raw_accel_lsb_mps2: float = 9.80665e-3  # 1 mG
    raw_gyro_lsb_radps: float = 1e-3  # 1 mrad/s


@dataclass(frozen=True)
class SensorConfig:
    imu: ImuConfig = field(default_factory=ImuConfig)
    attitude_sigma_rad: float = 0.005
    velocity_sigma_mps: float = 0.05
    position_sigma_m: float = 0.3
    noise: bool = True
    bias: bool = True
    noise_scale: float = 1.0
    bias_scale: float = 1.0


SENSOR_PROFILES = ("ideal", "autopilot")


@dataclass(frozen=True)
class AutopilotProfileConfig:
    """The ``autopilot`` sensor profile (``[autopilot]`` in sitl.toml); see docs/model.md.

    A fast IMU with rotor vibration, an attitude estimator (complementary filter) on it,
    and an EKF-like filtered GPS velocity with a lag. The IMU noise densities, biases and
    random walks are the ``[imu]`` ones.
    """

    imu_rate_hz: float = 1000.0  # internal IMU sampling (capped by the physics step rate)
    # vibration: sinusoids at harmonics of each rotor's speed, amplitude ~ (Omega/trim)^2
    vibration_harmonics: tuple[float, ...] = (1.0, 2.0)  # multiples of the rotor speed
    vibration_harmonic_weights: tuple[float, ...] = (1.0, 0.5)
    vibration_accel_mps2: tuple[float, float, float] = (1.5, 1.5, 2.5)  # per rotor, at trim
    vibration_gyro_radps: tuple[float, float, float] = (0.03, 0.03, 0.01)  # per rotor, at trim
    broadband_accel_mps2: float = 0.3  # extra white vibration per fast sample (1 sigma)
    broadband_gyro_radps: float = 0.005
    # attitude estimator (complementary filter with GPS-acceleration compensation)
    ahrs_rate_hz: float = 250.0
    ahrs_tilt_gain: float = 0.1  # 1/s, accelerometer correction of roll and pitch
    ahrs_yaw_gain: float = 0.2  # 1/s, compass correction of yaw
    ahrs_bias_gain: float = 0.005  # 1/s^2, gyro bias integrator
    ahrs_accel_comp_tau_s: float = 0.3  # low-pass of the GPS-derived NED acceleration
    ahrs_rate_filter_hz: float = 20.0  # low-pass of ATTITUDE body rates
    gyro_cal_sigma_radps: float = 1e-3  # residual of the boot gyro calibration
    accel_cal_sigma_mps2: float = 0.03  # residual of the accelerometer calibration
    compass_bias_sigma_rad: float = 0.01  # constant heading error (declination, soft iron)
    compass_noise_rad: float = 0.02  # white, per AHRS update
    # GPS and the EKF-like velocity/position output
    gps_rate_hz: float = 10.0
    gps_velocity_sigma_mps: float = 0.08
    gps_position_sigma_m: float = 0.3
    velocity_filter_tau_s: float = 0.1  # first-order filter on each GPS fix
    velocity_lag_s: float = 0.15  # total lag of LOCAL_POSITION_NED against truth
    rates_hz: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ControllerGains:
    pos_p: float = 1.0  # 1/s, position error -> velocity command
    vel_p: float = 2.0  # 1/s, velocity error -> acceleration command
    vel_i: float = 0.5  # 1/s^2
    att_p: float = 8.0  # 1/s, attitude error -> rate command
    rate_p: float = 30.0  # 1/s, rate error -> angular acceleration command
    yaw_p: float = 3.0  # 1/s
    yaw_rate_p: float = 8.0  # 1/s
    max_tilt_rad: float = 0.5
    max_speed_mps: float = 8.0
    max_accel_mps2: float = 5.0
    max_rate_radps: float = 4.0


@dataclass(frozen=True)
class SitlConfig:
    dt_s: float = 1e-3
    control_rate_hz: float = 250.0
    sysid: int = 1
    compid: int = 1
    home_lat_deg: float = 47.5867
    home_lon_deg: float = 7.5654
    home_alt_m: float = 260.0
    start_unix_s: float = 1.7e9
    rates_hz: dict[str, float] = field(default_factory=dict)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    gains: ControllerGains = field(default_factory=ControllerGains)
    autopilot: AutopilotProfileConfig = field(default_factory=AutopilotProfileConfig)


@dataclass(frozen=True)
class Setpoint:
    """From ``t_s`` on: ``kind`` in position, velocity, turn, hold (here), idle (rotors off)."""

    t_s: float
    kind: str
    position_ned_m: tuple[float, float, float] | None = None
    velocity_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rad: float | None = None
    speed_mps: float = 0.0
    turn_rate_radps: float = 0.0
    climb_rate_mps: float = 0.0


@dataclass(frozen=True)
class Fault:
    """A scheduled sensor fault active on ``[t_start_s, t_end_s)``."""

    sensor: str  # "velocity" or "accel"
    kind: str  # velocity: dropout, freeze, bias, noise; accel: bias
    t_start_s: float
    t_end_s: float
    axis: str = ""  # velocity: n, e, d
    magnitude: float = 0.0
    vector: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    duration_s: float
    dt_s: float | None
    control: str  # closed_loop | open_loop
    position_ned_m: tuple[float, float, float]
    velocity_body_mps: tuple[float, float, float]
    euler_rad: tuple[float, float, float]
    omega_body_radps: tuple[float, float, float]
    rotor_radps: tuple[float, float] | None  # None: trim
    swash_rad: tuple[float, float]
    open_loop_rotor_radps: tuple[float, float] | None  # None: trim
    open_loop_swash_rad: tuple[float, float]
    setpoints: tuple[Setpoint, ...]
    wind: WindConfig
    sensors: dict[str, Any]
    rates_hz: dict[str, float]
    faults: tuple[Fault, ...]
    source: str = ""
    sensor_profile: str = "ideal"  # one of SENSOR_PROFILES


def _rates(path: str | Path, table: dict[str, Any], prefix: str) -> dict[str, float]:
    check_keys(path, table, set(STREAM_IDS), prefix=prefix)
    return {k: get_float(path, table, k, prefix=prefix, lo=0.0, hi=100000.0) for k in table}


def load_sitl_config(path: str | Path | None = None) -> SitlConfig:
    """Load ``sitl.toml`` (default: the packaged copy)."""
    p = Path(path) if path is not None else data_path("sitl.toml")
    raw = load_toml(p)
    check_keys(
        p,
        raw,
        {
            "dt_s",
            "control_rate_hz",
            "sysid",
            "compid",
            "home",
            "start_unix_s",
            "rates_hz",
            "imu",
            "attitude",
            "local_position",
            "controller",
            "autopilot",
        },
    )
    home = get_table(p, raw, "home")
    check_keys(p, home, {"lat_deg", "lon_deg", "alt_m"}, prefix="home.")
    imu_t = get_table(p, raw, "imu")
    imu_keys = set(ImuConfig.__dataclass_fields__)
    check_keys(p, imu_t, imu_keys, prefix="imu.")
    imu = ImuConfig(**{k: get_float(p, imu_t, k, prefix="imu.", lo=0.0, hi=1e3) for k in imu_t})
    for k in ("raw_accel_lsb_mps2", "raw_gyro_lsb_radps"):
        if getattr(imu, k) <= 0.0:
            raise ConfigError(p, f"imu.{k}", "must be > 0")
    att = get_table(p, raw, "attitude")
    check_keys(p, att, {"angle_sigma_rad"}, prefix="attitude.")
    lp = get_table(p, raw, "local_position")
    check_keys(p, lp, {"velocity_sigma_mps", "position_sigma_m"}, prefix="local_position.")
    ctl = get_table(p, raw, "controller")
    check_keys(p, ctl, set(ControllerGains.__dataclass_fields__), prefix="controller.")
    gains = ControllerGains(
        **{k: get_float(p, ctl, k, prefix="controller.", lo=0.0, hi=1e4, lo_open=True) for k in ctl}
    )
    sysid = get_float(p, raw, "sysid", default=1.0, lo=1.0, hi=255.0)
    compid = get_float(p, raw, "compid", default=1.0, lo=1.0, hi=255.0)
    if sysid != int(sysid) or compid != int(compid):
        raise ConfigError(p, "sysid", "sysid and compid must be integers")
    d = SensorConfig()
    return SitlConfig(
        dt_s=get_float(p, raw, "dt_s", default=1e-3, lo=1e-6, hi=0.01),
        control_rate_hz=get_float(p, raw, "control_rate_hz", default=250.0, lo=10.0, hi=10000.0),
        sysid=int(sysid),
        compid=int(compid),
        home_lat_deg=get_float(p, home, "lat_deg", prefix="home.", default=47.5867, lo=-90, hi=90),
        home_lon_deg=get_float(p, home, "lon_deg", prefix="home.", default=7.5654, lo=-180, hi=180),
        home_alt_m=get_float(p, home, "alt_m", prefix="home.", default=260.0, lo=-500, hi=1e4),
        start_unix_s=get_float(p, raw, "start_unix_s", default=1.7e9, lo=0.0, hi=4e9),
        rates_hz=_rates(p, get_table(p, raw, "rates_hz"), "rates_hz."),
        sensors=SensorConfig(
            imu=imu,
            attitude_sigma_rad=get_float(
                p,
                att,
                "angle_sigma_rad",
                prefix="attitude.",
                default=d.attitude_sigma_rad,
                lo=0.0,
                hi=1.0,
            ),
            velocity_sigma_mps=get_float(
                p,
                lp,
                "velocity_sigma_mps",
                prefix="local_position.",
                default=d.velocity_sigma_mps,
                lo=0.0,
                hi=10.0,
            ),
            position_sigma_m=get_float(
                p,
                lp,
                "position_sigma_m",
                prefix="local_position.",
                default=d.position_sigma_m,
                lo=0.0,
                hi=100.0,
            ),
        ),
        gains=gains,
        autopilot=_autopilot(p, get_table(p, raw, "autopilot")),
    )


def _autopilot(p: Path, t: dict[str, Any]) -> AutopilotProfileConfig:
    """The ``[autopilot]`` table: every key optional (defaults above), bounds checked."""
    pre = "autopilot."
    d = AutopilotProfileConfig()
    vec_keys = {
        "vibration_harmonics",
        "vibration_harmonic_weights",
        "vibration_accel_mps2",
        "vibration_gyro_radps",
    }
    check_keys(p, t, set(AutopilotProfileConfig.__dataclass_fields__), prefix=pre)
    kw: dict[str, Any] = {}
    positive = {"imu_rate_hz", "ahrs_rate_hz", "gps_rate_hz", "ahrs_rate_filter_hz"}
    for k, v in t.items():
        if k == "rates_hz":
            kw[k] = _rates(p, get_table(p, t, k, prefix=pre), pre + "rates_hz.")
        elif k in vec_keys:
            three = k.endswith(("mps2", "radps"))  # per axis; the harmonics: any number >= 1
            if not three and v == []:
                raise ConfigError(p, pre + k, "needs at least one entry")
            n = 3 if three or not isinstance(v, list) else len(v)
            kw[k] = get_vec(p, t, k, n, prefix=pre, lo=0.0, hi=1e3)
        else:
            kw[k] = get_float(p, t, k, prefix=pre, lo=0.0, hi=1e5, lo_open=k in positive)
    cfg = replace(d, **kw)
    if len(cfg.vibration_harmonics) != len(cfg.vibration_harmonic_weights):
        raise ConfigError(
            p, pre + "vibration_harmonic_weights", "needs one weight per vibration_harmonics entry"
        )
    filt = filter_delay_s(cfg)
    if cfg.velocity_lag_s < filt:
        raise ConfigError(
            p,
            pre + "velocity_lag_s",
            f"{cfg.velocity_lag_s} s is below the filter's own delay {filt:.4f} s "
            "(velocity_filter_tau_s at gps_rate_hz)",
        )
    return cfg


def filter_delay_s(cfg: AutopilotProfileConfig) -> float:
    """Low-frequency delay of the first-order GPS filter sampled at ``gps_rate_hz``.

    ``y_k = y_{k-1} + a (x_k - y_{k-1})``, ``a = 1 - exp(-T/tau)``, weights ``a (1-a)^j``
    on ``x_{k-j}``: mean delay ``(1-a)/a T`` (``tau`` when ``T << tau``).
    """
    period_s = 1.0 / cfg.gps_rate_hz
    if cfg.velocity_filter_tau_s <= 0.0:
        return 0.0
    a = 1.0 - math.exp(-period_s / cfg.velocity_filter_tau_s)
    return (1.0 - a) / a * period_s


def _pair(path: str | Path, t: dict[str, Any], key: str, prefix: str) -> tuple[float, float] | None:
    """``"trim"`` -> None, else a pair of numbers."""
    v = t.get(key, "trim")
    if v == "trim":
        return None
    a, b = get_vec(path, t, key, 2, prefix=prefix, lo=0.0, hi=10000.0)
    return (a, b)


def _v3(
    path: str | Path,
    t: dict[str, Any],
    key: str,
    prefix: str,
    default: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[float, float, float]:
    a, b, c = get_vec(path, t, key, 3, prefix=prefix, default=default)
    return (a, b, c)


def scenario_from_dict(raw: dict[str, Any], path: str | Path) -> Scenario:
    p = path
    check_keys(
        p,
        raw,
        {
            "name",
            "description",
            "duration_s",
            "dt_s",
            "control",
            "initial",
            "open_loop",
            "setpoints",
            "wind",
            "sensors",
            "rates_hz",
            "faults",
            "sensor_profile",
        },
    )
    init = get_table(p, raw, "initial")
    check_keys(
        p,
        init,
        {
            "position_ned_m",
            "velocity_body_mps",
            "euler_rad",
            "omega_body_radps",
            "rotor_radps",
            "swash_rad",
        },
        prefix="initial.",
    )
    ol = get_table(p, raw, "open_loop")
    check_keys(p, ol, {"rotor_radps", "swash_rad"}, prefix="open_loop.")
    control = get_str(
        p, raw, "control", default="closed_loop", choices=("closed_loop", "open_loop")
    )
    sps_raw = raw.get("setpoints", [])
    if not isinstance(sps_raw, list):
        raise ConfigError(p, "setpoints", "expected an array of tables [[setpoints]]")
    setpoints = []
    sp_keys = {
        "t_s",
        "kind",
        "position_ned_m",
        "velocity_ned_mps",
        "yaw_rad",
        "speed_mps",
        "turn_rate_radps",
        "climb_rate_mps",
    }
    for i, sp in enumerate(sps_raw):
        pre = f"setpoints[{i}]."
        if not isinstance(sp, dict):
            raise ConfigError(p, pre[:-1], "expected a table")
        check_keys(p, sp, sp_keys, prefix=pre)
        kind = get_str(
            p, sp, "kind", prefix=pre, choices=("position", "velocity", "turn", "hold", "idle")
        )
        pos = _v3(p, sp, "position_ned_m", pre) if "position_ned_m" in sp else None
        if kind == "position" and pos is None:
            raise ConfigError(p, pre + "position_ned_m", "required for kind = 'position'")
        yaw = (
            get_float(p, sp, "yaw_rad", prefix=pre, lo=-10.0, hi=10.0) if "yaw_rad" in sp else None
        )
        setpoints.append(
            Setpoint(
                t_s=get_float(p, sp, "t_s", prefix=pre, lo=0.0),
                kind=kind,
                position_ned_m=pos,
                velocity_ned_mps=_v3(p, sp, "velocity_ned_mps", pre),
                yaw_rad=yaw,
                speed_mps=get_float(p, sp, "speed_mps", prefix=pre, default=0.0, lo=0.0, hi=50.0),
                turn_rate_radps=get_float(
                    p, sp, "turn_rate_radps", prefix=pre, default=0.0, lo=-5.0, hi=5.0
                ),
                climb_rate_mps=get_float(
                    p, sp, "climb_rate_mps", prefix=pre, default=0.0, lo=-10.0, hi=10.0
                ),
            )
        )
    setpoints.sort(key=lambda s: s.t_s)
    if control == "closed_loop" and not setpoints:
        setpoints = [Setpoint(0.0, "hold")]
    wind_t = get_table(p, raw, "wind")
    check_keys(p, wind_t, {"constant_ned_mps", "gusts", "turbulence"}, prefix="wind.")
    gusts = []
    g_raw = wind_t.get("gusts", [])
    if not isinstance(g_raw, list):
        raise ConfigError(p, "wind.gusts", "expected an array of tables [[wind.gusts]]")
    for i, g in enumerate(g_raw):
        pre = f"wind.gusts[{i}]."
        if not isinstance(g, dict):
            raise ConfigError(p, pre[:-1], "expected a table")
        check_keys(p, g, {"t_start_s", "duration_s", "amplitude_ned_mps"}, prefix=pre)
        gusts.append(
            Gust(
                get_float(p, g, "t_start_s", prefix=pre, lo=0.0),
                get_float(p, g, "duration_s", prefix=pre, lo=0.0, lo_open=True),
                _v3(p, g, "amplitude_ned_mps", pre),
            )
        )
    turb = get_table(p, wind_t, "turbulence", prefix="wind.")
    check_keys(p, turb, {"sigma_mps", "time_constant_s"}, prefix="wind.turbulence.")
    ts = turb.get("sigma_mps", 0.0)
    if isinstance(ts, list):
        sig = _v3(p, turb, "sigma_mps", "wind.turbulence.")
    else:
        s = get_float(p, turb, "sigma_mps", prefix="wind.turbulence.", default=0.0, lo=0.0, hi=20.0)
        sig = (s, s, s)
    wind = WindConfig(
        constant_ned_mps=_v3(p, wind_t, "constant_ned_mps", "wind."),
        gusts=tuple(gusts),
        turbulence_sigma_mps=sig,
        turbulence_time_constant_s=get_float(
            p, turb, "time_constant_s", prefix="wind.turbulence.", default=1.0, lo=1e-3, hi=1e3
        ),
    )
    sens = get_table(p, raw, "sensors")
    check_keys(p, sens, {"noise", "bias", "noise_scale", "bias_scale"}, prefix="sensors.")
    sensors: dict[str, Any] = {
        "noise": get_bool(p, sens, "noise", prefix="sensors.", default=True),
        "bias": get_bool(p, sens, "bias", prefix="sensors.", default=True),
        "noise_scale": get_float(
            p, sens, "noise_scale", prefix="sensors.", default=1.0, lo=0.0, hi=100.0
        ),
        "bias_scale": get_float(
            p, sens, "bias_scale", prefix="sensors.", default=1.0, lo=0.0, hi=100.0
        ),
    }
    f_raw = raw.get("faults", [])
    if not isinstance(f_raw, list):
        raise ConfigError(p, "faults", "expected an array of tables [[faults]]")
    faults = []
    for i, fr in enumerate(f_raw):
        pre = f"faults[{i}]."
        if not isinstance(fr, dict):
            raise ConfigError(p, pre[:-1], "expected a table")
        check_keys(
            p,
            fr,
            {"sensor", "axis", "kind", "t_start_s", "t_end_s", "magnitude", "vector"},
            prefix=pre,
        )
        kind = get_str(
            p, fr, "kind", prefix=pre, choices=("dropout", "freeze", "bias", "noise", "accel_bias")
        )
        sensor = get_str(
            p,
            fr,
            "sensor",
            prefix=pre,
            default="accel" if kind == "accel_bias" else "velocity",
            choices=("velocity", "accel"),
        )
        t0 = get_float(p, fr, "t_start_s", prefix=pre, lo=0.0)
        t1 = (
            get_float(p, fr, "t_end_s", prefix=pre, default=float("inf"), lo=t0)
            if "t_end_s" in fr
            else float("inf")
        )
        if sensor == "velocity":
            if kind == "accel_bias":
                raise ConfigError(p, pre + "kind", "accel_bias applies to sensor = 'accel'")
            axis = get_str(p, fr, "axis", prefix=pre, choices=("n", "e", "d"))
            faults.append(
                Fault(
                    sensor,
                    kind,
                    t0,
                    t1,
                    axis=axis,
                    magnitude=get_float(
                        p, fr, "magnitude", prefix=pre, default=0.0, lo=-100.0, hi=100.0
                    ),
                )
            )
        else:
            if kind not in ("accel_bias", "bias"):
                raise ConfigError(p, pre + "kind", "the accelerometer supports kind = 'accel_bias'")
            faults.append(Fault("accel", "accel_bias", t0, t1, vector=_v3(p, fr, "vector", pre)))
    ip = init
    return Scenario(
        name=get_str(p, raw, "name", default=Path(p).stem),
        description=get_str(p, raw, "description", default=""),
        duration_s=get_float(p, raw, "duration_s", default=60.0, lo=0.0, hi=1e6, lo_open=True),
        dt_s=get_float(p, raw, "dt_s", lo=1e-6, hi=0.01) if "dt_s" in raw else None,
        control=control,
        position_ned_m=_v3(p, ip, "position_ned_m", "initial.", (0.0, 0.0, -10.0)),
        velocity_body_mps=_v3(p, ip, "velocity_body_mps", "initial."),
        euler_rad=_v3(p, ip, "euler_rad", "initial."),
        omega_body_radps=_v3(p, ip, "omega_body_radps", "initial."),
        rotor_radps=_pair(p, ip, "rotor_radps", "initial."),
        swash_rad=_swash(p, ip, "swash_rad", "initial."),
        open_loop_rotor_radps=_pair(p, ol, "rotor_radps", "open_loop."),
        open_loop_swash_rad=_swash(p, ol, "swash_rad", "open_loop."),
        setpoints=tuple(setpoints),
        wind=wind,
        sensors=sensors,
        rates_hz=_rates(p, get_table(p, raw, "rates_hz"), "rates_hz."),
        faults=tuple(faults),
        source=str(p),
        sensor_profile=get_str(p, raw, "sensor_profile", default="ideal", choices=SENSOR_PROFILES),
    )


def _swash(path: str | Path, t: dict[str, Any], key: str, prefix: str) -> tuple[float, float]:
    a, b = get_vec(path, t, key, 2, prefix=prefix, default=(0.0, 0.0), lo=-1.0, hi=1.0)
    return (a, b)


def scenario_names() -> list[str]:
    """Names of the scenarios shipped with the package."""
    return sorted(p.stem for p in data_path("scenarios").glob("*.toml"))


def resolve_scenario_path(name_or_path: str) -> Path:
    """A scenario name (``hover``) -> the packaged file; anything with a suffix or slash is a path."""
    if name_or_path.endswith(".toml") or "/" in name_or_path:
        return Path(name_or_path)
    p = data_path("scenarios", f"{name_or_path}.toml")
    if not p.is_file():
        raise ConfigError(
            p, "", f"unknown scenario {name_or_path!r} (known: {', '.join(scenario_names())})"
        )
    return p


def load_scenario(name_or_path: str | Path) -> Scenario:
    p = resolve_scenario_path(str(name_or_path))
    return scenario_from_dict(load_toml(p), p)


def effective_sensor_config(sitl: SitlConfig, sc: Scenario) -> SensorConfig:
    """The sitl sensor defaults with the scenario's switches applied."""
    return replace(sitl.sensors, **sc.sensors)


def effective_rates(sitl: SitlConfig, sc: Scenario) -> dict[str, float]:
    """Stream rates in Hz: built-in defaults, then sitl.toml, then (``autopilot`` profile)
    ``[autopilot.rates_hz]``, then the scenario."""
    rates = {
        "heartbeat": 1.0,
        "raw_imu": 250.0,
        "scaled_imu": 250.0,
        "highres_imu": 250.0,
        "attitude": 100.0,
        "local_position_ned": 30.0,
        "sim_state": 50.0,
    }
    rates.update(sitl.rates_hz)
    if sc.sensor_profile == "autopilot":
        rates.update(sitl.autopilot.rates_hz)
    rates.update(sc.rates_hz)
    return rates
