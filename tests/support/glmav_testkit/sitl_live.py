"""Helpers of the daemon's integration tests: the real SITL streaming to the service over UDP.

The simulator runs as a subprocess (``glmav-sitl run ... --link udpout:127.0.0.1:PORT``)
and the service in this process (``Service.run`` on ``udpin:127.0.0.1:PORT`` in a
thread). The test waits for an event, not a time: the service has received as many
frames as the simulator reports having sent (its summary line ``N messages``).
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from glmav_observer.app import Service
from glmav_observer.app_summary import ServiceSummary
from glmav_observer.commands.demo import scenario_toml
from glmav_observer.config import ServiceConfig, load_config
from glmav_observer.fleet.routing import frame_length
from glmav_observer.ingest.framing import FrameCounters, TlogRecord, iter_tlog
from glmav_observer.ingest.links import Link
from glmav_observer.records import Record
from glmav_testkit import REPO_ROOT

REPO = REPO_ROOT
SITL = str(Path(sys.executable).with_name("glmav-sitl"))


def service_test_config() -> ServiceConfig:
    """The shipped configuration, asking the SITL to stop RAW_IMU/SCALED_IMU (HIGHRES is used)."""
    cfg = load_config(REPO / "configs" / "service.toml")
    rates = dict(cfg.ingest.rates_hz)
    rates.update({"RAW_IMU": -1.0, "SCALED_IMU": -1.0})
    return replace(cfg, ingest=replace(cfg.ingest, rates_hz=rates))


@dataclass
class MemorySink:
    """Keeps every record (a real sink: the Sink protocol, used by the service as any other)."""

    records: list[Record] = field(default_factory=list)
    closed: bool = False

    def write(self, record: Record) -> None:
        self.records.append(record)

    def close(self) -> None:
        self.closed = True


@dataclass
class LiveRun:
    summary: ServiceSummary
    records: list[Record]
    tlog: Path
    sent_messages: int


def fault_scenario(tmp: Path, axis: str, kind: str, t_start_s: float, magnitude: float) -> Path:
    """A climbing turn (as the shipped fault scenarios and the demo) with one velocity fault."""
    p = tmp / f"fault-{kind}-{axis}.toml"
    text = scenario_toml(
        60.0, axis, kind, t_start_s, 1000.0, magnitude=magnitude, name=f"fault-{kind}-{axis}"
    )
    p.write_text(text, encoding="utf-8")
    return p


def run_live(
    scenario: str | Path,
    *,
    port: int,
    tmp: Path,
    duration_s: float,
    seed: int = 0,
    speed: str = "4",
    sysids: tuple[int, ...] = (1,),
    config: ServiceConfig | None = None,
    timeout_s: float = 60.0,
) -> LiveRun:
    """Fly ``scenario`` in the SITL (one process per sysid), estimate live, return everything."""
    cfg = config or service_test_config()
    sink = MemorySink()
    service = Service(cfg, [sink])
    link = Link(f"udpin:127.0.0.1:{port}", udp_receive_buffer_bytes=cfg.udp_receive_buffer_bytes)
    stop = threading.Event()
    thread = threading.Thread(target=service.run, args=({"udp": link}, stop), daemon=True)
    thread.start()
    procs = []
    tlog = tmp / f"live-{Path(str(scenario)).stem}-{seed}.tlog"
    try:
        for i, sysid in enumerate(sysids):
            cmd = [SITL, "run", "--scenario", str(scenario), "--duration", str(duration_s),
                   "--speed", speed, "--seed", str(seed + i), "--sysid", str(sysid),
                   "--link", f"udpout:127.0.0.1:{port}"]  # fmt: skip
            if i == 0:
                cmd += ["--tlog", str(tlog)]
            procs.append(
                subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            )
        sent = 0
        for p in procs:
            out, err = p.communicate(timeout=timeout_s)
            assert p.returncode == 0, err
            m = re.search(r"(\d+) messages", out)
            assert m is not None, out
            sent += int(m.group(1))
        deadline = time.monotonic() + timeout_s
        while service.decoders.get("udp") is None or (
            service.decoders["udp"].counters.counts["frames_ok"] < sent
        ):
            assert time.monotonic() < deadline, (
                f"received {service.decoders['udp'].counters.as_dict()} of {sent} frames"
            )
            time.sleep(0.02)  # polling an in-process counter with a deadline
    finally:
        stop.set()
        thread.join(timeout=10)
        link.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
        service.close()
    return LiveRun(service.summary(), sink.records, tlog, sent)


def follow_tlog(
    path: Path, proc: subprocess.Popen[bytes], poll_s: float = 0.02
) -> Iterator[TlogRecord]:
    """The records of the ``.tlog`` that ``proc`` is still writing, each once it is whole.

    A consumer (the service) then runs on one core while the simulator runs on the other,
    as they would live, and still sees every record (a file: no datagram lost). Ends when
    ``proc`` has exited and everything it wrote is read; a partial record left at the end
    is an error (the simulator writes whole records).
    """
    counters = FrameCounters()
    while not path.exists():
        if proc.poll() is not None:
            raise RuntimeError(f"{path}: the simulator exited ({proc.returncode}) before writing")
        time.sleep(poll_s)
    buf = bytearray()
    with path.open("rb") as f:
        while True:
            exited = proc.poll() is not None  # checked before the read: nothing comes after it
            chunk = f.read()
            buf += chunk
            whole = 0
            while whole + 8 < len(buf):
                length = frame_length(buf, whole + 8)
                if length is None or whole + 8 + length > len(buf):
                    break
                whole += 8 + length
            if whole:
                yield from iter_tlog(bytes(buf[:whole]), counters)
                del buf[:whole]
            elif exited and not chunk:
                break
            elif not chunk:
                time.sleep(poll_s)
    if buf:
        raise RuntimeError(f"{path}: {len(buf)} bytes at the end are not a whole record")
