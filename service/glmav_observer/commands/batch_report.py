"""The outputs of ``batch`` (:mod:`glmav_observer.commands.batch`): a log's plot (velocity
against the measurement and the reference, residuals, fault windows shaded; a PNG), and
the dataset, summary table and static HTML report written for all logs.
"""

from __future__ import annotations

import base64
import functools
import html
import io
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: Points per line in a report plot (decimated beyond: the PNG is 800 px wide).
PLOT_MAX_POINTS = 2000


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


def plot_png(
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


class BatchWriteError(OSError):
    """Some outputs of the batch could not be written (a full disk): the message names
    each file and why; what was written is whole, nothing partial is left. ``rows``: the
    summary rows of the logs (set by the batch, to print them)."""

    rows: list[dict[str, Any]]


def _write_whole(target: Path, write: Callable[[Path], object]) -> str | None:
    """``write`` into a hidden file beside ``target``, renamed onto it when complete;
    on failure the hidden file is removed and the reason returned."""
    partial = target.with_name(f".{target.name}.partial")
    try:
        partial.unlink(missing_ok=True)  # a planted link there is removed, not followed
        write(partial)
        os.replace(partial, target)
    except OSError as err:
        partial.unlink(missing_ok=True)
        return f"{target}: not written ({err.strerror or err})"
    return None


def _write_parquet(table: Any, path: Path) -> None:
    import pyarrow.parquet as pq  # type: ignore[import-untyped]  # no stubs

    pq.write_table(table, path)


def write_outputs(results: list[dict[str, Any]], out: Path) -> None:
    """The Parquet dataset, the summary and the report; each file whole or absent
    (written under a hidden name, renamed when complete). A file that cannot be written
    (a full disk) does not stop the others, and a log whose Parquet file failed says so
    in the summary (``records_not_written``): :class:`BatchWriteError` lists them all."""
    import csv

    failed: list[str | None] = []
    rec_dir = out / "records"
    rec_dir.mkdir(parents=True, exist_ok=True)
    for r in results:
        if r["table"] is not None:
            table = r["table"]
            problem = _write_whole(
                rec_dir / f"{r['row']['log_id']}.parquet", functools.partial(_write_parquet, table)
            )
            if problem is not None:  # the summary says so for this log
                r["row"]["records_not_written"] = problem
            failed.append(problem)
    rows = [r["row"] for r in results]
    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]

    def summary_csv(path: Path) -> None:
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=columns, lineterminator="\n")
            w.writeheader()
            for row in rows:
                w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in columns})

    failed.append(_write_whole(out / "summary.csv", summary_csv))
    failed.append(
        _write_whole(
            out / "summary.json",
            lambda p: p.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8"),
        )
    )
    failed.append(
        _write_whole(out / "report.html", lambda p: p.write_text(_html(results), encoding="utf-8"))
    )
    problems = [f for f in failed if f is not None]
    if problems:
        raise BatchWriteError("; ".join(problems))


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
        "<th>log</th><th>format</th><th>firmware</th><th>vehicle</th><th>duration (s)</th>"
        "<th>rates (Hz): att. / IMU / GPS / EKF / truth</th><th>velocity, GPS delay</th>"
        "<th>reference</th><th>faults isolated (s into the log)</th><th>switches</th>"
        "<th>RMSE n / e / d (m/s), against</th><th>full vs EKF in flight n / e / d</th>"
    )
    body = []
    for r in results:
        row = r["row"]
        log = f"<a href='#{esc(row['log_id'])}'>{esc(row['log_id'])}</a>"
        if row.get("error"):
            body.append(
                f"<tr class='error'><td>{log}</td><td>{esc(_fmt(row.get('format')))}</td>"
                f"<td colspan='10' class='text'>{esc(str(row['error']))}</td></tr>"
            )
            continue
        rates = " / ".join(_fmt(row.get(f"rate_{k}_hz"), 1) or "-" for k in
                           ("attitude", "imu", "gps", "ekf", "truth"))  # fmt: skip
        src = str(row.get("velocity_source") or "")
        if src == "gps":
            src += f", {_fmt(row.get('gps_delay_ms'), 0)} ms ({row.get('gps_delay_source')})"
        rmse = " / ".join(_fmt(row.get(f"rmse_active_{a}")) for a in "ned")
        flight = " / ".join(_fmt(row.get(f"rmse_full_in_flight_{a}")) for a in "ned")
        body.append(
            f"<tr><td>{log}</td><td>{esc(_fmt(row.get('format')))}</td>"
            f"<td>{esc(_fmt(row.get('vehicle')))}</td><td>{esc(_fmt(row.get('vehicle_type')))}</td>"
            f"<td>{_fmt(row.get('duration_s'), 1)}</td><td>{esc(rates)}</td><td>{esc(src)}</td>"
            f"<td>{esc(_fmt(row.get('reference')) or 'none')}</td>"
            f"<td class='text'>{esc(row.get('faults') or 'none')}</td>"
            f"<td>{_fmt(row.get('switches'))}</td>"
            f"<td>{esc(rmse)}, {esc(_fmt(row.get('rmse_basis')))}</td><td>{esc(flight)}</td></tr>"
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
