"""``glmav-sitl``: a simulated GLMAV that speaks MAVLink 2 like an autopilot.

Without ``--scenario`` it starts on the ground at home, disarmed, and flies what a ground
station (MAVSDK, MAVProxy, QGroundControl) commands: arm, takeoff, land, RTL, hold,
offboard setpoints, parameters (sensor noise, velocity fault injection). With
``--scenario`` it flies the scenario's setpoints, as recorded flights and tests do.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import threading
from collections.abc import Sequence

from glmav_sitl.config import packaged_files
from glmav_sitl.mavlink.links import LinkError
from glmav_sitl.params import load_vehicle_params
from glmav_sitl.runner import parse_speed, run
from glmav_sitl.scenario import SENSOR_PROFILES, load_scenario, load_sitl_config, scenario_names
from glmav_sitl.stop import stop_on_signals
from glmav_toml import ConfigError

log = logging.getLogger("glmav_sitl")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("glmav-observer")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="glmav-sitl", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    ap.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser(
        "run",
        help="fly (for a ground station, or a scenario) and stream MAVLink",
        description="Stream MAVLink on the given links. Without --scenario: on the ground, "
        "disarmed, flying what a ground station commands, until stopped (Ctrl-C) or --duration. "
        "With --scenario: the scenario's flight, for its duration.",
    )
    r.add_argument(
        "--scenario",
        default=None,
        help=f"a name ({', '.join(scenario_names())}) or a path to a .toml file "
        "(default: none, a ground station flies the vehicle)",
    )
    r.add_argument(
        "--duration",
        type=float,
        default=None,
        help="seconds of sim time (default: the scenario's; without a scenario, until stopped)",
    )
    r.add_argument("--speed", default="realtime", help="realtime | max | FACTOR (e.g. 10)")
    r.add_argument(
        "--link",
        action="append",
        default=[],
        metavar="CONN",
        help="connection string, repeatable: udpout:HOST:PORT, udpin:HOST:PORT, tcp:, tcpin:",
    )
    r.add_argument(
        "--sensor-profile",
        choices=SENSOR_PROFILES,
        default=None,
        help="ideal (truth + noise) or autopilot (vibrating 50 Hz IMU, estimated attitude, "
        "filtered lagging GPS); default: the scenario's sensor_profile",
    )
    r.add_argument("--tlog", default=None, help="write the MAVLink stream to this .tlog")
    r.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    r.add_argument("--config", default=None, help="sitl.toml (default: the packaged one)")
    r.add_argument("--vehicle", default=None, help="vehicle parameter file (default: glmav.toml)")
    r.add_argument("--sysid", type=int, default=None, help="MAVLink system id (1-255)")
    r.add_argument(
        "--dt", type=float, default=None, help="physics step, s (default: scenario / sitl.toml)"
    )
    r.add_argument(
        "--signing-key",
        default=None,
        metavar="HEX",
        help="sign outgoing MAVLink 2 packets with this 32-byte key (64 hex digits)",
    )
    f = sub.add_parser(
        "fleet", help="replay recorded .tlog files as K vehicles (a traffic generator)"
    )
    f.add_argument("--tlog", action="append", required=True, metavar="LOG",
                   help="a recorded .tlog, repeatable (vehicle k replays log k mod n)")  # fmt: skip
    f.add_argument("--vehicles", type=int, default=1, help="K vehicles (default 1)")
    f.add_argument("--link", action="append", required=True, metavar="CONN",
                   help="udpout:HOST:PORT, tcp:HOST:PORT or tcpin:HOST:PORT; repeat to fan out")  # fmt: skip
    f.add_argument("--sysid-base", type=int, default=1, help="system id of vehicle 0 (default 1)")
    f.add_argument("--duration", type=float, default=None, help="stop after S s (default: log end)")
    f.add_argument("--speed", type=float, default=1.0, help="rate factor (default 1: as recorded)")
    f.add_argument("--stagger", type=float, default=1.0, metavar="S",
                   help="vehicle starts spread over S s, each at its own phase of the log (default 1)")  # fmt: skip
    sub.add_parser(
        "scenarios",
        help="list the packaged scenarios",
        description="List the packaged scenarios with their descriptions.",
    )
    sub.add_parser(
        "files",
        help="print the paths of the packaged default files",
        description="Print the paths of the packaged sitl.toml, vehicle file and scenarios "
        "(the one copy of each): copy one, edit it and pass it with --config, --vehicle "
        "or --scenario PATH.",
    )
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    if args.command == "fleet":
        from glmav_sitl.fleet import main as fleet_main

        return fleet_main(args)
    if args.command == "files":
        for path in packaged_files():
            print(path)
        return 0
    if args.command == "scenarios":
        for name in scenario_names():
            print(f"{name}: {load_scenario(name).description}")
        return 0
    try:
        speed = parse_speed(args.speed)
        if args.sysid is not None and not 1 <= args.sysid <= 255:
            raise ValueError("--sysid must be in 1..255")
        key = None
        if args.signing_key is not None:
            key = bytes.fromhex(args.signing_key)
            if len(key) != 32:
                raise ValueError("--signing-key must be 32 bytes (64 hex digits)")
        scenario = None if args.scenario is None else load_scenario(args.scenario)
        if scenario is not None and args.sensor_profile is not None:
            scenario = dataclasses.replace(scenario, sensor_profile=args.sensor_profile)
        profile = args.sensor_profile  # also for a ground-station flight (no scenario)
        sitl = load_sitl_config(args.config)
        params = load_vehicle_params(args.vehicle)
    except ConfigError as e:
        print(f"glmav-sitl: config error: {e}", file=sys.stderr)
        return 2
    except ValueError as e:
        print(f"glmav-sitl: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    stop_on_signals(stop)
    log.info(
        "flying %s -> %s",
        f"for a ground station, {profile or 'ideal'} sensors"
        if scenario is None
        else f"{scenario.name} ({scenario.source}), {scenario.sensor_profile} sensors",
        ", ".join(args.link) or "no link",
    )
    try:
        summary = run(
            scenario,
            args.link,
            args.duration,
            "max" if speed is None else speed,
            args.seed,
            args.tlog,
            args.sysid,
            stop,
            params=params,
            sitl=sitl,
            dt_s=args.dt,
            signing_key=key,
            sensor_profile=profile,
        )
    except LinkError as e:
        print(f"glmav-sitl: link error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"glmav-sitl: {e}", file=sys.stderr)
        return 1
    tr = summary.final_truth
    sent = sum(summary.messages_sent.values())
    print(
        f"{summary.scenario}: {summary.sim_time_s:.2f} s simulated in {summary.wall_time_s:.2f} s "
        f"({summary.realtime_factor:.1f}x real time), {summary.steps} steps of {summary.dt_s:g} s, "
        f"{sent} messages, {summary.commands_received} commands"
        + (f"; final NED position {tuple(round(v, 2) for v in tr.p_ned_m)} m" if tr else "")
    )
    est = summary.received_estimates
    if est is not None and est.heartbeats:
        comps = ", ".join(
            f"{s}/{c} (type {t})" for (s, c), (t, _a) in sorted(est.heartbeats.items())
        )
        print(
            f"other components: {comps}; {len(est.texts)} STATUSTEXT, "
            f"{sum(len(v) for v in est.named_values.values())} NAMED_VALUE_FLOAT"
        )
    if est is not None and est.count:
        rmse = est.rmse_ned_mps()
        counts = ", ".join(f"{n} {k}" for k, n in sorted(est.count.items()))
        srcs = ", ".join(f"{s}/{c}" for s, c in sorted(est.sources))
        print(
            f"received estimates: {counts} from {srcs}"
            + (
                f"; velocity RMSE against truth N/E/D {rmse[0]:.3f}/{rmse[1]:.3f}/{rmse[2]:.3f} m/s"
                f" over {est.compared}"
                if rmse is not None
                else ""
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
