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
from dataclasses import dataclass, field, replace
from pathlib import Path

from glmav_sitl.dynamics.model import ModelOptions
from glmav_sitl.mavlink.links import Link, open_link
from glmav_sitl.mavlink.vehicle import MavlinkVehicle, ReceivedEstimates
from glmav_sitl.params import VehicleParams, load_vehicle_params
from glmav_sitl.scenario import (
    Scenario,
    Setpoint,
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
    received_estimates: ReceivedEstimates | None = None
    statustexts: list[str] = field(default_factory=list)

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


def ground_scenario() -> Scenario:
    """Ground-station flight: on the ground at home, rotors stopped, waiting for commands."""
    return replace(
        load_scenario("hover"),
        name="ground-station",
        description="On the ground at home, disarmed; flies what a ground station commands",
        position_ned_m=(0.0, 0.0, 0.0),
        rotor_radps=(0.0, 0.0),
        setpoints=(Setpoint(0.0, "idle"),),
        source="<ground-station flight>",
    )


def run(  # noqa: PLR0917 (the positional order is the documented API of issue #3)
    scenario: Scenario | str | None = "hover",
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
    sensor_profile: str | None = None,
) -> RunSummary:
    """Fly ``scenario`` for ``duration_s`` (default: the scenario's), streaming MAVLink.

    ``scenario=None``: ground-station flight (:mod:`glmav_sitl.gcs.autopilot`): on the
    ground, disarmed, flying what a ground station commands, until ``duration_s`` or
    ``stop_event`` (no duration: until stopped).

    ``speed``: ``"realtime"``, ``"max"`` (as fast as possible) or a factor. Links are
    connection strings (``udpout:127.0.0.1:14550``) or already-open :class:`Link`\\ s
    (closed here only if opened here). ``started`` is set once the links are open.
    ``sensor_profile`` overrides the scenario's (also for a ground-station flight).
    """
    gcs_flight = scenario is None
    if scenario is None:
        sc = ground_scenario()
    else:
        sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    if sensor_profile is not None:
        sc = replace(sc, sensor_profile=sensor_profile)
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
            ground_station_flight=gcs_flight,
        )
        autopilot = vehicle.autopilot
        if started is not None:
            started.set()
        if duration_s is not None:
            end_us = round(duration_s * 1e6)
        else:
            end_us = 1 << 62 if gcs_flight else round(sc.duration_s * 1e6)
        poll_every = sim.control_every  # read inputs / pace once per control tick
        truth_every = max(1, round(truth_every_s / sim.dt_s))
        wall0 = time.perf_counter()
        stopped = False
        vehicle.poll_streams()
        if on_truth is not None:
            on_truth(sim.truth())
        advance: Callable[[int], None] = sim.advance
        if gcs_flight and autopilot is not None:
            ground = autopilot.after_step

            def advance(k: int) -> None:
                for _ in range(k):
                    sim.step()
                    ground()

        poll = vehicle.poll_streams
        tick = vehicle.tick
        dt_us = sim.dt_us
        while sim.t_us < end_us:
            # the physics steps up to the next step where something else is due (a stream,
            # a control period's inputs and pacing, a truth callback, the end), in one call;
            # the same steps as one at a time, with the same things done after each
            n = sim.n_steps
            t_us = sim.t_us
            k = poll_every - n % poll_every
            if on_truth is not None and truth_every - n % truth_every < k:
                k = truth_every - n % truth_every
            k_stream = -((t_us - vehicle.next_stream_us) // dt_us)  # ceil(wait / dt)
            if k_stream < k:
                k = k_stream if k_stream > 1 else 1
            k_end = -((t_us - end_us) // dt_us)
            k = min(k, k_end)
            advance(k)
            poll()
            n = sim.n_steps
            if on_truth is not None and n % truth_every == 0:
                on_truth(sim.truth())
            if n % poll_every == 0:
                tick()
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
            received_estimates=vehicle.received_estimates,
            statustexts=list(vehicle.statustexts_sent),
        )
