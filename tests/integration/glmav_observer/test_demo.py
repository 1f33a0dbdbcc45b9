"""The README's main command, `glmav-observer demo`, run as a user runs it (shortened).

Real parts: the simulator in a subprocess streaming MAVLink over UDP loopback, the service
with an in-process Zenoh peer, a Rerun recording saved to a file (no display in CI).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

#: a flight flown by MAVSDK at the simulator's real-time rate (or faster, `--speed auto`):
#: alone among the suite's workers, as a user runs it
pytestmark = pytest.mark.exclusive


def _run_demo(tmp_path: Path, *extra: str) -> str:
    rrd = tmp_path / "demo.rrd"
    cmd = [
        sys.executable, "-m", "glmav_observer.cli", "demo",
        "--duration", "22", "--fault-at", "10", "--fault-length", "4", "--speed", "auto",
        "--rerun", f"save:{rrd}", *extra,
    ]  # fmt: skip
    proc = subprocess.run(
        cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path, check=False
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


@pytest.mark.timeout(150)
@pytest.mark.parametrize(("axis", "kind"), [("e", "bias"), ("n", "freeze")])
def test_demo_isolates_the_fault_and_meets_the_daemon_bounds(
    tmp_path: Path, axis: str, kind: str
) -> None:
    out = _run_demo(tmp_path, "--fault-axis", axis, "--fault-kind", kind)

    # every frame the simulator sent arrived and parsed (loopback, 4 MiB receive buffer)
    m = re.search(r"(\d+) messages, (\d+) rejected; (\d+) records", out)
    assert m is not None, out
    messages, rejected, records = (int(g) for g in m.groups())
    # 22 s at 250 + 100 + 30 + 50 Hz (+ heartbeats) is about 9,500 messages
    assert messages > 9000
    assert rejected == 0
    assert records > 4 * 22 * 100  # five velocity records per estimator update, and more

    # MAVSDK flew it: the fault by parameters, armed, took off, the offboard turn, no error
    fl = re.search(r"^flown by MAVSDK: (.*)$", out, re.MULTILINE)
    assert fl is not None, out
    steps = fl.group(1)
    assert "stopped:" not in steps, steps
    for step in (f"fault {kind} on v{axis} set by parameters", "armed", "takeoff to 10 m"):
        assert step in steps
    turn = re.search(r"offboard climbing turn from 5 m \(t = ([\d.]+) s\)", steps)
    assert turn is not None and float(turn.group(1)) < 9.0, steps  # moving before the fault

    # Zenoh: the local subscriber saw the published velocity records, at the default rates
    # ([zenoh.rates]: active 50 Hz, each of the four configurations 10 Hz; aided while the
    # fault lasts, and active once more at each decision): 90 a second, 10 % slack for the
    # bank's start; at most 250 Hz x 6 streams would mean the rates were not applied
    z = re.search(r"Zenoh: (\d+) velocity records received", out)
    assert z is not None and 0.9 * 22 * 90 < int(z.group(1)) < 22 * (90 + 50), out

    # active estimate within the daemon issue's bound (0.1 m/s per axis against SIM_STATE)
    row = re.search(r"^active\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", out, re.MULTILINE)
    assert row is not None, out
    assert max(float(x) for x in row.groups()) <= 0.1, out

    # the fault: right axis, within 0.5 s of its onset at 10 s (daemon issue), no other axis
    iso = re.search(r"fault isolated: axis (\w) \((\w+)\) at t = ([\d.]+) s, ([\d.]+) s after", out)
    assert iso is not None, out
    assert iso.group(1) == axis
    assert iso.group(2) == kind
    assert 0.0 <= float(iso.group(4)) <= 0.5
    assert "also isolated" not in out, out

    # the switch to the configuration without that axis, no jump above 0.05 m/s (daemon
    # issue), and back to `full` once the axis has been healthy for recovery_s = 2 s after the
    # fault ends at 14 s (configs/service.toml [fdi]); the run ends at 22 s
    lost = {"n": "c2", "e": "c3", "d": "c1"}[axis]
    switches = re.findall(r"switch: (\w+) -> (\w+) at t = ([\d.]+) s \((\w+)\), jump ([\d.]+)", out)
    assert len(switches) == 2, out
    (f0, t0, ts0, why0, jump0), (f1, t1, ts1, why1, _) = switches
    assert (f0, t0, why0) == ("full", lost, f"{kind}_{axis}")
    assert float(ts0) == float(iso.group(3))
    assert float(jump0) <= 0.05
    assert (f1, t1, why1) == (lost, "full", "recovered")
    assert 16.0 <= float(ts1) < 22.0
    assert "active configuration at the end: full" in out

    # the recording is where the table says
    rrd = tmp_path / "demo.rrd"
    assert f"recording: {rrd}" in out
    assert rrd.stat().st_size > 100_000  # ~4 MB for 25 s; a header-only file is a few kB


@pytest.mark.timeout(120)
def test_a_failed_demo_keeps_the_previous_recording(tmp_path: Path) -> None:
    rrd = tmp_path / "demo.rrd"
    rrd.write_bytes(b"a good recording")
    # a simulator that cannot start (an unknown sensor profile): exit 2, the reason, no traceback
    proc = subprocess.run(
        [sys.executable, "-m", "glmav_observer.cli", "demo", "--rerun", f"save:{rrd}",
         "--sensor-profile", "no-such-profile", "--no-zenoh"],
        capture_output=True, text=True, timeout=100, cwd=tmp_path, check=False,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "simulator failed" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert rrd.read_bytes() == b"a good recording"
    # no partial left; the flight's log lines (MAVSDK's, the service's) are in demo.log
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.log", "demo.rrd"]


@pytest.mark.timeout(150)
def test_demo_on_the_autopilot_sensor_profile(tmp_path: Path) -> None:
    """The same demo on the simulator's `autopilot` sensors (issue 12): 50 Hz point-sampled
    vibrating RAW_IMU, ATTITUDE from an attitude estimator, LOCAL_POSITION_NED from a 10 Hz
    GPS through a filter, 150 ms late. Bounds from that profile, each with its reason."""
    out = _run_demo(
        tmp_path, "--fault-axis", "e", "--fault-kind", "bias", "--sensor-profile", "autopilot"
    )
    m = re.search(r"(\d+) messages, (\d+) rejected", out)
    assert m is not None, out
    # 22 s at 50 + 50 + 10 Hz (+ telemetry) is about 5,000 messages; ideal sends 4x more
    assert 4000 < int(m.group(1)) < 9000 and int(m.group(2)) == 0, out
    row = re.search(r"^active\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", out, re.MULTILINE)
    assert row is not None, out
    # the input lags truth by 150 ms in a 3 m/s, 0.3 rad/s turn (0.9 m/s²): ~0.13 m/s of
    # its own if nothing compensated it; the FDI's fit learns the lag and the bank takes
    # the measurement moved to the present (docs/design/observer-notes.md): measured 0.067-0.089 m/s
    # over 7 runs. Bound 0.15 m/s per axis: above the compensated figure with the
    # fault's 6 s of dead reckoning on e, about what an uncompensated lag alone costs.
    assert max(float(x) for x in row.groups()) <= 0.15, out
    iso = re.search(r"fault isolated: axis (\w) \((\w+)\) at t = ([\d.]+) s, ([\d.]+) s after", out)
    assert iso is not None and (iso.group(1), iso.group(2)) == ("e", "bias"), out
    # the first biased sample is up to 0.1 s (10 Hz) + 0.15 s (lag) late, and the bias
    # test needs 3 failing samples (0.2 s more at 10 Hz): bound 0.75 s (measured 0.40)
    assert 0.0 <= float(iso.group(4)) <= 0.75, out
    # no other velocity axis (an accelerometer event, axis "body", isolates nothing: the
    # take-off on the profile's vibrating IMU reported one at 4.1 s in 1 run of 9)
    assert re.search(r"also isolated: axis [ned] ", out) is None, out
    switches = re.findall(r"switch: (\w+) -> (\w+) at t = ([\d.]+) s \((\w+)\), jump ([\d.]+)", out)
    # No wrong call before the fault (the take-off's acceleration on a 150 ms late GPS
    # used to read as a bias on d for 1-3 s): the hand-over at the fault and the way back
    # once e has been healthy for recovery_s = 2 s after the fault ends at 14 s.
    assert [(a, b) for a, b, *_ in switches] == [("full", "c3"), ("c3", "full")], out
    assert switches[0][2] == iso.group(3), out
    assert 16.0 <= float(switches[1][2]) < 22.0, out
    # A jump is `full` against c3 at the same time, and on this profile they differ mostly
    # on the two *measured* axes (a replay of the demo flight: n 0.043, d 0.059, e 0.038
    # at the way back): c3's gain (70 s⁻¹ on n, d: γΔt = 1.4 at 50 Hz) follows each 10 Hz
    # GPS sample (σ 0.08 m/s, filtered: ~0.05) while `full` (γ 4-20) smooths it. Two axes
    # of that noise, 3σ: √2 · 0.05 · 3 ≈ 0.21 m/s. Hand-over (e seeded from the active
    # estimate: no jump of its own): bound 0.21; measured 0.017-0.053 over 10 runs (the
    # daemon issue's 0.05 is held on the ideal profile above, with 30 Hz σ 0.05 noise that
    # c3 averages over 8 IMU steps per sample). Way back, measured 0.063-0.180
    # over 8 runs: `full` restarts at γ = 4 (0.08 per step), plus e's first correction step
    # (8 % of a ~0.3 m/s drift): bound 0.25 m/s.
    assert float(switches[0][4]) <= 0.21, out
    assert float(switches[1][4]) <= 0.25, out
    assert "active configuration at the end: full" in out
