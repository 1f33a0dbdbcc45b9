"""``glmav-observer batch PATH... --out DIR``: many logs at once, one report.

Every file given (directories are searched recursively) is replayed like ``replay`` does
(``.tlog``, ArduPilot dataflash, PX4 ULog, recognised by content). Written to ``DIR``:

- ``records/<log_id>.parquet``: one Parquet dataset of every record of every log, with
  the columns of ``replay --out`` plus ``log_id`` and ``vehicle`` (read the folder with
  ``pyarrow.dataset.dataset(DIR/records)`` or any Parquet reader);
- ``summary.csv`` and ``summary.json``: a row per log (format, vehicle, duration, rates,
  GPS delay, faults isolated with times, switches, RMSE against truth when the log has
  it, else against the autopilot's EKF) and the error of a log that could not be read;
- ``report.html``: a static page, the summary table and a plot per log (velocity against
  the measurement and the reference, residuals, fault windows shaded), PNGs embedded.

Logs run in a local process pool (``--workers``, default the CPU count); with
``--cluster ADDRESS`` they run on a Dask distributed cluster instead (the scheduler's
address, e.g. ``tcp://127.0.0.1:8786``; the log paths must be readable by its workers).
A log that fails is reported in the summary and does not stop the batch. Exit codes: 0
done (even with failed logs), 2 bad arguments, output folder, configuration or cluster.
"""

from __future__ import annotations

import argparse
import base64
import html
import io
import json
import math
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

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


#: Points per line in a report plot (decimated beyond: the PNG is 800 px wide).
PLOT_MAX_POINTS = 2000


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "batch", help="replay many logs: Parquet records, a summary table and an HTML report"
    )
    p.add_argument("paths", nargs="+", metavar="PATH", help="log files or folders of logs")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--config", default=None, help="service.toml (default: built-in defaults)")
    p.add_argument("--velocity-source", choices=("gps", "ekf"), default="gps")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPUs)")
    p.add_argument(
        "--cluster", default=None, metavar="ADDRESS", help="a Dask scheduler to run the logs on"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=main)


# ---------------------------------------------------------------------- one log (in a worker)
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


def _fault_windows(
    faults: list[dict[str, Any]], switches: list[dict[str, Any]], t_end: float
) -> list[tuple[float, float, str]]:
    """(start, end, label) of each isolated fault: until the next recovery switch, else the end."""
    rec = sorted(s["t_boot_s"] for s in switches if s["reason"] == "recovered")
    out = []
    for f in faults:
        t0 = f["t_detect_s"]
        t1 = next((t for t in rec if t > t0), t_end)
        out.append((t0, t1, f"{f['axis']} {f['kind']}"))
    return out


def _plot_png(
    records: list[Any],
    faults: list[dict[str, Any]],
    switches: list[dict[str, Any]],
    title: str,
    t0: float,
) -> bytes:
    """Velocity (n, e, d) and residuals against time into the log (``t0``: its start), PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from glmav_observer.records import (
        HealthRecord,
        MeasurementRecord,
        ReferenceRecord,
        TruthRecord,
        VelocityRecord,
    )

    t_end = max((r.t_boot_s for r in records), default=t0)

    groups: dict[str, tuple[list[float], list[Any]]] = {
        k: ([], []) for k in ("active", "meas", "ref", "truth", "resid")
    }
    for r in records:
        if isinstance(r, VelocityRecord):
            if r.config != "active":
                continue
            key, v = "active", r.v_ned_mps
        elif isinstance(r, MeasurementRecord):
            key, v = "meas", r.v_ned_mps
        elif isinstance(r, ReferenceRecord):
            key, v = "ref", r.v_ned_mps
        elif isinstance(r, TruthRecord):
            key, v = "truth", r.v_ned_mps
        elif isinstance(r, HealthRecord):
            key, v = "resid", r.residual_ned_mps
        else:
            continue
        groups[key][0].append(r.t_boot_s - t0)
        groups[key][1].append(v)

    def series(key: str) -> tuple[list[float], list[Any]]:
        t, v = groups[key]
        step = max(1, len(t) // PLOT_MAX_POINTS)  # a page needs no more points than pixels
        return t[::step], v[::step]

    active, meas, ref, truth, resid = (
        series(k) for k in ("active", "meas", "ref", "truth", "resid")
    )
    fig, axes = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    for k, name in enumerate(("north", "east", "down")):
        ax = axes[k]
        if truth[0]:
            ax.plot(truth[0], [v[k] for v in truth[1]], color="0.6", lw=2.5, label="truth")
        if ref[0]:
            ax.plot(
                ref[0],
                [v[k] for v in ref[1]],
                "--",
                color="tab:green",
                lw=1.2,
                label="EKF (reference)",
            )
        if meas[0]:
            ax.plot(
                meas[0], [v[k] for v in meas[1]], ".", color="tab:orange", ms=3, label="measurement"
            )
        if active[0]:
            ax.plot(
                active[0],
                [v[k] for v in active[1]],
                color="tab:blue",
                lw=1.0,
                label="observer (active)",
            )
        ax.set_ylabel(f"v {name} (m/s)")
    if resid[0]:
        for k, (name, c) in enumerate(
            zip("ned", ("tab:red", "tab:purple", "tab:brown"), strict=True)
        ):
            axes[3].plot(
                resid[0], [v[k] for v in resid[1]], color=c, lw=0.8, label=f"residual {name}"
            )
        axes[3].legend(loc="upper right", fontsize=8)
    if not any(math.isfinite(x) for v in resid[1] for x in v):
        axes[3].text(
            0.5, 0.5, "no residual tests: the IMU's rate is below [fdi] min_imu_rate_hz",
            transform=axes[3].transAxes, ha="center", va="center", color="0.4",
        )  # fmt: skip
    axes[3].set_ylabel("residual (m/s)")
    axes[3].set_xlabel(f"time into the log (s; it starts at {t0:.1f} s of the autopilot's clock)")
    windows = _fault_windows(faults, switches, t_end)
    for a0, a1 in sorted({(a0, a1) for a0, a1, _ in windows}):  # one band per window
        for ax in axes:
            ax.axvspan(a0 - t0, a1 - t0, color="tab:red", alpha=0.12, lw=0)
    if windows:
        from matplotlib.patches import Patch

        labels = ", ".join(sorted({w[2] for w in windows}))
        axes[0].add_artist(
            axes[0].legend(
                handles=[Patch(color="tab:red", alpha=0.25, label=f"isolated fault ({labels})")],
                loc="lower right",
                fontsize=8,
            )
        )
    axes[0].legend(loc="upper left", fontsize=8, ncol=4)
    axes[0].set_title(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def _fault_text(faults: list[dict[str, Any]], t_start: float) -> str:
    """``n, e, d freeze at 0.81 s; d bias at 27.60 s``: axes isolated together are grouped."""
    groups: dict[tuple[str, str], list[str]] = {}
    for f in faults:
        key = (f["kind"], f"{f['t_detect_s'] - t_start:.2f}")
        groups.setdefault(key, []).append(f["axis"])
    return "; ".join(f"{', '.join(ax)} {kind} at {t} s" for (kind, t), ax in groups.items())


def _rmse_row(prefix: str, r: tuple[float, float, float] | None) -> dict[str, float | None]:
    return {f"{prefix}_{a}": (None if r is None else round(r[i], 4)) for i, a in enumerate("ned")}


def process_log(
    path: str, log_id: str, config_path: str | None, velocity_source: str
) -> dict[str, Any]:
    """Replay one log; returns its summary row, its Parquet table and its plot (or its error).

    Runs in a worker (a local process or a Dask worker): every argument and result pickles.
    """
    from glmav_observer.app_replay import replay_flight_log, replay_tlog
    from glmav_observer.config import load_config
    from glmav_observer.ingest.logfiles import LogError, detect_format
    from glmav_toml import ConfigError

    row: dict[str, Any] = {"log_id": log_id, "path": path, "error": None}
    sink = _Collect()
    try:
        config = load_config(config_path)
        fmt = detect_format(path)
        row["format"] = fmt
        if fmt == "tlog":
            s = replay_tlog(path, config, [sink])
            t_start = min((r.t_boot_s for r in sink.records), default=0.0)
            v = next(iter(s.vehicles.values()), None)
            row.update(vehicle="MAVLink", duration_s=None)
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
        row["switches"] = len(switches)
        row["records"] = len(sink.records)
        table = _table(sink.records, log_id, str(row.get("vehicle", "")))
        png = _plot_png(
            sink.records, faults, switches, f"{log_id}: {row.get('vehicle', '')}", t_start
        )
        return {"row": row, "table": table, "png": png}
    except (LogError, ConfigError, OSError, ValueError) as err:
        row["error"] = str(err)
    except Exception as err:  # a log that breaks a library: reported, the batch goes on
        row["error"] = f"{type(err).__name__}: {err}"
    return {"row": row, "table": None, "png": None}


# ---------------------------------------------------------------------- the batch
def expand_paths(paths: Iterable[str]) -> tuple[list[Path], int]:
    """Files as given, and in folders (recursively) the files whose content is a log.

    A file named on the command line is always replayed (and reported if it is not a log);
    in a folder, other files (READMEs, licences) are skipped and counted.
    """
    from glmav_observer.ingest.logfiles import LogError, detect_format

    out: list[Path] = []
    skipped = 0
    for p in map(Path, paths):
        if not p.is_dir():
            out.append(p)
            continue
        for f in sorted(p.rglob("*")):
            if not f.is_file() or f.name.startswith("."):
                continue
            try:
                detect_format(f)
            except LogError:
                skipped += 1
                continue
            out.append(f)
    return out, skipped


def log_ids(files: list[Path]) -> list[str]:
    """A unique id per file: its name, with ``-2``, ``-3``... for repeated names."""
    seen: dict[str, int] = {}
    ids = []
    for f in files:
        base = f.name
        seen[base] = seen.get(base, 0) + 1
        ids.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    return ids


def _progress(done: int, total: int) -> None:
    bar = "#" * (25 * done // max(total, 1))
    end = "\n" if done >= total else ""
    print(f"\rbatch [{bar:<25}] {done}/{total} logs", end=end, file=sys.stderr, flush=True)


def run_batch(
    files: list[Path],
    out: Path,
    *,
    config_path: str | None = None,
    velocity_source: str = "gps",
    workers: int | None = None,
    cluster: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Replay ``files`` and write the dataset, the summary and the report into ``out``."""
    ids = log_ids(files)
    jobs = [(str(f), i, config_path, velocity_source) for f, i in zip(files, ids, strict=True)]
    results: list[dict[str, Any]] = []
    if progress is not None:
        progress(0, len(jobs))
    if cluster:
        from distributed import Client, as_completed

        with Client(cluster, timeout="30s") as client:  # type: ignore[no-untyped-call]
            futures = [client.submit(process_log, *j, pure=False) for j in jobs]
            for fut in as_completed(futures):  # type: ignore[no-untyped-call]
                results.append(fut.result())
                if progress is not None:
                    progress(len(results), len(jobs))
    else:
        import concurrent.futures as cf

        n = workers or os.cpu_count() or 1
        with cf.ProcessPoolExecutor(max_workers=min(n, max(1, len(jobs)))) as pool:
            pending = [pool.submit(process_log, *j) for j in jobs]
            for fut in cf.as_completed(pending):
                results.append(fut.result())
                if progress is not None:
                    progress(len(results), len(jobs))
    results.sort(key=lambda r: ids.index(r["row"]["log_id"]))
    write_outputs(results, out)
    return [r["row"] for r in results]


def write_outputs(results: list[dict[str, Any]], out: Path) -> None:
    import csv

    import pyarrow.parquet as pq  # type: ignore[import-untyped]  # no stubs

    rec_dir = out / "records"
    rec_dir.mkdir(parents=True, exist_ok=True)
    for r in results:
        if r["table"] is not None:
            pq.write_table(r["table"], rec_dir / f"{r['row']['log_id']}.parquet")
    rows = [r["row"] for r in results]
    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    with (out / "summary.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=columns, lineterminator="\n")
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in columns})
    (out / "summary.json").write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    (out / "report.html").write_text(_html(results), encoding="utf-8")


def _fmt(x: Any, nd: int = 3) -> str:
    if x is None or x == "":
        return ""
    if isinstance(x, float):
        return f"{x:.{nd}f}"
    return str(x)


def _html(results: list[dict[str, Any]]) -> str:
    """The report: a compact table (every column is in summary.csv) and a plot per log."""
    esc = html.escape
    head = (
        "<th>log</th><th>format</th><th>vehicle</th><th>duration (s)</th>"
        "<th>rates (Hz): att. / IMU / GPS / EKF / truth</th><th>velocity, GPS delay</th>"
        "<th>faults isolated (s into the log)</th><th>switches</th>"
        "<th>RMSE n / e / d (m/s), against</th>"
    )
    body = []
    for r in results:
        row = r["row"]
        log = f"<a href='#{esc(row['log_id'])}'>{esc(row['log_id'])}</a>"
        if row.get("error"):
            body.append(
                f"<tr class='error'><td>{log}</td><td>{esc(_fmt(row.get('format')))}</td>"
                f"<td colspan='7' class='text'>{esc(str(row['error']))}</td></tr>"
            )
            continue
        rates = " / ".join(_fmt(row.get(f"rate_{k}_hz"), 1) or "-" for k in
                           ("attitude", "imu", "gps", "ekf", "truth"))  # fmt: skip
        src = str(row.get("velocity_source") or "")
        if src == "gps":
            src += f", {_fmt(row.get('gps_delay_ms'), 0)} ms ({row.get('gps_delay_source')})"
        rmse = " / ".join(_fmt(row.get(f"rmse_active_{a}")) for a in "ned")
        body.append(
            f"<tr><td>{log}</td><td>{esc(_fmt(row.get('format')))}</td>"
            f"<td>{esc(_fmt(row.get('vehicle')))}</td><td>{_fmt(row.get('duration_s'), 1)}</td>"
            f"<td>{esc(rates)}</td><td>{esc(src)}</td>"
            f"<td class='text'>{esc(row.get('faults') or 'none')}</td>"
            f"<td>{_fmt(row.get('switches'))}</td>"
            f"<td>{esc(rmse)}, {esc(_fmt(row.get('rmse_basis')))}</td></tr>"
        )
    n_err = sum(1 for r in results if r["row"].get("error"))
    plots = []
    for r in results:
        row = r["row"]
        if r["png"] is None:
            plots.append(
                f"<h2>{esc(row['log_id'])}</h2><p class='error'>not replayed: {esc(str(row['error']))}</p>"
            )
            continue
        img = base64.b64encode(r["png"]).decode()
        plots.append(
            f"<h2 id='{esc(row['log_id'])}'>{esc(row['log_id'])}: {esc(str(row.get('vehicle', '')))}</h2>"
            f"<p>{esc(row['path'])}; faults: {esc(row.get('faults') or 'none')}</p>"
            f"<img alt='velocity and residuals of {esc(row['log_id'])}' src='data:image/png;base64,{img}'>"
        )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>glmav-observer batch report</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; font-size: 0.75em; }}
th, td {{ border: 1px solid #bbb; padding: 2px 6px; text-align: left; white-space: nowrap; }}
th, td.text {{ white-space: normal; }}
td.text {{ min-width: 12em; max-width: 24em; }}
tr.error td, p.error {{ color: #b00; }}
img {{ max-width: 100%; }}
</style></head><body>
<h1>glmav-observer batch report</h1>
<p>{len(results)} logs, {n_err} not replayed. RMSE in m/s of the active estimate against
truth where the log has it (rmse_basis = truth), else against the autopilot's EKF velocity.
Red bands: isolated faults. Every column is in summary.csv.</p>
<table><tr>{head}</tr>
{chr(10).join(body)}
</table>
{chr(10).join(plots)}
</body></html>
"""


def main(args: argparse.Namespace) -> int:
    from glmav_observer.config import load_config
    from glmav_toml import ConfigError

    files, skipped = expand_paths(args.paths)
    missing = [f for f in files if not f.is_file()]
    if missing:
        print(f"glmav-observer batch: {missing[0]}: no such file", file=sys.stderr)
        return 2
    if not files:
        print("glmav-observer batch: no log files under the paths given", file=sys.stderr)
        return 2
    import importlib.util

    needed = ["matplotlib"] + (["distributed"] if args.cluster else [])
    absent = [m for m in needed if importlib.util.find_spec(m) is None]
    if absent:
        print(
            f"glmav-observer batch: {', '.join(absent)} not installed: "
            "pip install 'glmav-observer[batch]'",
            file=sys.stderr,
        )
        return 2
    try:
        load_config(args.config)
    except ConfigError as err:
        print(f"glmav-observer batch: {err}", file=sys.stderr)
        return 2
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        print(f"glmav-observer batch: {out}: {err.strerror}", file=sys.stderr)
        return 2
    try:
        rows = run_batch(
            files,
            out,
            config_path=args.config,
            velocity_source=args.velocity_source,
            workers=args.workers,
            cluster=args.cluster,
            progress=None if args.no_progress else _progress,
        )
    except (OSError, TimeoutError) as err:
        where = f"cluster {args.cluster}" if args.cluster else "process pool"
        print(f"glmav-observer batch: {where}: {err}", file=sys.stderr)
        return 2
    n_err = sum(1 for r in rows if r.get("error"))
    print(f"{len(rows)} logs, {n_err} not replayed; wrote {out}/records/, summary.csv, report.html")
    if skipped:
        print(f"skipped {skipped} files in the folders given that are not logs")
    for r in rows:
        state = (
            f"ERROR {r['error']}"
            if r.get("error")
            else (
                f"{r.get('vehicle')}, {r.get('duration_s')} s, faults: {r.get('faults') or 'none'}, "
                f"RMSE vs {r.get('rmse_basis')} (n, e, d) = "
                f"{r.get('rmse_active_n')}, {r.get('rmse_active_e')}, {r.get('rmse_active_d')} m/s"
            )
        )
        print(f"  {r['log_id']}: {state}")
    return 0
