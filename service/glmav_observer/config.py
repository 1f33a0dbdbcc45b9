"""``configs/service.toml``: loading and validation of the service's settings.

Every setting has a default (the values in ``configs/service.toml``, where each one is
documented); a file overrides some of them. A bad file raises :class:`ConfigError`
naming the file, the key (dotted) and the reason; the commands turn it into exit code 2.
Unknown keys are errors too (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from glmav_observer.estimation.bank import DEFAULT_GAMMA
from glmav_observer.estimation.fdi import FdiConfig
from glmav_observer.estimation.vehicle import EstimatorConfig
from glmav_observer.ingest.clock import ClockConfig
from glmav_observer.ingest.convert import RawImuScale
from glmav_observer.ingest.pipeline import IngestConfig
from glmav_observer.ingest.rates import MESSAGE_IDS

#: Requested stream rates when ``[rates.hz]`` is absent (design.md's SITL rates).
DEFAULT_RATES_HZ: dict[str, float] = {
    "ATTITUDE": 100.0,
    "HIGHRES_IMU": 250.0,
    "LOCAL_POSITION_NED": 30.0,
    "SIM_STATE": 50.0,
    "EKF_STATUS_REPORT": 2.0,  # ArduPilot: is the velocity aided?
    "GPS_RAW_INT": 5.0,  # fix type: a GPS loss makes the autopilot's velocity unaided
}


class ConfigError(ValueError):
    """A bad configuration value: ``file``, ``key`` (dotted) and ``reason``."""

    def __init__(self, file: str, key: str, reason: str) -> None:
        super().__init__(f"{file}: {key}: {reason}")
        self.file = file
        self.key = key
        self.reason = reason


@dataclass(frozen=True, slots=True)
class ZenohSettings:
    enabled: bool = False
    config: str = ""
    prefix: str = "glmav"
    decimation: Mapping[str, int] = field(
        default_factory=lambda: {"velocity": 1, "active": 1, "health": 1}
    )


@dataclass(frozen=True, slots=True)
class RerunSettings:
    mode: str = "off"
    decimation: int = 1
    serve_bind: str = "127.0.0.1"


#: Component ids a ground station uses (MAVLink's MAV_COMP_ID_MISSIONPLANNER, QGroundControl):
#: the service never claims them.
GCS_COMPONENT_IDS = frozenset({190})


@dataclass(frozen=True, slots=True)
class MavlinkOutSettings:
    """``[mavlink_out]``: the active estimate (and health) back on MAVLink (publish/mavlink_out.py)."""

    enabled: bool = False
    link: str = ""  # a pymavlink connection string, e.g. udpout:127.0.0.1:14551
    system_id: int = 0  # 0: each vehicle's own system id (a component of that vehicle)
    component_id: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    rate_hz: float = 30.0  # ODOMETRY / VISION_SPEED_ESTIMATE per vehicle, vehicle time
    odometry: bool = True
    vision_speed_estimate: bool = False
    statustext: bool = True  # fault isolations and configuration switches
    named_value_float: bool = True  # per-axis health and the active configuration
    health_rate_hz: float = 1.0  # NAMED_VALUE_FLOAT per vehicle
    sigma_measured_mps: float = 0.05  # velocity std of a measured axis in the covariance


@dataclass(frozen=True, slots=True)
class ServiceConfig:
    """Everything the service needs; build with :func:`load_config`."""

    service_id: str = "glmav-observer"
    links: tuple[str, ...] = ()
    out: str = ""
    udp_receive_buffer_bytes: int = 4 * 1024 * 1024
    request_rates: bool = True
    ingest: IngestConfig = field(default_factory=IngestConfig)
    estimation: EstimatorConfig = field(default_factory=EstimatorConfig)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    rerun: RerunSettings = field(default_factory=RerunSettings)
    mavlink_out: MavlinkOutSettings = field(default_factory=MavlinkOutSettings)
    signing_key: bytes | None = field(default=None, repr=False)  # MAVLink 2 signing
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
            return x

        out: dict[str, Any] = plain(self)
        out["signing_key"] = "<set>" if self.signing_key is not None else None  # never the key
        return out


# ---------------------------------------------------------------------- validation helpers
Check = Callable[[Any], str | None]


def _positive(x: Any) -> str | None:
    return None if x > 0 else "must be > 0"


def _non_negative(x: Any) -> str | None:
    return None if x >= 0 else "must be >= 0"


def _ratio(x: Any) -> str | None:
    return None if 0 < x <= 1 else "must be in (0, 1]"


class _Reader:
    """Reads typed keys from one TOML table, tracking which keys were used."""

    def __init__(self, file: str, table: Mapping[str, Any], prefix: str) -> None:
        self.file = file
        self.table = table
        self.prefix = prefix
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}{name}"

    def get(self, name: str, kind: type, default: Any, check: Check | None = None) -> Any:
        self.used.add(name)
        if name not in self.table:
            return default
        value = self.table[name]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if kind is int and isinstance(value, bool):
            raise ConfigError(self.file, self.key(name), f"expected an integer, got {value!r}")
        if not isinstance(value, kind):
            raise ConfigError(self.file, self.key(name), f"expected {kind.__name__}, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(self.file, self.key(name), f"must be finite, got {value!r}")
        if check is not None:
            reason = check(value)
            if reason is not None:
                raise ConfigError(self.file, self.key(name), f"{reason}, got {value!r}")
        return value

    def sub(self, name: str) -> _Reader:
        self.used.add(name)
        value = self.table.get(name, {})
        if not isinstance(value, Mapping):
            raise ConfigError(self.file, self.key(name), "expected a table")
        return _Reader(self.file, value, f"{self.prefix}{name}.")

    def done(self) -> None:
        for k in self.table:
            if k not in self.used:
                raise ConfigError(self.file, self.key(k), "unknown key")


def _fields_from(r: _Reader, default: Any, checks: Mapping[str, Check]) -> dict[str, Any]:
    """Every int/float/bool field of a frozen dataclass, read from ``r`` with its default."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(default):
        v = getattr(default, f.name)
        if isinstance(v, bool):
            out[f.name] = r.get(f.name, bool, v)
        elif isinstance(v, int):
            out[f.name] = r.get(f.name, int, v, checks.get(f.name, _positive))
        elif isinstance(v, float):
            out[f.name] = r.get(f.name, float, v, checks.get(f.name, _positive))
    return out


def parse_config(data: Mapping[str, Any], file: str = "<config>") -> ServiceConfig:
    """Validate a parsed TOML document (see ``configs/service.toml``)."""
    root = _Reader(file, data, "")
    # [service]
    svc = root.sub("service")
    service_id = svc.get("id", str, "glmav-observer", lambda s: None if s else "must not be empty")
    links_raw = svc.get("links", list, [])
    for i, link in enumerate(links_raw):
        if not isinstance(link, str) or not link:
            raise ConfigError(file, f"service.links[{i}]", "expected a connection string")
    out = svc.get("out", str, "")
    if out and not out.endswith((".csv", ".jsonl")):
        raise ConfigError(file, "service.out", f"must end in .csv or .jsonl, got {out!r}")
    rcvbuf = svc.get("udp_receive_buffer_bytes", int, 4 * 1024 * 1024, _positive)
    svc.done()
    # [ingest]
    ing = root.sub("ingest")
    base = IngestConfig()
    max_vehicles = ing.get("max_vehicles", int, base.max_vehicles, _positive)
    evict_idle_s = ing.get("evict_idle_s", float, base.evict_idle_s, _positive)
    imu_fallback_s = ing.get("imu_fallback_s", float, base.imu_fallback_s, _positive)
    reorder_window_s = ing.get("reorder_window_s", float, base.reorder_window_s, _non_negative)
    clock = ClockConfig(**_fields_from(ing, ClockConfig(), {"latency_window_s": _non_negative}))
    raw = ing.sub("raw_imu")
    raw_default = RawImuScale(**_fields_from(raw, RawImuScale(), {}))
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
        by_sysid[sysid] = RawImuScale(**_fields_from(sub, raw_default, {}))
        sub.done()
    per.done()
    raw.done()
    ing.done()
    # [rates]
    rates = root.sub("rates")
    request_rates = rates.get("request", bool, True)
    window_s = rates.get("window_s", float, base.rate_window_s, _positive)
    shortfall = rates.get("shortfall_ratio", float, base.rate_shortfall_ratio, _ratio)
    retry_s = rates.get("retry_s", float, base.rate_retry_s, _positive)
    has_hz = "hz" in rates.table
    hz_r = rates.sub("hz")
    wanted: dict[str, float] = {} if has_hz else dict(DEFAULT_RATES_HZ)
    for name in list(hz_r.table):
        if name not in MESSAGE_IDS:
            raise ConfigError(
                file, f"rates.hz.{name}", f"unknown message (one of {sorted(MESSAGE_IDS)})"
            )
        wanted[name] = hz_r.get(
            name, float, 0.0, lambda x: None if x >= 0 or x == -1 else "must be >= 0, or -1"
        )
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
        rate_window_s=window_s,
        rate_shortfall_ratio=shortfall,
        rate_retry_s=retry_s,
    )
    # [estimation]
    est = root.sub("estimation")
    e_base = EstimatorConfig()
    gamma = {c: est.get(f"gamma_{c}", float, g, _positive) for c, g in DEFAULT_GAMMA.items()}
    e_form = est.get(
        "e_form",
        str,
        "exact",
        lambda s: None if s in ("exact", "small_angle") else "must be exact or small_angle",
    )
    est_fields = _fields_from(est, e_base, {"metrics_skip_s": _non_negative})
    est.done()
    # [fdi]
    fdi_r = root.sub("fdi")
    fdi = FdiConfig(
        **_fields_from(
            fdi_r,
            FdiConfig(),
            {"sigma_bias_mps2": _non_negative, "accel_noise_density": _non_negative},
        )
    )
    if fdi.warmup_s < 1.0:
        raise ConfigError(file, "fdi.warmup_s", "must be >= 1.0 (the bias fit needs 1 s)")
    fdi_r.done()
    estimation = EstimatorConfig(gamma=gamma, e_form=e_form, fdi=fdi, **est_fields)
    # [zenoh]
    zr = root.sub("zenoh")
    dec_r = zr.sub("decimation")
    zenoh = ZenohSettings(
        enabled=zr.get("enabled", bool, False),
        config=zr.get("config", str, ""),
        prefix=zr.get("prefix", str, "glmav", lambda s: None if s else "must not be empty"),
        decimation={
            k: dec_r.get(k, int, 1, _non_negative) for k in ("velocity", "active", "health")
        },
    )
    dec_r.done()
    zr.done()
    # [rerun]
    rr = root.sub("rerun")
    rerun = RerunSettings(
        mode=rr.get("mode", str, "off", check_rerun_mode),
        decimation=rr.get("decimation", int, 1, _positive),
        serve_bind=rr.get("serve_bind", str, "127.0.0.1"),
    )
    rr.done()
    # [security] (issue #9): the MAVLink 2 signing key; only frames signed with it pass
    sec = root.sub("security")
    key_hex = sec.get("signing_key_hex", str, "")
    key_file = sec.get("signing_key_file", str, "")
    sec.done()
    signing_key = _signing_key(file, key_hex, key_file)
    mavlink_out = _mavlink_out(root, file)
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
        source=file,
    )


def _mavlink_out(root: _Reader, file: str) -> MavlinkOutSettings:
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
        health_rate_hz=r.get("health_rate_hz", float, d.health_rate_hz, _positive),
        sigma_measured_mps=r.get("sigma_measured_mps", float, d.sigma_measured_mps, _positive),
    )
    r.done()
    if settings.enabled and not settings.link:
        raise ConfigError(file, "mavlink_out.link", "required when mavlink_out.enabled = true")
    return settings


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
        try:
            text = kp.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError) as err:
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
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(p), "-", "file not found") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(str(p), "-", f"not valid TOML: {err}") from None
    return parse_config(data, str(p))
