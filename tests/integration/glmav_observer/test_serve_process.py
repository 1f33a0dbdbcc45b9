"""``glmav-observer serve`` as a process: SIGINT stops it cleanly with the file flushed;
it asks the vehicle for its rates (the SITL counts our SET_MESSAGE_INTERVAL commands)."""

from __future__ import annotations

import csv
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

OBS = str(Path(sys.executable).with_name("glmav-observer"))
SITL = str(Path(sys.executable).with_name("glmav-sitl"))


@pytest.mark.timeout(120)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serve_stops_cleanly_and_flushes(
    sig: signal.Signals, free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    port = free_udp_port()
    out = tmp_path / "live.csv"
    serve = subprocess.Popen(
        # one process: the rate requests and the summary below are the single service's
        [OBS, "serve", "--workers", "1", "--link", f"udpin:127.0.0.1:{port}", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        _wait_bound(serve, port)
        sitl = subprocess.run(
            # real time: the first requests come 2-3 s after the vehicle is heard (a window,
            # then the next 1 s check); at speed 2 the flight was over after 3 s of wall time,
            # and on a loaded machine sometimes before them (0 commands)
            [SITL, "run", "--scenario", "hover", "--duration", "6", "--speed", "1",
             "--link", f"udpout:127.0.0.1:{port}"],
            check=False, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert sitl.returncode == 0, sitl.stderr
        m = re.search(r"(\d+) commands", sitl.stdout)
        # the simulator already streams what the estimator needs ([rates.min_hz]): the
        # service asks for none of it (it used to send 4 SET_MESSAGE_INTERVAL on sight), only
        # once for the two aiding streams glmav-sitl does not send (EKF_STATUS_REPORT,
        # GPS_RAW_INT: what an autopilot's velocity rests on), each after a query of its
        # interval (GET_MESSAGE_INTERVAL: what the service restores when it stops)
        assert m is not None and int(m.group(1)) == 4
    finally:
        serve.send_signal(sig)
        stdout, stderr = serve.communicate(timeout=30)
    assert serve.returncode == 0, stderr
    assert "vehicle 1" in stdout and "RMSE vs SIM_STATE" in stdout
    rows = list(csv.DictReader(out.open()))
    active = [r for r in rows if r["config"] == "active"]
    assert len(active) > 1000  # ~6 s of 250 Hz IMU, flushed at stop


def _wait_bound(proc: subprocess.Popen[str], port: int) -> None:
    """The service is up when its socket is bound: wait for it (an event, with a deadline)."""
    deadline = time.monotonic() + 30
    while True:
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return  # the port is taken: serve has bound it
        finally:
            probe.close()
        if proc.poll() is not None:  # exited before binding: say why
            raise AssertionError(proc.stderr.read() if proc.stderr is not None else "")
        assert time.monotonic() < deadline
        time.sleep(0.05)


def _serve_until_bound(args: list[str], port: int) -> tuple[int, str]:
    """Start ``serve`` with ``args``, wait until it holds ``port``, stop it: (exit, stderr)."""
    proc = subprocess.Popen(
        [OBS, "serve", "--workers", "1", "--link", f"udpin:127.0.0.1:{port}", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        _wait_bound(proc, port)
    finally:
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
    return proc.returncode, stderr


@pytest.mark.timeout(120)
def test_serve_says_where_its_estimates_go_and_warns_when_nowhere(
    free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    # by default: published on Zenoh (the embedded peer, no router), at the default rates
    code, err = _serve_until_bound(["--service-id", f"where-{free_udp_port()}"], free_udp_port())
    assert code == 0, err
    assert "output: zenoh via the embedded loopback peer (no router needed)" in err
    assert "active, aided at 50 Hz; full, c1, c2, c3 at 10 Hz; health at 5 Hz" in err
    assert "no output" not in err
    # --full-rate and a file: both said, every record
    out = tmp_path / "r.jsonl"
    code, err = _serve_until_bound(
        ["--full-rate", "--out", str(out), "--service-id", f"full-{free_udp_port()}"],
        free_udp_port(),
    )
    assert code == 0, err
    assert f"output: file {out}: every record" in err
    assert "truth at every record" in err and "10 Hz" not in err
    # nothing at all: a warning, still a clean run
    code, err = _serve_until_bound(["--no-zenoh"], free_udp_port())
    assert code == 0, err
    assert "WARNING" in err and "no output: the estimates are computed and published nowhere" in err
    assert "output: zenoh" not in err
