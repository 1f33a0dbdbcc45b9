"""Helpers for the Zenoh tests: a router subprocess, loopback configs, records, waiting."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from glmav_observer.configurations import LOST_AXIS_OF_CONFIG
from glmav_observer.records import (
    CONFIGS,
    FaultEvent,
    HealthRecord,
    MeasurementRecord,
    Record,
    TruthRecord,
    VelocityRecord,
)

ROUTER_START_TIMEOUT_S = 15.0


def client_config(path: Path, port: int, **extra: Any) -> Path:
    """Write a client-mode config to ``port`` on loopback (multicast scouting off)."""
    config: dict[str, Any] = {
        "mode": "client",
        "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
        **extra,
    }
    path.write_text(json.dumps(config), encoding="utf-8")
    return path


def client_session(port: int, **extra: Any) -> Any:
    import zenoh

    config: dict[str, Any] = {
        "mode": "client",
        "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
        **extra,
    }
    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


class RouterProcess:
    """``glmav-observer router --listen tcp/127.0.0.1:PORT`` in a subprocess."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.proc: subprocess.Popen[str] | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "glmav_observer.cli",
                "router",
                "--listen",
                f"tcp/127.0.0.1:{self.port}",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        # the first stdout line is printed once the router listens (or EOF if it failed)
        line = _readline_with_deadline(self.proc, ROUTER_START_TIMEOUT_S)
        if not line.startswith("router "):
            err = self.proc.stderr.read() if self.proc.stderr else ""
            self.stop()
            raise RuntimeError(f"router did not start: {line!r} {err}")

    def kill(self) -> None:
        """SIGKILL: the router vanishes without closing its links."""
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(timeout=10)
            self.proc = None

    def stop(self) -> int | None:
        if self.proc is None:
            return None
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait(timeout=10)
        self.proc = None
        return code


def _readline_with_deadline(proc: subprocess.Popen[str], timeout_s: float) -> str:
    result: list[str] = []
    assert proc.stdout is not None
    reader = threading.Thread(target=lambda: result.append(proc.stdout.readline()), daemon=True)  # type: ignore[union-attr]
    reader.start()
    reader.join(timeout_s)
    return result[0] if result else ""


@contextmanager
def running_router(port: int) -> Iterator[RouterProcess]:
    router = RouterProcess(port)
    router.start()
    try:
        yield router
    finally:
        router.stop()


def wait_until(predicate: Callable[[], bool], timeout_s: float, period_s: float = 0.01) -> bool:
    """Poll ``predicate`` until it holds or ``timeout_s`` passes; its last value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period_s)
    return predicate()


# ---------------------------------------------------------------------------------------
# Deterministic records (values differ per sysid, config and step so mix-ups show)
# ---------------------------------------------------------------------------------------


def velocity(sysid: int, config: str, step: int) -> VelocityRecord:
    t = 0.004 * step
    base = 0.1 * sysid + 0.01 * (CONFIGS.index(config) if config in CONFIGS else 4)
    v_body = (base + math.sin(t), -base + math.cos(t), 0.5 * base + 0.001 * step)
    v_ned = (v_body[1], v_body[0], -v_body[2])
    lost = None if config == "active" else LOST_AXIS_OF_CONFIG[config]
    return VelocityRecord(
        sysid=sysid,
        config=config,
        t_boot_s=t,
        v_body_mps=v_body,
        v_ned_mps=v_ned,
        lost_axis=lost,
        health="ok" if lost is None else "dead_reckoning",
        seq=step,
        source_config="full" if config == "active" else None,
        sigma_lost_mps=None if lost is None else 0.01 * step,
    )


def health(sysid: int, step: int) -> HealthRecord:
    return HealthRecord(
        sysid=sysid,
        t_boot_s=0.1 * step,
        seq=step,
        active_config="full" if step < 3 else "c1",
        residual_ned_mps=(0.01 * step, -0.02, float("nan")),
        test_ratio=(0.1, 0.2, 3.5 if step >= 3 else 0.3),
        axis_state={"n": "ok", "e": "ok", "d": "faulty" if step >= 3 else "ok"},
        isolated_faults=(FaultEvent("d", "bias", 0.3, 0.25),) if step >= 3 else (),
        input_rates_hz={"RAW_IMU": 250.0, "ATTITUDE": 100.0, "LOCAL_POSITION_NED": 30.0},
        counters={"bad_frames": step, "gaps": 0},
    )


def measurement(sysid: int, step: int) -> MeasurementRecord:
    return MeasurementRecord(
        sysid=sysid,
        t_boot_s=0.033 * step,
        v_ned_mps=(1.0, float("nan"), 0.1 * step),
        position_ned_m=(0.5 * step, 2.0, -10.0),
        seq=step,
        euler_rad=(0.01, 0.02, 0.03 * step),
    )


def truth(sysid: int, step: int) -> TruthRecord:
    return TruthRecord(
        sysid=sysid,
        t_boot_s=0.02 * step,
        v_body_mps=(1.0, 0.0, 0.01 * step),
        v_ned_mps=(0.0, 1.0, 0.01 * step),
        euler_rad=(0.0, 0.1, 0.2),
        position_ned_m=None,
        seq=step,
    )


def vehicle_stream(sysid: int, steps: int) -> list[Record]:
    """What the daemon emits for ``steps`` estimator updates: 5 velocity records per step,
    health every 25th step (10 Hz at 250 Hz), measurement every 8th, truth every 5th."""
    out: list[Record] = []
    for step in range(steps):
        out += [velocity(sysid, c, step) for c in (*CONFIGS, "active")]
        if step % 25 == 0:
            out.append(health(sysid, step // 25))
        if step % 8 == 0:
            out.append(measurement(sysid, step // 8))
        if step % 5 == 0:
            out.append(truth(sysid, step // 5))
    return out
