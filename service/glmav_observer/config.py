"""``configs/service.toml``: loading and validation of the service's settings.

Every setting has a default (the values in ``configs/service.toml``, where each one is
documented); a file overrides some of them. Keys are read and checked the way the
simulator reads its files (:mod:`glmav_toml`): a bad file raises
:class:`~glmav_toml.ConfigError` naming the file, the key (dotted) and the reason; the
commands turn it into exit code 2. Unknown keys are errors too (a typo must not silently
fall back to a default).

One concept, a little over 500 lines: every section of the file is declared where it is
read, with its checks beside it, so the settings and their reading stay in one place.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args

from glmav_observer.configurations import DEFAULT_GAMMA
from glmav_observer.estimation import EForm
from glmav_observer.estimation.aero.control import ControlMapping
from glmav_observer.estimation.fdi_types import DespikeConfig, FdiConfig
from glmav_observer.estimation.gps_bridge import GpsBridgeConfig
from glmav_observer.estimation.imu_monitor import ImuMonitorConfig
from glmav_observer.estimation.vehicle import EstimatorConfig
from glmav_observer.ingest.clock import ClockConfig
from glmav_observer.ingest.convert import RawImuScale
from glmav_observer.ingest.links import DEFAULT_UDP_RECEIVE_BUFFER_BYTES
from glmav_observer.ingest.pipeline import IngestConfig
from glmav_observer.ingest.rates import MESSAGE_IDS
from glmav_observer.publish.mavlink_out_settings import GCS_COMPONENT_IDS, MavlinkOutSettings
from glmav_observer.publish.schema import (
    DEFAULT_DECIMATION,
    DEFAULT_ENCODING,
    DEFAULT_PREFIX,
    KINDS,
    decimation_reason,
    encoding_reason,
)
from glmav_observer.reads import (
    EVERY,
    LIVE_DEFAULT_RATES_HZ,
    READS_ALL,
    STREAMS,
    Reads,
    rate_reason,
)
from glmav_toml import Check, ConfigError, TableReader, load_toml, one_of, read_limited, within

#: The rates the estimator needs (``[rates.min_hz]``): a stream below is asked for.
#: IMU: the FDI's ``min_imu_rate_hz`` (its residual tests need it); ATTITUDE: 10 Hz (the
#: rate MAVSDK's ``set_rate_attitude_euler`` users pick; the attitude is held between
#: samples); LOCAL_POSITION_NED: 5 Hz (the FDI's tests count samples within 0.3-0.6 s);
#: SIM_STATE: truth only, never needed.
DEFAULT_MIN_RATES_HZ: dict[str, float] = {
    "ATTITUDE": 10.0,
    "HIGHRES_IMU": 50.0,
    "LOCAL_POSITION_NED": 5.0,
    "SIM_STATE": 0.0,
}

#: Upper bound of ``[ingest] reorder_window_s`` (s of vehicle time).
MAX_REORDER_WINDOW_S = 1.0

#: Requested stream rates when ``[rates.hz]`` is absent (design.md's SITL rates).
DEFAULT_RATES_HZ: dict[str, float] = {
    "ATTITUDE": 100.0,
    "HIGHRES_IMU": 250.0,
    "LOCAL_POSITION_NED": 30.0,
    "SIM_STATE": 50.0,
    "EKF_STATUS_REPORT": 2.0,  # ArduPilot: is the velocity aided?
    "GPS_RAW_INT": 5.0,  # fix type: a GPS loss makes the autopilot's velocity unaided
}


@dataclass(frozen=True, slots=True)
class ZenohSettings:
    #: ``serve`` publishes on Zenoh unless told not to (the embedded loopback peer needs
    #: no router); ``replay`` and ``batch`` only when asked
    enabled: bool = True
    config: str = ""
    prefix: str = DEFAULT_PREFIX
    decimation: Mapping[str, int] = field(default_factory=lambda: dict(DEFAULT_DECIMATION))
    encoding: str = DEFAULT_ENCODING  # publish/schema.py ENCODINGS: "json" | "msgpack"
    #: per record stream, the rate published (Hz of vehicle time; glmav_observer.reads)
    rates_hz: Mapping[str, float] = field(default_factory=lambda: dict(LIVE_DEFAULT_RATES_HZ))
    #: every record of every stream, whatever ``rates_hz`` says (``serve --full-rate``)
    full_rate: bool = False

    def reads(self) -> Reads:
        """What the Zenoh sink reads (and so what the estimators build for it)."""
        return READS_ALL if self.full_rate else Reads(self.rates_hz)


@dataclass(frozen=True, slots=True)
class RerunSettings:
    mode: str = "off"
    decimation: int = 1
    serve_bind: str = "127.0.0.1"


@dataclass(frozen=True, slots=True)
class ServiceConfig:
    """Everything the service needs; build with :func:`load_config`."""

    service_id: str = "glmav-observer"
    links: tuple[str, ...] = ()
    out: str = ""
    udp_receive_buffer_bytes: int = DEFAULT_UDP_RECEIVE_BUFFER_BYTES
    request_rates: bool = True
    ingest: IngestConfig = field(default_factory=IngestConfig)
    estimation: EstimatorConfig = field(default_factory=EstimatorConfig)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    rerun: RerunSettings = field(default_factory=RerunSettings)
    mavlink_out: MavlinkOutSettings = field(default_factory=MavlinkOutSettings)
    signing_key: bytes | None = field(default=None, repr=False)  # MAVLink 2 signing
    #: where signing timestamps persist across restarts (None: in memory only)
    signing_state_file: str | None = None
    source: str = "<defaults>"

    def effective(self) -> dict[str, Any]:
        """The effective configuration as plain JSON-able data (served by the Zenoh sink)."""

        def plain(x: Any) -> Any:
            if dataclasses.is_dataclass(x) and not isinstance(x, type):
                return {f.name: plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
            if isinstance(x, Mapping):
                return {str(k): plain(v) for k, v in x.items()}
            if isinstance(x, tuple | list):
                return [plain(v) for v in x]
            if x == EVERY:  # a read rate (glmav_observer.reads): JSON has no infinity
                return "every"
            return x

        out: dict[str, Any] = plain(self)
        out["signing_key"] = "<set>" if self.signing_key is not None else None  # never the key
        return out


# ---------------------------------------------------------------------- checks
def _ip_address(x: Any) -> str | None:
    import ipaddress

    try:
        ipaddress.ip_address(x)
    except ValueError:
        return "must be an IP address (e.g. 127.0.0.1; 0.0.0.0 listens on every interface)"
    return None


_ID_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_.")


def _name(x: Any) -> str | None:
    """A service id or key segment: 1..64 of [A-Za-z0-9._-] (a Zenoh key chunk)."""
    if not 1 <= len(x) <= 64 or not set(x) <= _ID_CHARS:
        return "must be 1 to 64 characters from A-Z a-z 0-9 . _ -"
    return None


def _key_prefix(x: Any) -> str | None:
    """A Zenoh key prefix: chunks of :func:`_name` separated by '/'."""
    if not x or len(x) > 200 or any(_name(c) for c in x.split("/")):
        return "must be '/'-separated chunks of A-Z a-z 0-9 . _ - (no wildcards, no empty chunk)"
    return None


#: Ranges of the settings read generically (by field name; see configs/service.toml).
#: Upper bounds are far above any useful value, below what exhausts memory or time.
_BOUNDS: dict[str, Check] = {
    # [ingest] clock
    "latency_window_s": within(0.0, 1.0),
    "reset_backwards_s": within(0.0, 3600.0, lo_open=True),
    "jump_forward_s": within(0.0, 3600.0, lo_open=True),
    "gap_s": within(0.0, 60.0, lo_open=True),
    "confirm_samples": within(1, 1000),
    "confirm_forward_s": within(0.0, 3600.0, lo_open=True),
    "conflict_samples": within(1, 100_000),
    "conflict_window_s": within(0.0, 600.0, lo_open=True),
    # [ingest.raw_imu]
    "accel_mps2_per_lsb": within(0.0, 1.0, lo_open=True),
    "gyro_radps_per_lsb": within(0.0, 1.0, lo_open=True),
    # [estimation]
    "g_mps2": within(9.7, 9.9),
    "health_rate_hz": within(0.0, 1000.0, lo_open=True),
    "max_gap_s": within(0.0, 60.0, lo_open=True),
    "imu_filter_hz": within(0.0, 1000.0),
    "handover_contamination_mps": within(0.0, 100.0, lo_open=True),
    "metrics_skip_s": within(0.0, 3600.0),
    "gamma_full_min": within(0.0, 1000.0, lo_open=True),
    "gamma_full_max": within(0.0, 1000.0, lo_open=True),
    "aero_prior_k_per_s": within(0.0, 10.0),
    "aero_prior_k_sigma_per_s": within(0.0, 10.0, lo_open=True),
    # [estimation.aero_control]: SERVO_OUTPUT_RAW channel map (estimation/aero/control.py)
    "omega2_channel": within(1, 16),
    "dcx_channel": within(1, 16),
    "dcy_channel": within(1, 16),
    "omega2_pwm_zero_us": within(0.0, 65535.0),
    "dcx_pwm_zero_us": within(0.0, 65535.0),
    "dcy_pwm_zero_us": within(0.0, 65535.0),
    "omega2_radps_per_us": within(-100.0, 100.0),
    "dcx_rad_per_us": within(-0.1, 0.1),
    "dcy_rad_per_us": within(-0.1, 0.1),
    "max_age_s": within(0.0, 10.0, lo_open=True),
    "readmit_follow_s": within(0.0, 60.0),
    # [estimation.gps_bridge] (estimation/gps_bridge.py)
    "sigma_v_mps": within(0.0, 10.0, lo_open=True),
    "lag_prior_s": within(0.0, 2.0),
    "lag_max_s": within(0.0, 2.0, lo_open=True),
    "lag_step_s": within(0.001, 0.5),
    "learn_interval_s": within(0.0, 3600.0),
    "lag_memory_s": within(0.0, 86_400.0, lo_open=True),
    "lag_min_samples": within(1, 100_000),
    "excite_sigma": within(0.0, 1000.0),
    "trust_sigma": within(0.0, 1000.0, lo_open=True),
    "max_rejects": within(1, 10_000),
    "start_sigma": within(0.0, 1000.0, lo_open=True),
    # (sigma_floor_mps: as [fdi]'s)
    "blend_s": within(0.0, 600.0),
    "max_s": within(0.0, 3600.0, lo_open=True),
    "gps_timeout_s": within(0.0, 60.0, lo_open=True),
    # [fdi]
    "sigma_meas_mps": within(0.0, 10.0, lo_open=True),
    "vet_delay_s": within(0.0, 60.0, lo_open=True),
    "bias_window_s": within(0.0, 600.0, lo_open=True),
    "warmup_s": within(1.0, 600.0),
    "gate_sigma": within(0.0, 100.0, lo_open=True),
    "dropout_samples": within(1, 10_000),
    "missing_timeout_s": within(0.0, 60.0, lo_open=True),
    "freeze_repeats": within(1, 10_000),
    "bias_samples": within(1, 10_000),
    "bias_threshold_mps": within(0.0, 100.0, lo_open=True),
    "noise_samples": within(1, 10_000),
    "noise_ratio_threshold": within(0.0, 1e6, lo_open=True),
    "k_isolate": within(1, 10_000),
    "recovery_s": within(0.0, 3600.0, lo_open=True),
    "sigma_handover_mps": within(0.0, 100.0, lo_open=True),
    "sigma_velocity_mps": within(0.0, 100.0, lo_open=True),
    "sigma_bias_mps2": within(0.0, 100.0),
    "accel_noise_density": within(0.0, 10.0),
    "min_imu_rate_hz": within(0.0, 10_000.0, lo_open=True),
    "sigma_floor_mps": within(0.0, 10.0, lo_open=True),
    "scale_samples": within(1, 100_000),
    "bias_sigma": within(0.0, 100.0, lo_open=True),
    "freeze_motion_mps": within(0.0, 100.0),
    "freeze_repeat_rate": within(0.0, 1.0),
    "prior_bias_mps2": within(0.0, 100.0, lo_open=True),
    "prior_yaw_rad": within(0.0, 3.2, lo_open=True),
    "prior_lag_s": within(0.0, 2.0, lo_open=True),
    "max_lag_s": within(0.0, 5.0),
    "correlation_samples": within(1.0, 1000.0),
    "max_bias_mps2": within(0.0, 100.0, lo_open=True),
    "change_window_s": within(0.0, 600.0, lo_open=True),
    # a measurement later than 1 mean interval is not yet overdue: the bound keeps a
    # steady stream's jitter from flagging every record
    "overdue_intervals": within(1.0, 1000.0),
    # [fdi.imu] (estimation/imu_monitor.py)
    "window_s": within(0.0, 60.0, lo_open=True),
    "floor_mps2": within(0.0, 10_000.0, lo_open=True),  # (also [fdi.despike])
    "k_sigma": within(0.0, 100.0, lo_open=True),  # (also [fdi.despike])
    "baseline_tau_s": within(0.0, 86_400.0, lo_open=True),
    "resolve_timeout_s": within(0.0, 600.0),
    "min_samples": within(2, 100_000),
    "min_fill": within(0.0, 1.0, lo_open=True),
    "end_fraction": within(0.0, 1.0, lo_open=True),
    # [fdi.despike] (estimation/despike.py)
    "tau_samples": within(1, 1_000_000),
}


def _bounded(name: str) -> Check:
    """The range of a generically read field; a field without one is a programming error."""
    try:
        return _BOUNDS[name]
    except KeyError:
        raise KeyError(f"configuration field {name!r} has no range in config._BOUNDS") from None


def _fields_from(r: TableReader, default: Any) -> dict[str, Any]:
    """Every int/float/bool field of a frozen dataclass, read from ``r`` with its default
    and checked against its range in ``_BOUNDS``."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(default):
        v = getattr(default, f.name)
        if isinstance(v, bool):
            out[f.name] = r.get(f.name, bool, v)
        elif isinstance(v, int):
            out[f.name] = r.get(f.name, int, v, _bounded(f.name))
        elif isinstance(v, float):
            out[f.name] = r.get(f.name, float, v, _bounded(f.name))
    return out


def parse_config(data: Mapping[str, Any], file: str = "<config>") -> ServiceConfig:
    """Validate a parsed TOML document (see ``configs/service.toml``)."""
    root = TableReader(file, data, "")
    d = ServiceConfig()  # every default below comes from the dataclasses, never a literal
    # [service]
    svc = root.sub("service")
    service_id = svc.get("id", str, d.service_id, _name)
    links_raw = svc.get("links", list, list(d.links))
    for i, link in enumerate(links_raw):
        if not isinstance(link, str) or not link:
            raise ConfigError(file, f"service.links[{i}]", "expected a connection string")
    out = svc.get("out", str, d.out)
    if out and not out.endswith((".csv", ".jsonl")):
        raise ConfigError(file, "service.out", f"must end in .csv or .jsonl, got {out!r}")
    rcvbuf = svc.get(
        "udp_receive_buffer_bytes", int, d.udp_receive_buffer_bytes, within(4096, 1 << 30)
    )  # a C int for setsockopt; 1 GiB is beyond any net.core.rmem_max
    svc.done()
    # [ingest]
    ing = root.sub("ingest")
    base = IngestConfig()
    max_vehicles = ing.get("max_vehicles", int, base.max_vehicles, within(1, 254))
    evict_idle_s = ing.get("evict_idle_s", float, base.evict_idle_s, within(0, 3600, lo_open=True))
    imu_fallback_s = ing.get(
        "imu_fallback_s", float, base.imu_fallback_s, within(0, 60, lo_open=True)
    )
    # held samples grow with the window: 1 s holds ~400 samples a vehicle, and no radio
    # that reorders by more is usable for estimation anyway
    reorder_window_s = ing.get(
        "reorder_window_s", float, base.reorder_window_s, within(0.0, MAX_REORDER_WINDOW_S)
    )
    clock = ClockConfig(**_fields_from(ing, ClockConfig()))
    raw = ing.sub("raw_imu")
    raw_default = RawImuScale(**_fields_from(raw, RawImuScale()))
    by_sysid: dict[int, RawImuScale] = {}
    per = raw.sub("sysid")
    for key in list(per.table):
        try:
            sysid = int(key)
        except ValueError:
            raise ConfigError(file, f"ingest.raw_imu.sysid.{key}", "not a system id") from None
        if not 1 <= sysid <= 255:
            raise ConfigError(file, f"ingest.raw_imu.sysid.{key}", "system id must be 1..255")
        sub = per.sub(key)
        by_sysid[sysid] = RawImuScale(**_fields_from(sub, raw_default))
        sub.done()
    per.done()
    raw.done()
    ing.done()
    # [rates]
    rates = root.sub("rates")
    rate_mode = rates.get(
        "mode", str, "request" if d.request_rates else "observe", one_of("request", "observe")
    )
    request_rates = rate_mode == "request"
    window_s = rates.get("window_s", float, base.rate_window_s, within(0, 60, lo_open=True))
    retry_s = rates.get("retry_s", float, base.rate_retry_s, within(0, 3600, lo_open=True))
    retry_max_s = rates.get(
        "retry_max_s", float, base.rate_retry_max_s, within(0, 86400, lo_open=True)
    )
    if retry_max_s < retry_s:
        raise ConfigError(file, "rates.retry_max_s", f"must be >= retry_s ({retry_s:g})")
    link_bps = rates.get("link_bytes_per_s", float, 0.0, within(0, 1e9))
    budget_fraction = rates.get(
        "link_budget_fraction", float, base.link_budget_fraction, within(0, 1, lo_open=True)
    )
    has_hz = "hz" in rates.table
    hz_r = rates.sub("hz")
    wanted: dict[str, float] = {} if has_hz else dict(DEFAULT_RATES_HZ)
    for name in list(hz_r.table):
        if name not in MESSAGE_IDS:
            raise ConfigError(
                file, f"rates.hz.{name}", f"unknown message (one of {sorted(MESSAGE_IDS)})"
            )
        wanted[name] = hz_r.get(
            name,
            float,
            0.0,
            lambda x: None if 0 <= x <= 1000 or x == -1 else "must be in [0, 1000], or -1",
        )
    min_r = rates.sub("min_hz")
    needed: dict[str, float] = dict(DEFAULT_MIN_RATES_HZ)
    for name in list(min_r.table):
        if name not in MESSAGE_IDS:
            raise ConfigError(
                file, f"rates.min_hz.{name}", f"unknown message (one of {sorted(MESSAGE_IDS)})"
            )
        needed[name] = min_r.get(name, float, 0.0, within(0, 1000))
    min_r.done()
    hz_r.done()
    rates.done()
    ingest = IngestConfig(
        max_vehicles=max_vehicles,
        evict_idle_s=evict_idle_s,
        imu_fallback_s=imu_fallback_s,
        reorder_window_s=reorder_window_s,
        clock=clock,
        raw_imu_default=raw_default,
        raw_imu_by_sysid=by_sysid,
        rates_hz={k: v for k, v in wanted.items() if v != 0},
        rates_min_hz=needed,
        rate_window_s=window_s,
        rate_retry_s=retry_s,
        rate_retry_max_s=retry_max_s,
        link_bytes_per_s=link_bps or None,
        link_budget_fraction=budget_fraction,
    )
    # [estimation]
    est = root.sub("estimation")
    e_base = EstimatorConfig()
    gamma = {
        c: est.get(f"gamma_{c}", float, g, within(0, 1000, lo_open=True))
        for c, g in DEFAULT_GAMMA.items()
    }
    e_form = est.get("e_form", str, e_base.e_form, one_of(*get_args(EForm)))
    est_fields = _fields_from(est, e_base)
    ctl_r = est.sub("aero_control")
    ctl_on = ctl_r.get("enabled", bool, False)
    ctl_fields = _fields_from(ctl_r, ControlMapping())
    ctl_r.done()
    est_fields["aero_control"] = ControlMapping(**ctl_fields) if ctl_on else None
    br_r = est.sub("gps_bridge")
    bridge = GpsBridgeConfig(**_fields_from(br_r, GpsBridgeConfig()))
    if bridge.lag_prior_s > bridge.lag_max_s:
        raise ConfigError(
            file, "estimation.gps_bridge.lag_prior_s", "must be <= lag_max_s (the lag's grid)"
        )
    br_r.done()
    est_fields["gps_bridge"] = bridge
    est.done()
    # [fdi]
    fdi_r = root.sub("fdi")
    imu_r = fdi_r.sub("imu")
    imu_cfg = ImuMonitorConfig(**_fields_from(imu_r, ImuMonitorConfig()))
    imu_r.done()
    spike_r = fdi_r.sub("despike")
    spike_cfg = DespikeConfig(**_fields_from(spike_r, DespikeConfig()))
    spike_r.done()
    fdi = FdiConfig(**_fields_from(fdi_r, FdiConfig()), imu=imu_cfg, despike=spike_cfg)
    if fdi.warmup_s < 1.0:
        raise ConfigError(file, "fdi.warmup_s", "must be >= 1.0 (the bias fit needs 1 s)")
    fdi_r.done()
    estimation = EstimatorConfig(gamma=gamma, e_form=e_form, fdi=fdi, **est_fields)
    # [zenoh]
    zr = root.sub("zenoh")
    dec_r = zr.sub("decimation")
    rates_r = zr.sub("rates")
    zenoh = ZenohSettings(
        enabled=zr.get("enabled", bool, d.zenoh.enabled),
        config=zr.get("config", str, d.zenoh.config),
        prefix=zr.get("prefix", str, d.zenoh.prefix, _key_prefix),
        encoding=zr.get("encoding", str, d.zenoh.encoding, encoding_reason),
        decimation={k: dec_r.get(k, int, DEFAULT_DECIMATION[k], decimation_reason) for k in KINDS},
        rates_hz={k: _read_rate(rates_r, k, d.zenoh.rates_hz[k]) for k in STREAMS},
        full_rate=zr.get("full_rate", bool, d.zenoh.full_rate),
    )
    rates_r.done()
    dec_r.done()
    zr.done()
    # [rerun]
    rr = root.sub("rerun")
    rerun = RerunSettings(
        mode=rr.get("mode", str, d.rerun.mode, check_rerun_mode),
        decimation=rr.get("decimation", int, d.rerun.decimation, within(1, 10_000)),
        serve_bind=rr.get("serve_bind", str, d.rerun.serve_bind, _ip_address),
    )
    rr.done()
    # [security] (issue #9): the MAVLink 2 signing key; only frames signed with it pass
    sec = root.sub("security")
    key_hex = sec.get("signing_key_hex", str, "")
    key_file = sec.get("signing_key_file", str, "")
    state_file = sec.get("signing_state_file", str, "")
    sec.done()
    signing_key = _signing_key(file, key_hex, key_file)
    mavlink_out = _mavlink_out(root, file)
    state_path: str | None = None
    if signing_key is not None:
        state_path = _signing_state_path(file, state_file, signing_key)
    root.done()
    return ServiceConfig(
        service_id=service_id,
        links=tuple(links_raw),
        out=out,
        udp_receive_buffer_bytes=rcvbuf,
        request_rates=request_rates,
        ingest=ingest,
        estimation=estimation,
        zenoh=zenoh,
        rerun=rerun,
        mavlink_out=mavlink_out,
        signing_key=signing_key,
        signing_state_file=state_path,
        source=file,
    )


def _mavlink_out(root: TableReader, file: str) -> MavlinkOutSettings:
    """``[mavlink_out]`` (opt-in MAVLink output of the estimate; see configs/service.toml)."""
    r = root.sub("mavlink_out")
    d = MavlinkOutSettings()

    def comp(x: int) -> str | None:
        if not 1 <= x <= 254:
            return "must be 1..254"
        if x in GCS_COMPONENT_IDS:
            return "190 is a ground station's component id (MAV_COMP_ID_MISSIONPLANNER)"
        return None

    settings = MavlinkOutSettings(
        enabled=r.get("enabled", bool, d.enabled),
        link=r.get("link", str, d.link),
        system_id=r.get(
            "system_id",
            int,
            d.system_id,
            lambda x: (
                None if 0 <= x <= 254 else "must be 0 (the vehicle's) or 1..254 (255 is a GCS's)"
            ),
        ),
        component_id=r.get("component_id", int, d.component_id, comp),
        rate_hz=r.get(
            "rate_hz", float, d.rate_hz, lambda x: None if 0 < x <= 1000 else "must be in (0, 1000]"
        ),
        odometry=r.get("odometry", bool, d.odometry),
        vision_speed_estimate=r.get("vision_speed_estimate", bool, d.vision_speed_estimate),
        statustext=r.get("statustext", bool, d.statustext),
        named_value_float=r.get("named_value_float", bool, d.named_value_float),
        health_rate_hz=r.get(
            "health_rate_hz", float, d.health_rate_hz, within(0.0, 1000.0, lo_open=True)
        ),
        sigma_measured_mps=r.get(
            "sigma_measured_mps", float, d.sigma_measured_mps, within(0.0, 100.0, lo_open=True)
        ),
    )
    r.done()
    if settings.enabled and not settings.link:
        raise ConfigError(file, "mavlink_out.link", "required when mavlink_out.enabled = true")
    return settings


def _read_rate(table: TableReader, stream: str, default: float) -> float:
    """A read rate (``[zenoh.rates]``): Hz of vehicle time, 0 = not published, or
    ``"every"`` for every record."""
    if table.table.get(stream) == "every":
        table.used.add(stream)
        return EVERY
    reason = 'must be a number of Hz >= 0.01, 0 (not published) or "every" (every record)'

    def check(v: float) -> str | None:
        return None if rate_reason(v) is None else reason

    if stream in table.table and isinstance(table.table[stream], str):
        raise table.error(stream, f"{reason}, got {table.table[stream]!r}")
    value: float = table.get(stream, float, default, check)
    return value


#: A signing key file holds 64 hex digits and a newline: anything much larger is not one.
SIGNING_KEY_FILE_MAX_BYTES = 4096


def _signing_key(file: str, key_hex: str, key_file: str) -> bytes | None:
    """32 bytes from 64 hex digits, given inline or in a file (relative to ``file``)."""
    if key_hex and key_file:
        raise ConfigError(
            file, "security.signing_key_file", "give the key inline or as a file, not both"
        )
    where = "security.signing_key_hex"
    text = key_hex
    if key_file:
        where = "security.signing_key_file"
        kp = Path(key_file) if Path(key_file).is_absolute() else Path(file).parent / key_file
        # bounded, regular files only (a key file at /dev/zero must not fill the memory)
        try:
            raw = read_limited(kp, SIGNING_KEY_FILE_MAX_BYTES)
        except ConfigError as err:
            raise ConfigError(file, where, f"cannot read {kp}: {err.reason}") from None
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError as err:
            raise ConfigError(file, where, f"cannot read {kp}: {err}") from None
    if not text:
        return None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise ConfigError(file, where, "must be 64 hexadecimal digits") from None
    if len(key) != 32:
        raise ConfigError(file, where, f"must be 32 bytes (64 hex digits), got {len(key)}")
    return key


def _signing_state_path(file: str, state_file: str, key: bytes) -> str:
    """``[security] signing_state_file`` (relative to the config file), or by default
    ``signing-<key id>.json`` in ``$STATE_DIRECTORY`` (systemd), else
    ``${XDG_STATE_HOME:-~/.local/state}/glmav-observer``."""
    import os

    from glmav_observer.ingest.framing import signing_key_id

    if state_file:
        p = Path(state_file)
        return str(p if p.is_absolute() else Path(file).parent / p)
    base = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    if not base:
        xdg = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
        base = str(Path(xdg) / "glmav-observer")
    return str(Path(base) / f"signing-{signing_key_id(key)}.json")


def check_rerun_mode(mode: str) -> str | None:
    """None if ``mode`` is a valid ``--rerun`` value, else the reason (the sink's parser)."""
    from glmav_observer.publish.rerun.mode import RerunModeError, parse_rerun_mode

    try:
        parse_rerun_mode(mode)
    except RerunModeError as err:
        return str(err)
    return None


def load_config(path: str | Path | None) -> ServiceConfig:
    """Load and validate ``path`` (None: the defaults)."""
    if path is None:
        return parse_config({}, "<defaults>")
    p = Path(path)
    data = load_toml(p)
    return parse_config(data, str(p))
