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
A log that fails, or is refused for lacking what the estimator needs (the ``refusal``
column, as ``replay`` words it), is reported in the summary and does not stop the batch. Every output
file is whole or absent (written under a hidden name, renamed when complete); pymavlink's
reports about a damaged dataflash log are counted in the summary, not printed. Exit
codes: 0 every log replayed, 1 some logs could not be replayed (the others' outputs are
written), 2 bad arguments, output folder, configuration or cluster, or an output that
could not be written (a full disk: the summary is still printed, the message names the
files).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from glmav_observer.commands.batch_log import process_log
from glmav_observer.commands.batch_report import BatchWriteError, write_outputs


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


def _log_to_file(path: str) -> None:
    """A worker's log lines go to the batch's log file, not across the progress bar (a
    pool worker starts with the parent's handler, on stderr)."""
    root = logging.getLogger()
    handler = logging.FileHandler(path, encoding="utf-8")
    formatter = root.handlers[0].formatter if root.handlers else None
    if formatter is not None:
        handler.setFormatter(formatter)
    root.handlers[:] = [handler]


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
        out.mkdir(parents=True, exist_ok=True)
        log_path = out / "batch.log"
        log_path.write_text("", encoding="utf-8")  # this batch's lines only
        with cf.ProcessPoolExecutor(
            max_workers=min(n, max(1, len(jobs))),
            initializer=_log_to_file,
            initargs=(str(log_path),),
        ) as pool:
            pending = [pool.submit(process_log, *j) for j in jobs]
            for fut in cf.as_completed(pending):
                results.append(fut.result())
                if progress is not None:
                    progress(len(results), len(jobs))
    results.sort(key=lambda r: ids.index(r["row"]["log_id"]))
    try:
        write_outputs(results, out)
    except BatchWriteError as err:
        err.rows = [r["row"] for r in results]
        raise
    return [r["row"] for r in results]


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
    write_error: str | None = None
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
    except BatchWriteError as err:  # the logs ran: their summary is still printed
        rows, write_error = err.rows, str(err)
    except (OSError, TimeoutError) as err:
        where = f"cluster {args.cluster}" if args.cluster else "process pool"
        print(f"glmav-observer batch: {where}: {err}", file=sys.stderr)
        return 2
    n_err = sum(1 for r in rows if r.get("error"))
    wrote = "could not write everything" if write_error else "wrote"
    logs = ", batch.log" if not args.cluster else ""
    print(
        f"{len(rows)} logs, {n_err} not replayed; {wrote} {out}/records/, summary.csv, "
        f"report.html{logs}"
    )
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
    if write_error:
        print(f"glmav-observer batch: {write_error}", file=sys.stderr)
        return 2
    if n_err:
        print(f"glmav-observer batch: {n_err} of {len(rows)} logs not replayed", file=sys.stderr)
        return 1
    return 0
