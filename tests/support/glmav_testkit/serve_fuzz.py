"""Fuzzing a real ``glmav-observer serve`` over UDP loopback, in any worker mode.

A *plan* is the vehicle's valid stream (the simulator's frames, system id 1) with
``cases_per_frame`` damaged datagrams of :class:`glmav_testkit.fuzzgen.CaseMaker` after
every valid frame past the first ``warmup_frames`` (the vehicle is admitted before a
storm of system ids can fill the vehicle cap, as in ``benchmarks/fuzz_ingest.py``). Every
datagram is framed beforehand by the service's own ``FrameDecoder`` (datagram mode) in
this process: what the service must count, reason by reason.

A session starts ``serve`` (:class:`glmav_testkit.serve_process.ServeProcess`), sends the
vehicle's first frames and waits until the service logs it admitted (with workers, the
one that owns the vehicle may start reading after the other has admitted a storm of
spoofed ids: the vehicle would then wait ``evict_idle_s`` for a slot), then sends the
plan with the valid frames paced at the vehicle's rate (its own clock: the simulator's
frames per simulated second) and the queues bounded (:class:`PacedSender`: no kernel
drop unless the service stops reading), waits until the port is read, checks the process
is alive, stops it with SIGTERM and reads its summary and ``--out`` file.
"""

from __future__ import annotations

import collections
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from glmav_observer.ingest.framing import FrameCounters, FrameDecoder
from glmav_testkit.fleet_helpers import udp_queue, wait_drained
from glmav_testkit.fuzzgen import VEHICLE_SYSID, CaseMaker, ValidStream
from glmav_testkit.ingest_harness import Harness, velocity_series
from glmav_testkit.serve_process import PacedSender, ServeProcess, Stopped, free_udp_port

#: valid frames before the damage starts (benchmarks/fuzz_ingest.py's reason)
WARMUP_FRAMES = 50
#: the framing counters a datagram can move (the link's other counters are the socket's)
FRAMING_KEYS = ("frames_ok", "bad_crc", "bad_header", "truncated", "garbage_bytes",
                "unknown_message")  # fmt: skip


@dataclass
class FuzzPlan:
    datagrams: list[bytes]
    #: index in ``datagrams`` of each valid frame (paced at the vehicle's rate)
    valid_at: list[int]
    kinds: collections.Counter[str]
    #: the framing counters of the service's FrameDecoder over every datagram
    expected: dict[str, int]
    vehicle_s: float
    vehicle_safe: bool
    seed: int

    @property
    def cases(self) -> int:
        return sum(self.kinds.values())


def _vehicle_ms(frames: list[bytes]) -> list[int]:
    """The vehicle's time (ms) at each valid frame: the last stamp seen so far."""
    dec = FrameDecoder(datagram=True)
    t_ms = 0
    out = []
    for f in frames:
        for msg in dec.feed(f):
            if hasattr(msg, "time_boot_ms"):
                t_ms = int(msg.time_boot_ms)
            elif hasattr(msg, "time_usec") and msg.get_type() != "SYSTEM_TIME":
                t_ms = int(msg.time_usec) // 1000
        out.append(t_ms)
    return out


def make_plan(
    stream: ValidStream,
    vehicle_s: float,
    corrupt: bytes,
    seed: int,
    *,
    vehicle_safe: bool,
    cases_per_frame: int = 3,
) -> FuzzPlan:
    cm = CaseMaker(stream.frames, corrupt, seed, vehicle_safe=vehicle_safe)
    kinds: collections.Counter[str] = collections.Counter()
    datagrams: list[bytes] = []
    valid_at: list[int] = []
    for i, (frame, t_ms) in enumerate(zip(stream.frames, _vehicle_ms(stream.frames), strict=True)):
        valid_at.append(len(datagrams))
        datagrams.append(frame)
        if i < WARMUP_FRAMES:
            continue
        cm.t_ms = max(t_ms, 1)
        for _ in range(cases_per_frame):
            kind, data = cm.make()
            if not data:  # a zero-length datagram is not a case (UDP delivers it empty)
                continue
            kinds[kind] += 1
            datagrams.append(data)
    counters = FrameCounters()
    ref = FrameDecoder(datagram=True, counters=counters)
    for d in datagrams:
        for _ in ref.feed(d):
            pass
    return FuzzPlan(datagrams, valid_at, kinds, counters.as_dict(), vehicle_s, vehicle_safe, seed)


def clean_series(stream: ValidStream) -> list[Any]:
    """The vehicle's ``full`` velocity series from its clean stream, in this process."""
    h = Harness()
    h.feed_all(stream.frames)
    return velocity_series(h.records[VEHICLE_SYSID])


def out_series(path: Path, sysid: int = VEHICLE_SYSID, config: str = "full") -> list[Any]:
    """(t_boot_s, v_ned_mps) of one vehicle's velocity records in serve's ``--out`` JSONL."""
    rows = []
    with path.open(encoding="utf-8") as f:
        for line in f:
            if f'"sysid":{sysid},' not in line and f'"sysid":{sysid}}}' not in line:
                continue
            r = json.loads(line)
            if (r.get("schema"), r.get("sysid"), r.get("config")) == (
                "glmav.velocity/1",
                sysid,
                config,
            ):
                v = (r["v_ned_mps_n"], r["v_ned_mps_e"], r["v_ned_mps_d"])
                rows.append((r["t_boot_s"], v))
    return rows


@dataclass
class SessionResult:
    plan: FuzzPlan
    stopped: Stopped
    alive_after_traffic: bool
    kernel_drops: int
    sent: int
    wall_s: float
    held_s: float
    vehicle_series: list[Any]
    processes: dict[str, dict[str, float]] = field(default_factory=dict)

    def framing(self) -> dict[str, int]:
        """The service's framing counters (summed over workers), the plan's keys."""
        link = self.stopped.summary.link
        return {k: link.get(k, 0) for k in FRAMING_KEYS if k in self.plan.expected or k in link}


def run_session(
    plan: FuzzPlan,
    workers: int | None,
    workdir: Path,
    *,
    zenoh: bool = False,
    service_id: str | None = None,
) -> SessionResult:
    """Send ``plan`` to a new ``serve`` (``workers=None``: serve's default) and stop it."""
    port = free_udp_port()
    out = workdir / f"fuzz-{port}.jsonl"
    sp = ServeProcess(port, workers, workdir, zenoh=zenoh, out=out, service_id=service_id)
    sender = PacedSender(port)
    try:
        sp.wait_ready()
        rate = len(plan.valid_at) / plan.vehicle_s  # valid frames per vehicle second
        valid = set(plan.valid_at)
        first_case = plan.valid_at[min(WARMUP_FRAMES, len(plan.valid_at) - 1)]
        k = 0
        t0 = t_start = time.monotonic()
        for i, d in enumerate(plan.datagrams):
            if i == first_case:  # the damage starts once the vehicle is admitted
                t_wait = time.monotonic()
                sp.wait_log(f"new vehicle (sysid={VEHICLE_SYSID}, ")
                t0 += time.monotonic() - t_wait
            if i in valid:
                sender.pace(t0 + k / rate)
                k += 1
            sender.send(d)
        wait_drained(port, timeout_s=300.0)
        time.sleep(0.3)  # the last datagram read is being estimated and written
        wall = time.monotonic() - t_start
        drops = udp_queue(port)[1]
        alive = sp.alive()
        procs = sp.sample()
        stopped = sp.stop()
    except BaseException:
        sp.kill()
        raise
    finally:
        sender.close()
    series = out_series(out) if out.exists() else []
    result = SessionResult(plan, stopped, alive, drops, sender.sent, wall, sender.held_s, series,
                           procs)  # fmt: skip
    out.unlink(missing_ok=True)
    return result
