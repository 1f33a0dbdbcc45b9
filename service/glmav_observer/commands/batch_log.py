"""One log of ``batch`` (:mod:`glmav_observer.commands.batch`), replayed in a worker (a
local process or a Dask worker): its summary row, its records as a Parquet table of fixed
schema and its plot (:func:`process_log`; every argument and result pickles).
"""

from __future__ import annotations

import json
import math
from typing import Any

from glmav_observer.commands.batch_report import plot_png

#: Columns of the Parquet dataset after ``log_id`` and ``vehicle``; typed so that every
#: part file has the same schema whatever records a log produced.
STRING_COLUMNS = (
    "schema", "config", "lost_axis", "health", "source_config", "active_config",
    "axis_state.n", "axis_state.e", "axis_state.d", "isolated_faults", "source",
)  # fmt: skip
INT_COLUMNS = ("sysid", "seq")
FLOAT_COLUMNS = (
    "t_boot_s",
    "v_body_mps_u", "v_body_mps_v", "v_body_mps_w",
    "v_ned_mps_n", "v_ned_mps_e", "v_ned_mps_d",
    "sigma_lost_mps",
    "position_ned_m_n", "position_ned_m_e", "position_ned_m_d",
    "euler_rad_roll", "euler_rad_pitch", "euler_rad_yaw",
    "residual_ned_mps_n", "residual_ned_mps_e", "residual_ned_mps_d",
    "test_ratio_n", "test_ratio_e", "test_ratio_d",
)  # fmt: skip


def _schema() -> Any:
    import pyarrow as pa  # type: ignore[import-untyped]  # no stubs

    fields = [pa.field("log_id", pa.string()), pa.field("vehicle", pa.string())]
    fields += [pa.field(c, pa.string()) for c in STRING_COLUMNS]
    fields += [pa.field(c, pa.int64()) for c in INT_COLUMNS]
    fields += [pa.field(c, pa.float64()) for c in FLOAT_COLUMNS]
    return pa.schema(fields)


class _Collect:
    """A sink that keeps every record (a worker's memory holds one log's records)."""

    def __init__(self) -> None:
        self.records: list[Any] = []

    def write(self, record: Any) -> None:
        self.records.append(record)

    def close(self) -> None:
        pass


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, list | dict):
        return json.dumps(x, sort_keys=True, separators=(",", ":"))
    return x


def _table(records: list[Any], log_id: str, vehicle: str) -> Any:
    import pyarrow as pa

    from glmav_observer.records import flatten

    schema = _schema()
    wanted = set(schema.names)
    rows = []
    for r in records:
        row = {k: _clean(v) for k, v in flatten(r).items() if k in wanted}
        row["log_id"] = log_id
        row["vehicle"] = vehicle
        rows.append(row)
    return pa.Table.from_pylist(rows, schema=schema)


def _fault_text(faults: list[dict[str, Any]], t_start: float) -> str:
    """``n, e, d freeze at 0.81 s; d bias at 27.60 s``: axes isolated together are grouped."""
    groups: dict[tuple[str, str], list[str]] = {}
    for f in faults:
        key = (f["kind"], f"{f['t_detect_s'] - t_start:.2f}")
        groups.setdefault(key, []).append(f["axis"])
    return "; ".join(f"{', '.join(ax)} {kind} at {t} s" for (kind, t), ax in groups.items())


def _rmse_row(prefix: str, r: tuple[float, float, float] | None) -> dict[str, float | None]:
    return {f"{prefix}_{a}": (None if r is None else round(r[i], 4)) for i, a in enumerate("ned")}


#: The report's rate columns for a tlog: the messages counted (``rx_<NAME>``) behind each;
#: a tlog's LOCAL_POSITION_NED is the autopilot's EKF output, its GPS is GPS_RAW_INT.
_TLOG_RATE_MESSAGES: dict[str, tuple[str, ...]] = {
    "attitude": ("ATTITUDE",),
    "imu": ("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU"),
    "gps": ("GPS_RAW_INT",),
    "ekf": ("LOCAL_POSITION_NED",),
    "truth": ("SIM_STATE",),
}


def _tlog_duration_and_rates(records: list[Any], vehicle: Any) -> dict[str, Any]:
    """A tlog's duration (the span of the vehicle's record times, s) and its mean input
    rates (the messages received over that span; the IMU: the busiest IMU message)."""
    if vehicle is None:
        return {"duration_s": None}
    times = [r.t_boot_s for r in records if r.sysid == vehicle.sysid]
    duration_s = max(times) - min(times) if times else 0.0
    out: dict[str, Any] = {"duration_s": round(duration_s, 3) if times else None}
    if duration_s > 0.0:
        counters = vehicle.counters
        for column, names in _TLOG_RATE_MESSAGES.items():
            n = max(counters.get(f"rx_{name}", 0) for name in names)
            if n:
                out[f"rate_{column}_hz"] = round(n / duration_s, 2)
    return out


def process_log(
    path: str, log_id: str, config_path: str | None, velocity_source: str
) -> dict[str, Any]:
    """Replay one log; returns its summary row, its Parquet table and its plot (or its error).

    Runs in a worker (a local process or a Dask worker): every argument and result pickles.
    """
    from glmav_observer.app_replay import replay_flight_log, replay_tlog
    from glmav_observer.config import load_config
    from glmav_observer.ingest.logfiles import LogError, UnsupportedLogError, detect_format
    from glmav_observer.ingest.logfiles.tlog import check_tlog
    from glmav_toml import ConfigError

    row: dict[str, Any] = {"log_id": log_id, "path": path, "error": None}
    sink = _Collect()
    try:
        config = load_config(config_path)
        fmt = detect_format(path)
        row["format"] = fmt
        if fmt == "tlog":  # refused (below) when no vehicle sent all the estimator needs
            s = replay_tlog(path, config, [sink], scan=check_tlog(path))
            t_start = min((r.t_boot_s for r in sink.records), default=0.0)
            v = next(iter(s.vehicles.values()), None)
            row.update(vehicle="MAVLink", **_tlog_duration_and_rates(sink.records, v))
            rmse = v.rmse_ned_mps.get("active") if v is not None else None
            row.update(rmse_basis="truth" if rmse else None, **_rmse_row("rmse_active", rmse))
        else:
            fl = replay_flight_log(path, config, [sink], velocity_source=velocity_source)
            t_start = fl.t_start_s
            v = fl.vehicle_summary
            row.update(
                vehicle=fl.vehicle,
                duration_s=round(fl.duration_s, 3),
                **{f"rate_{k}_hz": round(x, 2) for k, x in fl.rates_hz.items()},
                velocity_source=fl.velocity_source,
                gps_delay_ms=round(fl.gps_delay_s * 1e3, 1),
                gps_delay_source=fl.gps_delay_source,
                vehicle_type=fl.vehicle_type,
                reference=fl.sources.get("ekf"),
                ekf_velocity_rejections=fl.ekf_velocity_innovation_failures,
                # samples dropped while reading, and what the reader found damaged
                # (pymavlink's reports: counted here, not printed)
                dropped_while_reading=", ".join(f"{k}={v}" for k, v in fl.dropped.items()),
            )
            row.update(
                _rmse_row("rmse_full_in_flight", fl.rmse_vs_reference_in_flight_ned_mps.get("full"))
            )
            truth = v.rmse_ned_mps.get("active") if v is not None and v.truth_samples else None
            ref = fl.rmse_vs_reference_ned_mps.get("active")
            basis = "truth" if truth else ("reference" if ref else None)
            row.update(rmse_basis=basis, **_rmse_row("rmse_active", truth or ref))
            row.update(_rmse_row("rmse_active_vs_reference", ref))
        faults = v.faults if v is not None else []
        switches = v.switches if v is not None else []
        # fault times in s into the log, as replay prints them (a SITL PX4 clock reads ~1.7e9 s)
        row["faults"] = _fault_text(faults, t_start)
        row["isolations"] = len(faults)
        row["switches"] = len(switches)
        row["records"] = len(sink.records)
        table = _table(sink.records, log_id, str(row.get("vehicle", "")))
        png = plot_png(
            sink.records, faults, switches, f"{log_id}: {row.get('vehicle', '')}", t_start
        )
        return {"row": row, "table": table, "png": png}
    except UnsupportedLogError as err:  # a readable log lacking a stream: the matrix's refusal
        row["error"] = row["refusal"] = str(err)
    except (LogError, ConfigError, OSError, ValueError) as err:
        row["error"] = str(err)
    except Exception as err:  # a log that breaks a library: reported, the batch goes on
        row["error"] = f"{type(err).__name__}: {err}"
    return {"row": row, "table": None, "png": None}
