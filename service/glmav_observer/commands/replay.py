"""``glmav-observer replay LOG``: the service's pipeline over a recorded log.

The log is recognised by its content (:func:`glmav_observer.ingest.logfiles.detect_format`):
a MAVLink ``.tlog`` goes through MAVLink ingest, once a vehicle in it has been found to send
what the estimator needs (``ATTITUDE``, an IMU message and ``LOCAL_POSITION_NED``:
:mod:`glmav_observer.ingest.logfiles.tlog`); an ArduPilot dataflash (``.bin``/``.log``)
or PX4 ULog (``.ulg``) is read into the same samples (``--velocity-source gps|ekf``, GPS
delay from the log's parameters or estimated, ``--gps-delay S`` to impose one).

Deterministic (the vehicle's clock drives everything; two runs give byte-identical
``--out`` files), with a progress bar on stderr for long logs and a summary on stdout:
per configuration RMSE against SIM_STATE when the log has it, faults isolated,
switches, samples dropped and frames rejected. ``--rrd PATH`` saves a Rerun recording.
Exit codes: 0 done, 2 bad configuration, output path or log file (nothing in it could
be read as MAVLink; a damaged flight log; a log without what the estimator needs,
"unsupported: this log has no X"; each leaving no output), 1 an output failed while
writing (e.g. a full disk), 130/143/129 stopped by SIGINT/SIGTERM/SIGHUP (the summary says
where; the outputs end on whole records). ``--out`` and ``--rrd`` never write through a
link or onto a device; an existing file is overwritten only with ``--force``.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from glmav_observer.ingest.logfiles import FlightLog
    from glmav_observer.ingest.logfiles.tlog import TlogScan

#: Logs smaller than this get no progress bar.
PROGRESS_MIN_BYTES = 2_000_000


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "replay",
        help="run the estimator over a .tlog, dataflash .bin/.log or .ulg (deterministic)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("log", metavar="LOG", help=".tlog, ArduPilot .bin/.log or PX4 .ulg")
    p.add_argument("--out", default=None, metavar="PATH", help="write records to .csv or .jsonl")
    p.add_argument("--rrd", default=None, metavar="PATH", help="save a Rerun recording")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing --out/--rrd file (never a link or a device)")  # fmt: skip
    p.add_argument("--config", default=None, help="service.toml (default: built-in defaults)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--velocity-source",
        choices=("gps", "ekf"),
        default="gps",
        help="flight logs: the velocity measurement (default gps; ekf = the autopilot's EKF)",
    )
    p.add_argument(
        "--gps-delay",
        type=float,
        default=None,
        metavar="S",
        help="flight logs: the GPS velocity's latency in s (default: from the log's parameters, else estimated)",
    )
    p.set_defaults(func=main)


class _Progress:
    """A one-line progress bar on stderr, redrawn when the percentage changes."""

    def __init__(self) -> None:
        self._last = -1

    def __call__(self, done: int, total: int) -> None:
        pct = 100 * done // max(total, 1)
        if pct == self._last:
            return
        self._last = pct
        bar = "#" * (pct // 4)
        end = "\n" if done >= total else ""
        print(f"\rreplay [{bar:<25}] {pct:3d}%", end=end, file=sys.stderr, flush=True)


def main(args: argparse.Namespace) -> int:
    import signal
    import threading
    from pathlib import Path

    from glmav_observer.app_replay import replay_flight_log, replay_tlog
    from glmav_observer.app_sinks import open_sinks
    from glmav_observer.config import load_config
    from glmav_observer.ingest.logfiles import LogError, detect_format, read_flight_log
    from glmav_observer.ingest.logfiles.tlog import check_tlog
    from glmav_observer.publish.file_sink import FileSinkError
    from glmav_observer.publish.output_files import check_output_target
    from glmav_observer.stop import set_from_signal_handler
    from glmav_toml import ConfigError

    log = Path(args.log)
    if not log.is_file():
        print(f"glmav-observer replay: {log}: no such file", file=sys.stderr)
        return 2
    flight_log: FlightLog | None = None
    scan: TlogScan | None = None
    try:
        config = load_config(args.config)
        fmt = detect_format(log)
        # read before any output is created: a damaged or unusable log leaves none
        if fmt == "tlog":  # until a vehicle has sent all the estimator needs
            scan = check_tlog(log)
        else:
            for path in (args.out, args.rrd):
                if path:
                    check_output_target(path, force=args.force)
            flight_log = read_flight_log(log, args.velocity_source, gps_delay_s=args.gps_delay)
        sinks = open_sinks(
            config,
            out=args.out or "",
            zenoh_enabled=False,
            rerun_mode=f"save:{args.rrd}" if args.rrd else "off",
            recording_name=log.name,
            force=args.force,
        )
    except (ConfigError, LogError, FileSinkError, OSError, ValueError) as err:
        print(f"glmav-observer replay: {err}", file=sys.stderr)
        return 2
    show = not args.no_progress and log.stat().st_size >= PROGRESS_MIN_BYTES
    if flight_log is not None:
        try:
            flight = replay_flight_log(
                flight_log, config, sinks, progress=_Progress() if show else None
            )
        except LogError as err:
            print(f"glmav-observer replay: {err}", file=sys.stderr)
            return 2
        print(flight.to_text())
        return 0
    stop = threading.Event()
    stopped_by: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        set_from_signal_handler(stop)

    signals = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    previous = {sig: signal.signal(sig, on_signal) for sig in signals}
    try:
        summary = replay_tlog(
            log, config, sinks, progress=_Progress() if show else None, stop_event=stop, scan=scan
        )
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if summary.messages == 0 and not summary.cut:
        counts = ", ".join(f"{k}={v}" for c in summary.link_counters.values() for k, v in c.items())
        print(
            f"glmav-observer replay: {log}: nothing could be read as MAVLink "
            f"({log.stat().st_size} bytes, 0 frames decoded{': ' + counts if counts else ''})",
            file=sys.stderr,
        )
        if args.out:  # nothing was written: no empty output is left
            Path(args.out).unlink(missing_ok=True)
        return 2
    print(summary.to_text())
    if stopped_by:
        print(f"glmav-observer replay: {summary.cut}: output cut short", file=sys.stderr)
        return 128 + stopped_by[0]
    if summary.failed_sinks:
        print("glmav-observer replay: an output failed: see SINK FAILED above", file=sys.stderr)
        return 1
    return 0
