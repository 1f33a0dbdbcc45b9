"""Run a scenario: simulator + MAVLink streams + pacing, stoppable from another thread.

``run(...)`` is the one entry point used by the CLI, the tests, the demo and the
benchmarks. Start it in a thread with a :class:`threading.Event` to stop it, or in a
subprocess via ``glmav-sitl run``. Truth is available in-process through
``on_truth(TruthState)``, called every ``truth_every_s`` of sim time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

from glmav_sitl.dynamics.model import ModelOptions
from glmav_sitl.mavlink.links import Link, open_link
from glmav_sitl.mavlink.vehicle import MavlinkVehicle
from glmav_sitl.params import VehicleParams, load_vehicle_params
from glmav_sitl.scenario import (
    Scenario,
    SitlConfig,
    effective_rates,
    load_scenario,
    load_sitl_config,
)
from glmav_sitl.simulator import Simulator, TruthState

log = logging.getLogger(__name__)


@dataclass
class RunSummary:
    scenario: str
    sim_time_s: float
    wall_time_s: float
    steps: int
    dt_s: float
    messages_sent: dict[str, int] = field(default_factory=dict)
    commands_received: int = 0
    bad_input: int = 0
    stopped_early: bool = False
    final_truth: TruthState | None = None

    @property
    def realtime_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else float("inf")


def parse_speed(speed: str | float | None) -> float | None:
    """``"realtime"`` -> 1.0, ``"max"`` -> None (as fast as possible), a number -> factor."""
    if speed is None or speed == "max":
        return None
    if speed == "realtime":
        return 1.0
    f = float(speed)
    if not f > 0.0:
        raise ValueError(f"speed factor must be > 0, got {speed!r}")
    return f


def run(  # noqa: PLR0917 (the positional order is the documented API of issue #3)
    scenario: Scenario | str = "hover",
    links: Sequence[str | Link] = (),
    duration_s: float | None = None,
    speed: str | float | None = "realtime",
    seed: int = 0,
    tlog_path: str | Path | None = None,
    sysid: int | None = None,
    stop_event: threading.Event | None = None,
    *,
    params: VehicleParams | None = None,
    sitl: SitlConfig | None = None,
    dt_s: float | None = None,
    model_options: ModelOptions | None = None,
    on_truth: Callable[[TruthState], None] | None = None,
    truth_every_s: float = 0.004,
    signing_key: bytes | None = None,
    started: threading.Event | None = None,
) -> RunSummary:
    """Fly ``scenario`` for ``duration_s`` (default: the scenario's), streaming MAVLink.

    ``speed``: ``"realtime"``, ``"max"`` (as fast as possible) or a factor. Links are
    connection strings (``udpout:127.0.0.1:14550``) or already-open :class:`Link`\\ s
    (closed here only if opened here). ``started`` is set once the links are open.
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    sitl = sitl or load_sitl_config()
    params = params or load_vehicle_params()
    factor = parse_speed(speed)
    stop = stop_event or threading.Event()
    with ExitStack() as stack:
        opened: list[Link] = []
        for spec in links:
            if isinstance(spec, str):
                lk = open_link(spec)
                stack.callback(lk.close)
                opened.append(lk)
            else:
                opened.append(spec)
        tlog = None
        if tlog_path is not None:
            tlog = stack.enter_context(Path(tlog_path).open("wb"))
        sim = Simulator(
            sc, params=params, sitl=sitl, seed=seed, dt_s=dt_s, model_options=model_options
        )
        vehicle = MavlinkVehicle(
            sim,
            opened,
            rates_hz=effective_rates(sitl, sc),
            sysid=sysid if sysid is not None else sitl.sysid,
            compid=sitl.compid,
            tlog=tlog,
            signing_key=signing_key,
        )
        if started is not None:
            started.set()
        duration = sc.duration_s if duration_s is None else duration_s
        end_us = round(duration * 1e6)
        poll_every = sim.control_every  # read inputs / pace once per control tick
        truth_every = max(1, round(truth_every_s / sim.dt_s))
        wall0 = time.perf_counter()
        stopped = False
        vehicle.poll_streams()
        if on_truth is not None:
            on_truth(sim.truth())
        step = sim.step
        poll = vehicle.poll_streams
        while sim.t_us < end_us:
            step()
            poll()
            n = sim.n_steps
            if on_truth is not None and n % truth_every == 0:
                on_truth(sim.truth())
            if n % poll_every == 0:
                if opened:
                    vehicle.poll_inputs()
                if stop.is_set():
                    stopped = True
                    break
                if factor is not None:
                    lag = sim.t_s / factor - (time.perf_counter() - wall0)
                    if lag > 0.002 and stop.wait(lag):
                        stopped = True
                        break
        wall = time.perf_counter() - wall0
        if tlog is not None:
            tlog.flush()
        return RunSummary(
            scenario=sc.name,
            sim_time_s=sim.t_s,
            wall_time_s=wall,
            steps=sim.n_steps,
            dt_s=sim.dt_s,
            messages_sent=dict(vehicle.stats.sent),
            commands_received=vehicle.stats.commands,
            bad_input=vehicle.stats.bad_input,
            stopped_early=stopped,
            final_truth=sim.truth(),
        )
