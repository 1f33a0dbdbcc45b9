"""Simulator settings (``sitl.toml``) and scenarios (``scenarios/NAME.toml``), validated.

A scenario names its initial state, how the vehicle is flown (closed loop with
time-tagged setpoints, or open-loop actuator inputs), the wind, the sensor profile
(``ideal`` or ``autopilot``, see :mod:`glmav_sitl.sensors.autopilot`), sensor noise
switches, stream rates and scheduled sensor faults. See ``glmav_sitl/data/scenarios/*.toml``
for commented examples; every key is checked (unknown keys are errors).

About 500 lines, kept together: a scenario overrides the settings' sensor dataclasses, and
both files are read by the same table readers (``_floats``, ``_pair``, ``_v3``, ``_default``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from glmav_sitl.config import data_path
from glmav_sitl.wind import Gust, WindConfig
from glmav_toml import REQUIRED, Check, ConfigError, TableReader, load_toml, one_of, within

# MAVLink streams the simulator emits and their message ids
STREAM_IDS: dict[str, int] = {
    "heartbeat": 0,
    "raw_imu": 27,
    "scaled_imu": 26,
    "highres_imu": 105,
    "attitude": 30,
    "local_position_ned": 32,
    "sim_state": 108,
    "servo_output_raw": 36,
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


def _rates(r: TableReader) -> dict[str, float]:
    """A ``rates_hz`` table: stream name -> Hz (0 = off)."""
    r.expect(STREAM_IDS)
    return {k: r.get(k, float, REQUIRED, within(0.0, 100000.0)) for k in list(r.table)}


def _floats(r: TableReader, default: Any, check: Callable[[str], Check]) -> dict[str, Any]:
    """Every float field of the dataclass instance ``default``, read from ``r`` (absent:
    the field's default) and checked with ``check(field name)``."""
    return {
        f.name: r.get(f.name, float, getattr(default, f.name), check(f.name))
        for f in fields(default)
        if isinstance(getattr(default, f.name), float)
    }


#: [imu] fields that divide: strictly positive
_IMU_POSITIVE = frozenset({"raw_accel_lsb_mps2", "raw_gyro_lsb_radps"})


def load_sitl_config(path: str | Path | None = None) -> SitlConfig:
    """Load ``sitl.toml`` (default: the packaged copy); absent keys take the defaults of
    :class:`SitlConfig` and the classes it holds."""
    p = Path(path) if path is not None else data_path("sitl.toml")
    r = TableReader(p, load_toml(p))
    d = SitlConfig()
    home = r.sub("home")
    home_lat_deg = home.get("lat_deg", float, d.home_lat_deg, within(-90, 90))
    home_lon_deg = home.get("lon_deg", float, d.home_lon_deg, within(-180, 180))
    home_alt_m = home.get("alt_m", float, d.home_alt_m, within(-500, 1e4))
    home.done()
    imu_r = r.sub("imu")
    imu = ImuConfig(
        **_floats(imu_r, d.sensors.imu, lambda k: within(0.0, 1e3, lo_open=k in _IMU_POSITIVE))
    )
    imu_r.done()
    att = r.sub("attitude")
    attitude_sigma_rad = att.get(
        "angle_sigma_rad", float, d.sensors.attitude_sigma_rad, within(0.0, 1.0)
    )
    att.done()
    lp = r.sub("local_position")
    velocity_sigma_mps = lp.get(
        "velocity_sigma_mps", float, d.sensors.velocity_sigma_mps, within(0.0, 10.0)
    )
    position_sigma_m = lp.get(
        "position_sigma_m", float, d.sensors.position_sigma_m, within(0.0, 100.0)
    )
    lp.done()
    ctl = r.sub("controller")
    gains = ControllerGains(**_floats(ctl, d.gains, lambda _: within(0.0, 1e4, lo_open=True)))
    ctl.done()
    cfg = SitlConfig(
        dt_s=r.get("dt_s", float, d.dt_s, within(1e-6, 0.01)),
        control_rate_hz=r.get("control_rate_hz", float, d.control_rate_hz, within(10.0, 1e4)),
        sysid=r.get("sysid", int, d.sysid, within(1, 255)),
        compid=r.get("compid", int, d.compid, within(1, 255)),
        home_lat_deg=home_lat_deg,
        home_lon_deg=home_lon_deg,
        home_alt_m=home_alt_m,
        start_unix_s=r.get("start_unix_s", float, d.start_unix_s, within(0.0, 4e9)),
        rates_hz=_rates(r.sub("rates_hz")),
        sensors=replace(
            d.sensors,
            imu=imu,
            attitude_sigma_rad=attitude_sigma_rad,
            velocity_sigma_mps=velocity_sigma_mps,
            position_sigma_m=position_sigma_m,
        ),
        gains=gains,
        autopilot=_autopilot(r.sub("autopilot")),
    )
    r.done()
    return cfg


#: [autopilot] rates that divide: strictly positive
_AUTOPILOT_POSITIVE = frozenset(
    {"imu_rate_hz", "ahrs_rate_hz", "gps_rate_hz", "ahrs_rate_filter_hz"}
)


def _autopilot(r: TableReader) -> AutopilotProfileConfig:
    """The ``[autopilot]`` table: every key optional (defaults above), bounds checked."""
    d = AutopilotProfileConfig()
    kw = _floats(r, d, lambda k: within(0.0, 1e5, lo_open=k in _AUTOPILOT_POSITIVE))
    for k in ("vibration_harmonics", "vibration_harmonic_weights"):  # any number >= 1
        kw[k] = r.vector(k, None, getattr(d, k), within(0.0, 1e3))
    for k in ("vibration_accel_mps2", "vibration_gyro_radps"):  # per axis
        kw[k] = r.vector(k, 3, getattr(d, k), within(0.0, 1e3))
    kw["rates_hz"] = _rates(r.sub("rates_hz"))
    r.done()
    cfg = AutopilotProfileConfig(**kw)
    if len(cfg.vibration_harmonics) != len(cfg.vibration_harmonic_weights):
        raise r.error(
            "vibration_harmonic_weights", "needs one weight per vibration_harmonics entry"
        )
    filt = filter_delay_s(cfg)
    if cfg.velocity_lag_s < filt:
        raise r.error(
            "velocity_lag_s",
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


def _pair(r: TableReader, key: str) -> tuple[float, float] | None:
    """``"trim"`` (the default) -> None, else a pair of rotor speeds, rad/s."""
    if r.table.get(key, "trim") == "trim":
        r.used.add(key)
        return None
    a, b = r.vector(key, 2, check=within(0.0, 10000.0))
    return (a, b)


def _v3(
    r: TableReader, key: str, default: Any = (0.0, 0.0, 0.0), check: Check | None = None
) -> tuple[float, float, float]:
    a, b, c = r.vector(key, 3, default, check)
    return (a, b, c)


def _swash(r: TableReader, key: str) -> tuple[float, float]:
    a, b = r.vector(key, 2, (0.0, 0.0), within(-1.0, 1.0))
    return (a, b)


def _default(cls: type, name: str) -> Any:
    """The declared default of field ``name`` of dataclass ``cls``."""
    return {f.name: f.default for f in fields(cls)}[name]


_SETPOINT_KINDS = ("position", "velocity", "turn", "hold", "idle")
_FAULT_KINDS = ("dropout", "freeze", "bias", "noise", "accel_bias")
#: a time from the start of the run, s
_TIME_S = within(0.0, math.inf)


def _setpoint(sp: TableReader) -> Setpoint:
    kind = sp.get("kind", str, REQUIRED, one_of(*_SETPOINT_KINDS))
    pos = _v3(sp, "position_ned_m") if sp.has("position_ned_m") else None
    sp.used.add("position_ned_m")
    if kind == "position" and pos is None:
        raise sp.error("position_ned_m", "required for kind = 'position'")
    out = Setpoint(
        t_s=sp.get("t_s", float, REQUIRED, _TIME_S),
        kind=kind,
        position_ned_m=pos,
        velocity_ned_mps=_v3(sp, "velocity_ned_mps", _default(Setpoint, "velocity_ned_mps")),
        yaw_rad=sp.get("yaw_rad", float, None, within(-10.0, 10.0)),
        speed_mps=sp.get("speed_mps", float, _default(Setpoint, "speed_mps"), within(0.0, 50.0)),
        turn_rate_radps=sp.get(
            "turn_rate_radps", float, _default(Setpoint, "turn_rate_radps"), within(-5.0, 5.0)
        ),
        climb_rate_mps=sp.get(
            "climb_rate_mps", float, _default(Setpoint, "climb_rate_mps"), within(-10.0, 10.0)
        ),
    )
    sp.done()
    return out


def _wind(w: TableReader) -> WindConfig:
    d = WindConfig()
    gusts = []
    for g in w.tables("gusts"):
        gusts.append(
            Gust(
                g.get("t_start_s", float, REQUIRED, _TIME_S),
                g.get("duration_s", float, REQUIRED, within(0.0, math.inf, lo_open=True)),
                _v3(g, "amplitude_ned_mps"),
            )
        )
        g.done()
    turb = w.sub("turbulence")
    if isinstance(turb.table.get("sigma_mps"), list):  # per axis
        sigma = _v3(turb, "sigma_mps", check=within(0.0, 20.0))
    else:  # the same on every axis
        s = turb.get("sigma_mps", float, d.turbulence_sigma_mps[0], within(0.0, 20.0))
        sigma = (s, s, s)
    wind = WindConfig(
        constant_ned_mps=_v3(w, "constant_ned_mps", d.constant_ned_mps),
        gusts=tuple(gusts),
        turbulence_sigma_mps=sigma,
        turbulence_time_constant_s=turb.get(
            "time_constant_s", float, d.turbulence_time_constant_s, within(1e-3, 1e3)
        ),
    )
    turb.done()
    w.done()
    return wind


def _fault(fr: TableReader) -> Fault:
    kind = fr.get("kind", str, REQUIRED, one_of(*_FAULT_KINDS))
    sensor = fr.get(
        "sensor",
        str,
        "accel" if kind == "accel_bias" else "velocity",
        one_of("velocity", "accel"),
    )
    t0 = fr.get("t_start_s", float, REQUIRED, _TIME_S)
    t1 = fr.get("t_end_s", float, math.inf, within(t0, math.inf))
    if sensor == "velocity":
        if kind == "accel_bias":
            raise fr.error("kind", "accel_bias applies to sensor = 'accel'")
        fault = Fault(
            sensor,
            kind,
            t0,
            t1,
            axis=fr.get("axis", str, REQUIRED, one_of("n", "e", "d")),
            magnitude=fr.get(
                "magnitude", float, _default(Fault, "magnitude"), within(-100.0, 100.0)
            ),
        )
    else:
        if kind not in ("accel_bias", "bias"):
            raise fr.error("kind", "the accelerometer supports kind = 'accel_bias'")
        fault = Fault("accel", "accel_bias", t0, t1, vector=_v3(fr, "vector"))
    fr.done()
    return fault


def scenario_from_dict(raw: dict[str, Any], path: str | Path) -> Scenario:
    """Validate a parsed scenario file; absent keys take their documented defaults."""
    r = TableReader(path, raw)
    control = r.get("control", str, "closed_loop", one_of("closed_loop", "open_loop"))
    setpoints = sorted((_setpoint(sp) for sp in r.tables("setpoints")), key=lambda s: s.t_s)
    if control == "closed_loop" and not setpoints:
        setpoints = [Setpoint(0.0, "hold")]
    sens = r.sub("sensors")
    sd = SensorConfig()
    sensors: dict[str, Any] = {
        "noise": sens.get("noise", bool, sd.noise),
        "bias": sens.get("bias", bool, sd.bias),
        "noise_scale": sens.get("noise_scale", float, sd.noise_scale, within(0.0, 100.0)),
        "bias_scale": sens.get("bias_scale", float, sd.bias_scale, within(0.0, 100.0)),
    }
    sens.done()
    ip = r.sub("initial")
    ol = r.sub("open_loop")
    scenario = Scenario(
        name=r.get("name", str, Path(path).stem),
        description=r.get("description", str, ""),
        duration_s=r.get("duration_s", float, 60.0, within(0.0, 1e6, lo_open=True)),
        dt_s=r.get("dt_s", float, None, within(1e-6, 0.01)),
        control=control,
        position_ned_m=_v3(ip, "position_ned_m", (0.0, 0.0, -10.0)),
        velocity_body_mps=_v3(ip, "velocity_body_mps"),
        euler_rad=_v3(ip, "euler_rad"),
        omega_body_radps=_v3(ip, "omega_body_radps"),
        rotor_radps=_pair(ip, "rotor_radps"),
        swash_rad=_swash(ip, "swash_rad"),
        open_loop_rotor_radps=_pair(ol, "rotor_radps"),
        open_loop_swash_rad=_swash(ol, "swash_rad"),
        setpoints=tuple(setpoints),
        wind=_wind(r.sub("wind")),
        sensors=sensors,
        rates_hz=_rates(r.sub("rates_hz")),
        faults=tuple(_fault(fr) for fr in r.tables("faults")),
        source=str(path),
        sensor_profile=r.get("sensor_profile", str, "ideal", one_of(*SENSOR_PROFILES)),
    )
    for t in (ip, ol, r):
        t.done()
    return scenario


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
        "servo_output_raw": 50.0,
    }
    rates.update(sitl.rates_hz)
    if sc.sensor_profile == "autopilot":
        rates.update(sitl.autopilot.rates_hz)
    rates.update(sc.rates_hz)
    return rates
