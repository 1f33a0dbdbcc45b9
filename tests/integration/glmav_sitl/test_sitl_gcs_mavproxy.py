"""MAVProxy (the real ground station, driven through its console) flies the simulator.

``glmav-sitl run`` without a scenario in a subprocess; MAVProxy in another, reading commands
on stdin. Each command is sent once MAVProxy has printed what the previous one produced.
"""

from __future__ import annotations

import math
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from glmav_sitl.config import data_path
from glmav_sitl.gcs.params import default_params
from glmav_sitl.params import load_vehicle_params

#: stream rates of a telemetry radio link (Hz), not the estimator's
GCS_LINK_RATES_HZ = {
    "raw_imu": 0.0,
    "scaled_imu": 0.0,
    "highres_imu": 50.0,
    "attitude": 20.0,
    "local_position_ned": 10.0,
    "sim_state": 0.0,
}


class Console:
    """A MAVProxy process: ``send`` a command line, ``expect`` a line matching a pattern."""

    def __init__(self, cmd: list[str], cwd: Path) -> None:
        self.proc = subprocess.Popen(
            cmd,
            cwd=cwd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def expect(self, pattern: str, timeout_s: float) -> re.Match[str]:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"MAVProxy did not print {pattern!r}: {self.seen[-30:]}")
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                continue
            self.seen.append(line)
            m = rx.search(line)
            if m is not None:
                return m

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10.0)


@pytest.mark.timeout(150)
def test_mavproxy_reads_sets_params_arms_takes_off_and_lands(
    tmp_path: Path, free_udp_port: Callable[[], int]
) -> None:
    mavproxy = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    assert mavproxy is not None, "MAVProxy is in the test extra: pip install -e '.[test]'"
    port = free_udp_port()
    n_params = len(
        default_params(
            load_vehicle_params(),
            velocity_sigma_mps=0.05,
            max_speed_mps=8.0,
            on_change=lambda n, v: None,
        )
    )
    gcs = Console(
        [
            sys.executable,
            mavproxy,
            f"--master=udpin:127.0.0.1:{port}",
            "--no-state",
            "--default-modules=param,cmdlong,arm,mode",
        ],
        tmp_path,
    )
    # MAVProxy is one Python thread parsing everything it hears: on a loaded machine the
    # default 900 messages/s can overflow its socket and lose an answer; a radio link's rates
    sitl_toml = tmp_path / "sitl.toml"
    text = data_path("sitl.toml").read_text(encoding="utf-8")
    for name, hz in GCS_LINK_RATES_HZ.items():
        # the first occurrence: [rates_hz] (the autopilot profile has its own rates below)
        text, n = re.subn(rf"(?m)^{name} = [0-9.]+", f"{name} = {hz}", text, count=1)
        assert n == 1, name
    sitl_toml.write_text(text, encoding="utf-8")
    sitl = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "glmav_sitl.cli",
            "run",
            "--link",
            f"udpout:127.0.0.1:{port}",
            "--duration",
            "100",
            "--config",
            str(sitl_toml),
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        gcs.expect(r"online system 1", 20.0)
        gcs.send("param fetch")
        m = gcs.expect(r"Received (\d+) parameters", 20.0)
        assert int(m.group(1)) == n_params
        gcs.send("param show VEH_M")
        m = gcs.expect(r"VEH_M\s+(\S+)$", 5.0)
        assert float(m.group(1)) == pytest.approx(load_vehicle_params().m, rel=1e-6)
        gcs.send("param set MPC_LAND_SPEED 3")
        # MAVProxy shows its cached copy, updated by the vehicle's PARAM_VALUE answer
        deadline = time.monotonic() + 10.0
        value = math.nan
        while value != 3.0 and time.monotonic() < deadline:
            time.sleep(0.2)  # the console is polled; the answer arrives meanwhile
            gcs.send("param show MPC_LAND_SPEED")
            value = float(gcs.expect(r"MPC_LAND_SPEED\s+(\S+)$", 5.0).group(1))
        assert value == 3.0
        gcs.send("arm throttle")
        gcs.expect(r"COMPONENT_ARM_DISARM: ACCEPTED", 10.0)
        gcs.expect(r"AP: armed", 5.0)
        gcs.send("takeoff 5")  # cmdlong's takeoff: NAV_TAKEOFF, height above home
        gcs.expect(r"NAV_TAKEOFF: ACCEPTED", 10.0)
        gcs.expect(r"AP: takeoff complete", 20.0)
        # HOLD at 5 m: MAVProxy's latest GLOBAL_POSITION_INT settles there (mm; 5 cm: the
        # position loop's residual after a few time constants of 1 s)
        deadline = time.monotonic() + 10.0
        rel_alt_mm = 0
        while abs(rel_alt_mm - 5000) > 50 and time.monotonic() < deadline:
            gcs.send("status GLOBAL_POSITION_INT")
            m = gcs.expect(r"GLOBAL_POSITION_INT \{.*relative_alt : (-?\d+)", 5.0)
            rel_alt_mm = int(m.group(1))
            time.sleep(0.2)  # the console is polled; the vehicle settles meanwhile
        assert rel_alt_mm == pytest.approx(5000, abs=50)
        # issue 31 D14: HEARTBEAT says PX4, so MAVProxy names the modes (HOLD is PX4's
        # LOITER). Its `mode NAME` hands pymavlink PX4's (base, main, sub) tuple where a
        # number is expected ("required argument is not a float", MAVProxy 1.8.75 with any
        # PX4 vehicle): the mode is set with PX4's DO_SET_MODE numbers (main 4, sub 6)
        gcs.send("status HEARTBEAT")
        m = gcs.expect(r"HEARTBEAT \{.*autopilot : (\d+)", 5.0)
        assert int(m.group(1)) == 12  # MAV_AUTOPILOT_PX4
        gcs.send("long DO_SET_MODE 1 4 6")
        gcs.expect(r"DO_SET_MODE: ACCEPTED", 10.0)
        gcs.expect(r"^(\S+> )*Mode LAND$", 5.0)
        shown = {ln.rsplit(" ", 1)[-1] for ln in gcs.seen if re.search(r"(^|> )Mode \S+$", ln)}
        assert shown == {"LOITER", "TAKEOFF", "LAND"}, gcs.seen[-30:]
        gcs.expect(r"AP: landed", 20.0)
        gcs.expect(r"AP: disarmed", 5.0)
    finally:
        gcs.close()
        sitl.terminate()
        out, err = sitl.communicate(timeout=20.0)
    assert sitl.returncode == 0, err[-2000:]
    # the simulator's own summary: back on the ground, commands counted
    m2 = re.search(r"(\d+) commands; final NED position \(([^)]*)\)", out)
    assert m2 is not None, out
    assert int(m2.group(1)) >= 3
    assert float(m2.group(2).split(",")[2]) == 0.0
