"""Bad input over real UDP loopback: no crash, everything counted, the valid stream unaffected.

The SITL's stream (a ``glmav-sitl`` tlog, one frame per datagram as it sends them) is sent
to ``serve``'s pipeline over UDP with damaged datagrams interleaved: truncated frames,
bad CRCs, garbage, NaN fields, samples of the vehicle with time going backwards, and a
flood of unknown system ids. The vehicle's velocity records must be exactly those of
a replay of the clean log.
"""

from __future__ import annotations

import math
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.app import Service
from glmav_observer.app_replay import replay_tlog
from glmav_observer.ingest.framing import iter_tlog
from glmav_observer.ingest.links import Link
from glmav_observer.records import VelocityRecord, flatten
from glmav_testkit.sitl_live import SITL, MemorySink, service_test_config


def _pack(msg: Any, sysid: int) -> bytes:
    return bytes(msg.pack(dialect.MAVLink(None, srcSystem=sysid, srcComponent=1)))


def _bad_datagrams(i: int, t_ms: int) -> list[bytes]:
    """Damaged datagrams to follow valid frame ``i`` (vehicle time ``t_ms``)."""
    att = _pack(dialect.MAVLink_attitude_message(t_ms, 0.1, 0.1, 0.1, 0, 0, 0), 1)
    k = i % 6
    if k == 0:
        return [att[: len(att) // 2]]  # truncated
    if k == 1:
        bad = bytearray(att)
        bad[-1] ^= 0x5A
        return [bytes(bad)]  # bad CRC (a valid-looking frame of the vehicle)
    if k == 2:
        return [b"\x00\x11garbage\xfd\x03"]  # garbage, with a stray magic byte
    if k == 3:  # NaN fields from the vehicle itself
        return [_pack(dialect.MAVLink_attitude_message(t_ms, math.nan, 0, 0, 0, 0, 0), 1)]
    if k == 4:  # the vehicle's time going back to 0 (a single corrupt stamp)
        back = dialect.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0)
        return [_pack(back, 1)]
    # unknown system ids: a flood of 3 new vehicles per valid frame
    return [
        _pack(dialect.MAVLink_attitude_message(t_ms, 0, 0, 0, 0, 0, 0), 10 + (i * 3 + j) % 240)
        for j in range(3)
    ]


@pytest.mark.timeout(180)
def test_bad_input_is_counted_and_the_valid_stream_is_unaffected(
    free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    tlog = tmp_path / "cruise.tlog"
    subprocess.run(
        [SITL, "run", "--scenario", "cruise", "--duration", "8", "--speed", "max",
         "--seed", "4", "--tlog", str(tlog)],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    records = list(iter_tlog(tlog.read_bytes()))
    cfg = service_test_config()
    sink = MemorySink()
    service = Service(cfg, [sink])
    port = free_udp_port()
    link = Link(f"udpin:127.0.0.1:{port}")
    stop = threading.Event()
    th = threading.Thread(target=service.run, args=({"udp": link}, stop), daemon=True)
    th.start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent_ok = 0
    last_t_ms = 0
    try:
        for i, rec in enumerate(records):
            tx.sendto(bytes(rec.msg.get_msgbuf()), ("127.0.0.1", port))
            sent_ok += 1
            if hasattr(rec.msg, "time_boot_ms"):
                last_t_ms = int(rec.msg.time_boot_ms)
            if i % 5 == 4 and last_t_ms > 0:
                for d in _bad_datagrams(i // 5, last_t_ms):
                    tx.sendto(d, ("127.0.0.1", port))
            if i % 200 == 199:  # let the service drain (an event: its frame count)
                deadline = time.monotonic() + 30
                while (
                    "udp" not in service.decoders
                    or service.decoders["udp"].counters.counts["frames_ok"] < sent_ok
                ):
                    assert time.monotonic() < deadline
                    time.sleep(0.005)
        # a marker after the last damaged datagrams: the last valid frame again (dropped
        # as a duplicate, no record). Loopback keeps order, so once it is decoded every
        # datagram before it has been read (an event; a sleep lost some on a loaded
        # machine now that a stop no longer drains the socket without bound)
        tx.sendto(bytes(records[-1].msg.get_msgbuf()), ("127.0.0.1", port))
        sent_ok += 1
        deadline = time.monotonic() + 30
        while service.decoders["udp"].counters.counts["frames_ok"] < sent_ok:
            assert time.monotonic() < deadline
            time.sleep(0.005)
    finally:
        stop.set()
        th.join(10)
        link.close()
        tx.close()
        service.close()
    s = service.summary()
    link_c = s.link_counters["udp"]
    n_groups = (len(records) // 5) // 6  # each kind of damage occurs about this often
    assert link_c["truncated"] >= n_groups
    assert link_c["bad_crc"] >= n_groups
    assert link_c["garbage_bytes"] >= 9 * n_groups
    v1 = s.vehicles[1]
    assert v1.counters["nan_field"] >= n_groups
    # back by more than reset_backwards_s (2 s): a reboot candidate, never confirmed;
    # less (the first 2 s): simply late
    assert v1.counters["time_backwards"] + v1.counters["late"] >= n_groups
    assert v1.counters["time_backwards"] > 0
    assert v1.counters.get("clock_reset", 0) == 0  # isolated stamps never reset the vehicle
    # the flood: capped at max_vehicles (8), the rest dropped and counted
    assert len(s.vehicles) <= cfg.ingest.max_vehicles
    assert s.service_counters["vehicle_cap_dropped"] >= n_groups
    # the valid stream is unaffected: identical velocity records to a clean replay
    clean = MemorySink()
    replay_tlog(tlog, cfg, [clean])
    got = [flatten(r) for r in sink.records if isinstance(r, VelocityRecord) and r.sysid == 1]
    want = [flatten(r) for r in clean.records if isinstance(r, VelocityRecord)]
    assert len(want) > 1000
    assert got == want
