"""The kernel routes a UDP port to the workers by system id (real sockets on loopback):
the classic BPF program and the parent's rule give every system id the same worker."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

import pytest
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav2

from glmav_observer.fleet.reuseport import bind_group, is_kernel_routable
from glmav_observer.fleet.routing import (
    datagram_sysid,
    reuseport_program,
    sysid_of,
    worker_of_sysid,
)
from glmav_observer.ingest.links import Link, LinkError


def _heartbeat(sysid: int, *, v1: bool = False) -> bytes:
    m = (mav1 if v1 else mav2).MAVLink(None, srcSystem=sysid, srcComponent=1)
    return bytes(m.heartbeat_encode(2, 3, 0, 0, 4).pack(m))


def _read_all(sock: socket.socket) -> list[bytes]:
    got = []
    while True:
        try:
            got.append(sock.recv(4096))
        except BlockingIOError:
            return got


@pytest.mark.parametrize("n_workers", [1, 2, 3, 5, 8])
def test_the_kernel_gives_each_system_id_to_the_parents_choice(
    n_workers: int, free_udp_port: Callable[[], int]
) -> None:
    port = free_udp_port()
    socks = bind_group(f"udpin:127.0.0.1:{port}", n_workers, 1 << 20)
    try:
        sent = [_heartbeat(s, v1=v1) for s in range(256) for v1 in (False, True)]
        garbage = [b"\x00not mavlink", b"\xfd\x09\x00", b"\xfe", b"x" + _heartbeat(7)]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for d in sent + garbage:
                tx.sendto(d, ("127.0.0.1", port))
        time.sleep(0.1)  # loopback delivery is immediate; the margin is for a loaded host
        got = [_read_all(s) for s in socks]
        # nothing lost, nothing twice (each datagram is unique by sysid and version)
        assert sorted(d for g in got for d in g) == sorted(sent + garbage)
        for i, received in enumerate(got):
            for d in received:
                sysid = sysid_of(d)
                # the program reads the header at byte 0 only: no header there (or one cut
                # short) is worker 0's, as the parent's sysid_of gives None
                want = 0 if sysid is None else worker_of_sysid(sysid, n_workers)
                assert i == want, (d[:6], i, want)
    finally:
        for s in socks:
            s.close()


def test_a_datagram_with_bytes_before_its_header_is_routed_by_that_header() -> None:
    # the kernel sends it to worker 0; the worker finds its owner with this rule
    assert datagram_sysid(b"xx" + _heartbeat(42)) == 42
    assert datagram_sysid(b"\x00\x01\x02") is None
    assert datagram_sysid(b"\xfd\x09") is None  # a header cut short: no search past it


def test_consecutive_and_strided_ids_spread_over_the_workers() -> None:
    for n in range(2, 9):
        for k in range(1, 256):
            counts = [0] * n
            for s in range(1, k + 1):
                counts[worker_of_sysid(s, n)] += 1
            # the golden ratio's multiples mod 1 (three-gap theorem): measured at most 3
            # apart for every K ≤ 255, n ≤ 8; a modulo rule would pass, a plain hash not
            assert max(counts) - min(counts) <= 3, (n, k, counts)
        # even ids only: a modulo rule would put them all on even workers
        counts = [0] * n
        for s in range(2, 202, 2):
            counts[worker_of_sysid(s, n)] += 1
        assert max(counts) - min(counts) <= 3, (n, counts)


def test_the_program_is_checked_and_bounded() -> None:
    assert len(reuseport_program(2)) == 12
    with pytest.raises(ValueError, match="0 workers"):
        reuseport_program(0)


def test_a_taken_port_is_a_link_error_naming_it(free_udp_port: Callable[[], int]) -> None:
    port = free_udp_port()
    holder = Link(f"udpin:127.0.0.1:{port}")  # a single-process serve holds the port
    try:
        with pytest.raises(LinkError, match=f"UDP port {port} is already taken"):
            bind_group(f"udpin:127.0.0.1:{port}", 2, 1 << 20)
    finally:
        holder.close()
    # and the group holds it against an exclusive bind in turn
    socks = bind_group(f"udpin:127.0.0.1:{port}", 2, 1 << 20)
    try:
        with pytest.raises(LinkError, match=f"UDP port {port} is already taken"):
            Link(f"udpin:127.0.0.1:{port}")
    finally:
        for s in socks:
            s.close()


def test_only_udp_server_links_are_routed_by_the_kernel() -> None:
    assert is_kernel_routable("udpin:127.0.0.1:14550")
    assert is_kernel_routable("udp:0.0.0.0:14550")
    for conn in ("udpout:127.0.0.1:14550", "tcpin:127.0.0.1:5760", "/dev/ttyUSB0", "nonsense"):
        assert not is_kernel_routable(conn)
    with pytest.raises(LinkError, match="only a udpin"):
        bind_group("tcpin:127.0.0.1:5760", 2, 1 << 20)
