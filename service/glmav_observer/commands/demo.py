"""``glmav-observer demo``: the embedded default, one command from install to estimates.

It starts the simulator (``glmav-sitl run`` without a scenario, a subprocess: on the
ground, disarmed; MAVLink over UDP loopback is the only contract between the two) and flies
it through MAVSDK as a ground station would (:mod:`glmav_observer.commands.demo_mission`:
a velocity-sensor fault injected through parameters, arm, takeoff, an offboard climbing
turn). The service runs in this process with an in-process Zenoh peer and a Rerun recording
(a spawned viewer when one can be started, else ``demo.rrd``, replaced only when the demo
succeeds), and the demo ends with a table: RMSE per configuration against the simulator's
truth, the fault isolated and when, the switch, and where the recording is. No external
server, no manual step.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from glmav_observer.app import Service, serve
from glmav_observer.app_sinks import open_sinks
from glmav_observer.app_summary import ServiceSummary, rmse_table
from glmav_observer.commands.demo_mission import MissionLog, fly
from glmav_observer.config import ServiceConfig, load_config
from glmav_observer.publish.sink import Sink
from glmav_observer.publish.zenoh_sink import ZenohSink
from glmav_toml import ConfigError

logger = logging.getLogger(__name__)

FAULT_KINDS = ("bias", "freeze", "dropout", "noise")
#: Fault magnitude per kind: a 1 m/s bias step (above the 0.3 m/s the FDI must catch), a
#: noise burst of 2 m/s (40x the nominal 0.05 m/s); freeze and dropout have none.
FAULT_MAGNITUDE = {"bias": 1.0, "noise": 2.0, "freeze": 0.0, "dropout": 0.0}
#: How long the service may stay silent after the simulator has finished before the demo
#: stops it (host seconds): the loopback socket has drained by then.
DRAIN_QUIET_S = 0.3
#: ``--speed auto`` without a live viewer: 5x real time, about 2,200 MAVLink messages/s. Not
#: "max": an unthrottled simulator on a busy 2-core machine can outrun the service's UDP
#: socket, and the datagrams lost then look like sensor dropouts to fault isolation.
AUTO_SPEED_FACTOR = 5
DRAIN_MAX_S = 5.0


@dataclass
class DemoResult:
    """What the demo measured (also what its table prints)."""

    mission: MissionLog
    fault_axis: str
    fault_kind: str
    fault_at_s: float
    fault_end_s: float
    duration_s: float
    sim_wall_s: float
    summary: ServiceSummary
    sysid: int
    recording: str | None
    zenoh_received: int
    rows: list[tuple[str, float, float, float]] = field(default_factory=list)

    @property
    def first_isolation(self) -> dict[str, Any] | None:
        faults = self.summary.vehicles[self.sysid].faults
        hits = [f for f in faults if f["axis"] == self.fault_axis]
        return hits[0] if hits else None


def scenario_toml(
    duration_s: float,
    fault_axis: str,
    fault_kind: str,
    fault_at_s: float,
    fault_end_s: float,
    *,
    magnitude: float | None = None,
    name: str = "demo",
) -> str:
    """A climbing turn (3 m/s, 0.3 rad/s, climbing 0.5 m/s) with one velocity fault.

    ``magnitude``: m/s of a bias or a noise burst (default :data:`FAULT_MAGNITUDE`).
    """
    size = FAULT_MAGNITUDE[fault_kind] if magnitude is None else magnitude
    return f"""name = "{name}"
description = "Climbing turn with a {fault_kind} fault on LOCAL_POSITION_NED v{fault_axis} from {fault_at_s:g} s to {fault_end_s:g} s (glmav-observer demo)"
duration_s = {duration_s:g}

[initial]
position_ned_m = [0.0, 0.0, -10.0]

[[setpoints]]
t_s = 0.0
kind = "hold"
yaw_rad = 0.0

[[setpoints]]
t_s = 3.0
kind = "turn"
speed_mps = 3.0
turn_rate_radps = 0.3
climb_rate_mps = 0.5

[[faults]]
sensor = "velocity"
axis = "{fault_axis}"
kind = "{fault_kind}"
t_start_s = {fault_at_s:g}
t_end_s = {fault_end_s:g}
magnitude = {size:g}
"""


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def run_demo(
    *,
    duration_s: float = 25.0,
    fault_axis: str = "e",
    fault_kind: str = "bias",
    fault_at_s: float = 12.0,
    fault_length_s: float = 4.0,
    speed: str = "auto",
    seed: int = 1,
    rerun_mode: str = "spawn",
    rrd_path: str = "demo.rrd",
    zenoh: bool = True,
    config: ServiceConfig | None = None,
    sensor_profile: str | None = None,
) -> DemoResult:
    """Fly the demo mission through the simulator and the service; return what was measured.

    ``speed``: ``auto`` (real time when a live viewer is attached, else
    :data:`AUTO_SPEED_FACTOR` times real time), ``realtime``, ``max`` or a factor, passed to
    ``glmav-sitl run --speed``. ``sensor_profile`` is passed to ``glmav-sitl run
    --sensor-profile`` when given. A recording saved to a file replaces an existing one only
    when the demo succeeds (it is written to ``PATH.partial`` first).
    """
    if fault_axis not in ("n", "e", "d"):
        raise ValueError(f"fault axis must be n, e or d, got {fault_axis!r}")
    if fault_kind not in FAULT_KINDS:
        raise ValueError(f"fault kind must be one of {FAULT_KINDS}, got {fault_kind!r}")
    if not 0.0 < fault_at_s < duration_s:
        raise ValueError(f"fault time {fault_at_s} s must lie inside (0, {duration_s}) s")
    config = config if config is not None else load_config(None)
    fault_end_s = min(duration_s, fault_at_s + fault_length_s)
    # a file recording goes to PATH.partial, renamed over PATH once the demo has succeeded
    final_rrd = Path(
        rerun_mode.removeprefix("save:") if rerun_mode.startswith("save:") else rrd_path
    )
    partial_rrd = final_rrd.with_name(final_rrd.name + ".partial")
    if rerun_mode.startswith("save:"):
        rerun_mode = f"save:{partial_rrd}"
    mission: list[MissionLog] = []
    ok = False

    sinks: list[Sink] = []
    received = [0]
    subscriber: Any = None
    service: Service | None = None
    worker: threading.Thread | None = None
    stop = threading.Event()
    failure: list[BaseException] = []
    port, gcs_port = _free_udp_port(), _free_udp_port()
    conn = f"udpin:127.0.0.1:{port}"
    try:
        # composed as `serve` composes it (app_sinks.open_sinks, app.serve): no file output
        sinks = open_sinks(
            config,
            out="",
            zenoh_enabled=zenoh,
            rerun_mode=rerun_mode,
            recording_name="glmav-observer demo",
            rerun_fallback_save_path=str(partial_rrd),
            force=True,  # PATH.partial is the demo's own scratch name (a link is still refused)
        )
        zenoh_sink = next((s for s in sinks if isinstance(s, ZenohSink)), None) if zenoh else None
        if zenoh_sink is not None:
            # a subscriber on the sink's own session: proof that records leave on Zenoh
            def count(_sample: Any) -> None:
                received[0] += 1

            subscriber = zenoh_sink.session.declare_subscriber(
                f"{config.zenoh.prefix}/*/velocity/**", count
            )
        recording: str | None = None
        live_viewer = False
        if rerun_mode != "off":
            from glmav_observer.publish.rerun import RerunSink

            rerun_sink = next(s for s in sinks if isinstance(s, RerunSink))
            recording = rerun_sink.effective_mode
            live_viewer = not recording.startswith("save:")
        sim_speed = (
            ("realtime" if live_viewer else str(AUTO_SPEED_FACTOR)) if speed == "auto" else speed
        )
        service = Service(config, sinks)
        ready = threading.Event()

        def serve_until_stopped(svc: Service) -> None:
            try:
                serve(config, sinks, [conn], stop, service=svc, ready=ready)
            except BaseException as err:  # reported by the caller, not as a thread traceback
                failure.append(err)
                ready.set()

        worker = threading.Thread(
            target=serve_until_stopped, args=(service,), name="demo-service", daemon=True
        )
        worker.start()
        ready.wait(10.0)
        if failure:
            raise RuntimeError(f"the service could not start on {conn}: {failure[0]}")
        # the ground station: MAVSDK listening for the simulator on its own port
        mission_stop, listening = threading.Event(), threading.Event()
        flight = threading.Thread(
            target=lambda: mission.append(
                fly(
                    gcs_port,
                    fault_axis=fault_axis,
                    fault_kind=fault_kind,
                    fault_at_s=fault_at_s,
                    fault_end_s=fault_end_s,
                    magnitude=FAULT_MAGNITUDE[fault_kind],
                    stop=mission_stop,
                    connected=listening,
                )
            ),
            name="demo-mavsdk",
            daemon=True,
        )
        flight.start()
        listening.wait(10.0)
        cmd = [
            sys.executable, "-m", "glmav_sitl.cli", "run", "--duration", f"{duration_s:g}",
            "--speed", sim_speed, "--seed", str(seed),
            "--link", f"udpout:127.0.0.1:{port}", "--link", f"udpout:127.0.0.1:{gcs_port}",
            *(["--sensor-profile", sensor_profile] if sensor_profile else []),
        ]  # fmt: skip
        logger.info("starting simulator", extra={"cmd": " ".join(cmd)})
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        sim_wall_s = time.perf_counter() - t0
        mission_stop.set()
        flight.join(timeout=30.0)
        if proc.returncode != 0:
            raise RuntimeError(f"simulator failed ({proc.returncode}): {proc.stderr.strip()}")
        # drain: wait until the service has been quiet for DRAIN_QUIET_S
        last, quiet_since, deadline = -1, time.monotonic(), time.monotonic() + DRAIN_MAX_S
        while time.monotonic() < deadline:
            if service.messages != last:
                last, quiet_since = service.messages, time.monotonic()
            elif time.monotonic() - quiet_since >= DRAIN_QUIET_S:
                break
            stop.wait(0.05)
        ok = True
    finally:
        # the service thread stops (app.serve closes its link and the sinks) before
        # anything it uses goes away
        stop.set()
        if worker is not None:
            worker.join(timeout=10.0)
        if subscriber is not None:
            subscriber.undeclare()
        if service is None or worker is None:
            for s in sinks:
                s.close()
        if not ok:
            partial_rrd.unlink(missing_ok=True)  # an earlier good recording stays
    if failure:
        raise RuntimeError(f"the service failed: {failure[0]}")
    summary = service.summary()
    if not summary.vehicles:
        partial_rrd.unlink(missing_ok=True)
        raise RuntimeError("the service saw no vehicle: no MAVLink arrived on " + conn)
    if recording is not None and recording.startswith("save:"):
        # a recording the sink could not finish (a full disk) is removed by the sink
        rerun_failed = [err for name, err in summary.failed_sinks if name == "RerunSink"]
        if rerun_failed:
            raise RuntimeError(rerun_failed[0])  # an earlier good recording stays
        partial_rrd.replace(final_rrd)
        recording = f"save:{final_rrd}"
    sysid = min(summary.vehicles)
    return DemoResult(
        mission=mission[0] if mission else MissionLog(error="the MAVSDK thread did not end"),
        fault_axis=fault_axis,
        fault_kind=fault_kind,
        fault_at_s=fault_at_s,
        fault_end_s=fault_end_s,
        duration_s=duration_s,
        sim_wall_s=sim_wall_s,
        summary=summary,
        sysid=sysid,
        recording=recording,
        zenoh_received=received[0],
        rows=rmse_table(summary, sysid),
    )


def format_result(r: DemoResult) -> str:
    """The table the demo ends with."""
    v = r.summary.vehicles[r.sysid]
    out = [
        f"glmav-observer demo: climbing turn, {r.fault_kind} fault on measured v{r.fault_axis} "
        f"from t = {r.fault_at_s:g} s to {r.fault_end_s:g} s, {r.duration_s:g} s simulated "
        f"in {r.sim_wall_s:.1f} s",
        f"MAVLink over UDP loopback: {r.summary.messages} messages, "
        f"{r.summary.rejected_frames} rejected; {r.summary.records} records; "
        f"Zenoh: {r.zenoh_received} velocity records received by a local subscriber",
        r.mission.summary(),
        "",
        "RMSE against truth (SIM_STATE), m/s, NED",
        f"{'config':<8}{'north':>9}{'east':>9}{'down':>9}",
    ]
    for cfg, n, e, d in r.rows:
        out.append(f"{cfg:<8}{n:9.3f}{e:9.3f}{d:9.3f}")
    out.append("")
    iso = r.first_isolation
    if iso is not None:
        delay = iso["t_detect_s"] - r.fault_at_s
        out.append(
            f"fault isolated: axis {iso['axis']} ({iso['kind']}) at t = {iso['t_detect_s']:.3f} s,"
            f" {delay:.3f} s after onset"
        )
    else:
        out.append(f"fault NOT isolated on axis {r.fault_axis}")
    others = [f for f in v.faults if f is not iso]
    for f in others:
        out.append(f"also isolated: axis {f['axis']} ({f['kind']}) at t = {f['t_detect_s']:.3f} s")
    for sw in v.switches:
        jump = "n/a" if sw["jump_mps"] is None else f"{sw['jump_mps']:.3f} m/s"
        out.append(
            f"switch: {sw['from']} -> {sw['to']} at t = {sw['t_boot_s']:.3f} s "
            f"({sw['reason']}), jump {jump}"
        )
    out.append(f"active configuration at the end: {v.active_config}")
    if r.recording is None:
        out.append("recording: none (--rerun off)")
    elif r.recording.startswith("save:"):
        path = r.recording.removeprefix("save:")
        out.append(f"recording: {path}  (open it with: rerun {path})")
    else:
        out.append(f"recording: streamed to the Rerun viewer ({r.recording})")
    return "\n".join(out)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "demo",
        help="simulator + service + Zenoh + Rerun on loopback, with an injected fault",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--duration", type=float, default=25.0, help="simulated seconds (25)")
    p.add_argument("--fault-axis", choices=("n", "e", "d"), default="e")
    p.add_argument("--fault-kind", choices=FAULT_KINDS, default="bias")
    p.add_argument("--fault-at", type=float, default=12.0, help="fault onset, s (12)")
    p.add_argument(
        "--fault-length", type=float, default=4.0, help="fault duration, s (4); then recovery"
    )
    p.add_argument(
        "--speed",
        default="auto",
        help="auto (real time with a live viewer, else 5x), realtime, max or a factor",
    )
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--rerun",
        default="spawn",
        help="spawn (falls back to save:--rrd without a display), save:PATH, serve, off",
    )
    p.add_argument("--rrd", default="demo.rrd", help="where to save when no viewer starts")
    p.add_argument("--no-zenoh", action="store_true", help="do not open the Zenoh peer")
    p.add_argument("--config", default=None, help="service TOML (default: built-in settings)")
    p.add_argument(
        "--sensor-profile",
        default=None,
        help="passed to glmav-sitl run --sensor-profile (default: the simulator's)",
    )
    p.add_argument(
        "--log",
        default="demo.log",
        help="where the service's and MAVSDK's log lines go during the flight (demo.log)",
    )
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="show the log lines (the service's, MAVSDK's) on the terminal instead",
    )
    p.set_defaults(func=main)


@contextlib.contextmanager
def _stderr_to(path: str | None) -> Iterator[None]:
    """Send file descriptor 2 to ``path`` (this run's: truncated) for the block, then restore it.

    MAVSDK's C++ core and our log handler both write to stderr while the flight runs; the
    summary (stdout) should stand alone, as the README shows it. At the descriptor level,
    so the C++ lines follow too. ``None``: leave stderr alone (``--verbose``)."""
    if path is None:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    except OSError as err:
        os.close(saved)
        raise ValueError(f"--log {path}: {err.strerror}") from None
    try:
        os.dup2(fd, 2)
        os.close(fd)
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def main(args: argparse.Namespace) -> int:
    log_path = None if args.verbose else args.log
    try:
        config = load_config(args.config)
        with _stderr_to(log_path):
            result = _run(args, config)
    except (ConfigError, ValueError, RuntimeError) as err:
        where = f" (the log: {log_path})" if log_path is not None else ""
        print(f"glmav-observer demo: {err}{where}", file=sys.stderr)
        return 2
    print(format_result(result))
    iso = result.first_isolation
    return 0 if iso is not None and not math.isnan(result.rows[-1][1]) else 1


def _run(args: argparse.Namespace, config: ServiceConfig) -> DemoResult:
    return run_demo(
        duration_s=args.duration,
        fault_axis=args.fault_axis,
        fault_kind=args.fault_kind,
        fault_at_s=args.fault_at,
        fault_length_s=args.fault_length,
        speed=args.speed,
        seed=args.seed,
        rerun_mode=args.rerun,
        rrd_path=args.rrd,
        zenoh=not args.no_zenoh,
        config=config,
        sensor_profile=args.sensor_profile,
    )
