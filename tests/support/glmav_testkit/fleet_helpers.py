"""Helpers of the fleet tests: a recorded log from the simulator, ports, waiting for queues."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

OBS = str(Path(sys.executable).with_name("glmav-observer"))
SITL = str(Path(sys.executable).with_name("glmav-sitl"))


def record_tlog(tmp: Path, seconds: float = 6.0, scenario: str = "hover") -> Path:
    """A log of the simulator at the design rates, with SIM_STATE truth (0.2 s CPU per s)."""
    from glmav_sitl.fleet import record_tlog as record

    return record(tmp / f"{scenario}-{seconds:g}s.tlog", seconds, scenario=scenario)


def record_fault_tlog(
    tmp: Path, seconds: float, *, axis: str, kind: str, t_start_s: float, magnitude: float = 0.0
) -> Path:
    """:func:`record_tlog` of a hover with a velocity-sensor fault on ``axis`` from
    ``t_start_s`` to the end (the scenario's faults replaced)."""
    from dataclasses import replace

    from glmav_sitl.fleet import DESIGN_RATES_HZ
    from glmav_sitl.runner import run
    from glmav_sitl.scenario import Fault, load_scenario, load_sitl_config

    scenario = load_scenario("hover")
    fault = Fault("velocity", kind, t_start_s, seconds + 1.0, axis, magnitude)
    scenario = replace(scenario, faults=(fault,))
    sitl = load_sitl_config()
    path = tmp / f"hover-{kind}-{axis}-{seconds:g}s.tlog"
    rates = {**sitl.rates_hz, **DESIGN_RATES_HZ}
    run(scenario, (), seconds, "max", 0, path, sitl=replace(sitl, rates_hz=rates))
    return path


def wait_bound_udp(port: int, proc: subprocess.Popen[str], timeout_s: float = 60.0) -> None:
    """Until ``proc`` has bound UDP ``port`` on 127.0.0.1 (an event, with a deadline)."""
    deadline = time.monotonic() + timeout_s
    while True:
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return
        finally:
            probe.close()
        if time.monotonic() > deadline or proc.poll() is not None:
            raise AssertionError(f"port {port} not bound: {proc.poll()}")
        time.sleep(0.05)


def wait_listening_tcp(port: int, proc: subprocess.Popen[str], timeout_s: float = 60.0) -> None:
    """Until TCP 127.0.0.1:``port`` is listening, read from /proc/net/tcp (a probe
    connection would be taken as the client by a one-client ``tcpin`` link)."""
    want = f"0100007F:{port:04X}"
    deadline = time.monotonic() + timeout_s
    while True:
        with open("/proc/net/tcp", encoding="ascii") as f:
            if any(
                cols[1] == want and cols[3] == "0A"  # 0A: LISTEN
                for cols in (line.split() for line in f.readlines()[1:])
            ):
                return
        if time.monotonic() > deadline or proc.poll() is not None:
            raise AssertionError(f"port {port} not listening: {proc.poll()}")
        time.sleep(0.05)


def udp_queue(port: int) -> tuple[int, int]:
    """(bytes waiting in the receive queues, datagrams dropped) of UDP 127.0.0.1:``port``,
    summed over its sockets (``serve --workers N``: one per worker, a reuseport group)."""
    want = f"0100007F:{port:04X}"
    queued = dropped = 0
    with open("/proc/net/udp", encoding="ascii") as f:
        for line in f.readlines()[1:]:
            cols = line.split()
            if cols[1] == want:
                queued += int(cols[4].split(":")[1], 16)
                dropped += int(cols[-1])
    return queued, dropped


def wait_drained(port: int, timeout_s: float = 120.0) -> int:
    """Until the service has read everything queued on ``port``; returns the kernel drops.

    The service reads as fast as its workers estimate: on a machine shared with other
    jobs that can take a while, hence the long deadline (an error, not a silent return)."""
    deadline = time.monotonic() + timeout_s
    while udp_queue(port)[0]:
        if time.monotonic() > deadline:
            raise AssertionError(f"UDP {port}: {udp_queue(port)[0]} bytes still unread")
        time.sleep(0.05)
    return udp_queue(port)[1]


def wait_drained_tcp(port: int, timeout_s: float = 120.0) -> None:
    """Until the connections to TCP 127.0.0.1:``port`` have nothing in flight: nothing
    left to send on the client side (tx queue), nothing left to read on the server side
    (rx queue)."""
    want = f"0100007F:{port:04X}"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        queued = 0
        with open("/proc/net/tcp", encoding="ascii") as f:
            for cols in (line.split() for line in f.readlines()[1:]):
                tx, rx = (int(x, 16) for x in cols[4].split(":"))
                if cols[1] == want and cols[3] != "0A":  # the server's side, not LISTEN
                    queued += rx
                elif cols[2] == want:  # the client's side
                    queued += tx
        if not queued:
            return
        time.sleep(0.05)
    raise AssertionError(f"TCP {port}: {queued} bytes still in flight after {timeout_s} s")


def frames_sent(fleet_stdout: str) -> int:
    m = re.search(r"(\d+) frames sent", fleet_stdout)
    assert m is not None, fleet_stdout
    return int(m.group(1))
