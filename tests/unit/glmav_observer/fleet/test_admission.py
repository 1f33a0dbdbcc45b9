"""``max_vehicles`` shared by the ingests of several workers (issue 31 D12)."""

from __future__ import annotations

import multiprocessing
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.fleet.admission import SharedAdmission
from glmav_observer.ingest.framing import FrameDecoder
from glmav_observer.ingest.pipeline import Ingest, IngestConfig


def _att(t_ms: int, sysid: int) -> Any:
    mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=1)
    msg = dialect.MAVLink_attitude_message(t_ms, 0.1, -0.2, 0.3, 1, 2, 3)
    (out,) = FrameDecoder(datagram=True).feed(bytes(msg.pack(mav)))
    return out


def _child_admits(admission: SharedAdmission, sysids: list[int], out: Any) -> None:
    out.send([admission.acquire(s) for s in sysids])


def test_two_ingests_admit_the_cap_in_total_and_eviction_frees_a_slot() -> None:
    cfg = IngestConfig(max_vehicles=3, evict_idle_s=10.0)
    shared = SharedAdmission(cfg.max_vehicles)
    a, b = Ingest(cfg, shared), Ingest(cfg, shared)
    for s in (1, 2):
        a.on_message(_att(10, s), 0.0)
    b.on_message(_att(10, 3), 0.0)
    assert b.on_message(_att(10, 4), 1.0) == []  # b holds 1 of its own cap of 3, but the
    assert a.on_message(_att(10, 5), 1.0) == []  # service holds 3 of 3
    assert (len(a.vehicles), len(b.vehicles), shared.admitted()) == (2, 1, 3)
    assert a.counters["vehicle_cap_dropped"] == b.counters["vehicle_cap_dropped"] == 1
    # a's vehicle 1 silent for 15 s: a evicts it for its new vehicle 5, the slot moves
    a.on_message(_att(20, 2), 15.0)
    a.on_message(_att(10, 5), 15.0)
    assert sorted(a.vehicles) == [2, 5] and shared.admitted() == 3
    # b has no idle vehicle: a new one is still refused (the cap counts a's)
    b.on_message(_att(20, 3), 15.0)
    assert b.on_message(_att(10, 6), 16.0) == [] and shared.admitted() == 3


def test_the_table_is_shared_with_a_spawned_process() -> None:
    ctx = multiprocessing.get_context("spawn")
    shared = SharedAdmission(2, ctx)
    assert shared.acquire(7)
    recv, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_child_admits, args=(shared, [7, 8, 9], send))
    child.start()
    assert recv.poll(60.0)  # a spawned interpreter starts in seconds; 60 s: a loaded host
    got = recv.recv()
    child.join(10.0)
    # 7: already admitted (here); 8: the second slot; 9: over the cap of 2
    assert got == [True, True, False]
    assert shared.admitted() == 2


def _events(got: list[Any]) -> list[str]:
    return [type(e).__name__ for e in got if type(e).__name__ in ("NewVehicle", "VehicleEvicted")]


def test_a_newcomer_takes_the_slot_of_another_workers_idle_vehicle() -> None:
    """The fuzz over ``serve --workers 2`` (benchmarks/fuzz_ingest.py --serve): a storm of
    spoofed ids that went to one worker filled the service, and the real vehicle of the
    other worker was refused for ever (a worker evicted only its own idle vehicles). As in
    one process, a vehicle silent for ``evict_idle_s`` now gives its slot to a newcomer,
    whichever worker holds it; its worker evicts it at its next message."""
    cfg = IngestConfig(max_vehicles=2, evict_idle_s=10.0)
    shared = SharedAdmission(cfg.max_vehicles)
    a, b = Ingest(cfg, shared), Ingest(cfg, shared)
    a.on_message(_att(10, 20), 0.0)  # two ids heard once, at 0 and 3 s
    a.on_message(_att(10, 21), 3.0)
    assert b.on_message(_att(10, 1), 5.0) == []  # full, nobody idle for 10 s yet
    assert b.counters["vehicle_cap_dropped"] == 1
    got = b.on_message(_att(10, 1), 10.5)  # 20 has been silent 10.5 s: its slot is 1's
    assert _events(got) == ["NewVehicle"] and 1 in b.vehicles
    assert shared.admitted() == 2
    # 20 comes back to a: it has lost its slot, a evicts it; the service is full again
    # (21 silent only 9 s) and 20 is refused as a newcomer would be
    got = a.on_message(_att(20, 20), 12.0)
    assert _events(got) == ["VehicleEvicted"] and 20 not in a.vehicles
    assert a.counters["evicted"] == 1 and a.counters["vehicle_cap_dropped"] == 1
    assert sorted(a.vehicles) == [21] and shared.admitted() == 2
    # a vehicle heard at least every second keeps its slot against any newcomer
    for k in range(30):
        b.on_message(_att(20 + 100 * k, 1), 10.5 + 0.9 * k)
    assert 1 in b.vehicles
    got = a.on_message(_att(10, 22), 40.0)  # 21 silent 37 s: 22 takes its slot, not 1's
    assert _events(got) == ["VehicleEvicted", "NewVehicle"]
    assert sorted(a.vehicles) == [22] and 1 in b.vehicles and shared.admitted() == 2
