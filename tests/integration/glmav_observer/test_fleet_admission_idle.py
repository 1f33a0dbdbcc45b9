"""A vehicle of one worker takes the slot of another worker's idle vehicle, as in one
process (found by the fuzz over ``serve`` in the default worker mode: a storm of spoofed
system ids at start, routed to the worker that began reading first, filled
``max_vehicles`` and the real vehicle, owned by the other worker, was refused for ever:
a worker evicted only its own idle vehicles).

Eight system ids owned by worker 0 (of 2) are heard once and fill the service; then a
vehicle owned by worker 1 sends ATTITUDE at 20 Hz. With ``evict_idle_s = 1`` it must be
admitted about 1 s after the fillers fell silent, with two workers as with one."""

from __future__ import annotations

import re
import socket
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from glmav_observer.fleet.routing import worker_of_sysid
from glmav_testkit.serve_process import ServeProcess, free_udp_port

MAX_VEHICLES = 8
EVICT_IDLE_S = 1.0


def _attitude(sysid: int, t_ms: int) -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return bytes(mavlink2.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(mav))


@pytest.mark.timeout(180)
@pytest.mark.parametrize("workers", [2, 1])
def test_a_newcomer_gets_the_slot_of_an_idle_vehicle_of_another_worker(
    workers: int, tmp_path: Path
) -> None:
    fillers = [s for s in range(2, 60) if worker_of_sysid(s, 2) == 0][:MAX_VEHICLES]
    vehicle = next(s for s in range(1, 60) if worker_of_sysid(s, 2) == 1)
    cfg = tmp_path / "service.toml"
    cfg.write_text(f'[ingest]\nevict_idle_s = {EVICT_IDLE_S}\n[rates]\nmode = "observe"\n')
    port = free_udp_port()
    sp = ServeProcess(port, workers, tmp_path, extra=["--config", str(cfg)])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sp.wait_ready()
        for s in fillers:
            sock.sendto(_attitude(s, 100), ("127.0.0.1", port))
        for s in fillers:  # an event: the workers may start reading seconds after the bind
            sp.wait_log(f"new vehicle (sysid={s}, ")
        t_full = time.monotonic()  # the fillers were last heard before this
        k = 0
        admitted_after_s = None
        while time.monotonic() - t_full < 60.0:
            sock.sendto(_attitude(vehicle, 1000 + 50 * k), ("127.0.0.1", port))
            k += 1
            time.sleep(0.05)
            if f"new vehicle (sysid={vehicle}, " in sp.stderr_path.read_text():
                admitted_after_s = time.monotonic() - t_full
                break
    finally:
        sock.close()
        stopped = sp.stop()
    assert stopped.returncode == 0, stopped.stderr[-3000:]
    # admitted once a filler had been silent for evict_idle_s: from 1 s after the fillers
    # were admitted (they may have been heard a little before t_full) to a generous bound
    # for a loaded machine (it was never, before, with two workers)
    assert admitted_after_s is not None, stopped.stderr[-3000:]
    assert 0.5 * EVICT_IDLE_S <= admitted_after_s < 30.0
    # one filler gave up its slot. One process evicts it at once; with workers, the
    # filler's worker learns it at the filler's next message (it sent none), so the
    # summary of both lists the 8 fillers and the vehicle
    evicted = 1 if workers == 1 else 0
    assert stopped.summary.service.get("evicted", 0) == evicted, stopped.summary.text
    assert len(re.findall(r"vehicle evicted", stopped.stderr)) == evicted
    assert sorted(stopped.summary.vehicles) == sorted([*fillers, vehicle])
