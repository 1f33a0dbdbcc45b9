"""The UDP links' drain (udp_drain.pyx, ``recvmmsg``) on real sockets on 127.0.0.1: the
datagrams sent, in order, with their senders and the kernel's arrival stamps, as
``Link.read`` gives them one at a time; bounded; quiet on an empty or refused socket."""

from __future__ import annotations

import errno
import itertools
import os
import socket
import time
from collections.abc import Callable, Iterator

import pytest

from glmav_observer.ingest import udp_drain
from glmav_observer.ingest.links import UDP_DRAIN_BATCH, Link

pytestmark = pytest.mark.skipif(not udp_drain.AVAILABLE, reason="recvmmsg is Linux only")

#: the stamps are CLOCK_REALTIME moved onto the monotonic clock by the two clocks' offset
#: read after the call; NTP slews that offset by at most 500 ppm (adjtimex's limit), so two
#: conversions of one stamp a second apart differ by < 0.5 ms: 1 ms covers that
CLOCK_TOLERANCE_S = 1e-3


@pytest.fixture
def link(free_udp_port: Callable[[], int]) -> Iterator[tuple[Link, int]]:
    port = free_udp_port()
    lk = Link(f"udpin:127.0.0.1:{port}")
    yield lk, port
    lk.close()


def _senders(n: int) -> list[socket.socket]:
    out = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        out.append(s)
    return out


def test_the_drain_returns_the_datagrams_sent_in_order_with_senders_and_stamps(
    link: tuple[Link, int],
) -> None:
    lk, port = link
    senders = _senders(3)
    # 300 datagrams from 3 senders, interleaved, of 0 to 1,000 bytes and one of 60,000
    sent = []
    t_before = time.monotonic()
    for i in range(300):
        s = senders[i % 3]
        data = bytes([i % 251]) * (60_000 if i == 150 else (i * 7) % 1001)
        s.sendto(data, ("127.0.0.1", port))
        sent.append((data, s.getsockname()))
    got = lk.read_datagrams(1000)
    t_after = time.monotonic()
    for s in senders:
        s.close()
    assert [(d, p) for d, _, p in got] == sent  # every one, whole, in order, its sender
    assert lk.peer == sent[-1][1] and lk.arrival_s == got[-1][1]
    stamps = [t for _, t, _ in got]
    # each arrival is the kernel's stamp: between the first send and the read's return
    assert t_before - CLOCK_TOLERANCE_S <= stamps[0]
    assert stamps[-1] <= t_after
    assert all(b >= a - CLOCK_TOLERANCE_S for a, b in itertools.pairwise(stamps))


def test_the_drain_gives_what_read_gives_one_at_a_time(
    free_udp_port: Callable[[], int],
) -> None:
    # two links, the same datagrams: one read by the drain, one by Link.read (recvmsg)
    ports = [free_udp_port(), free_udp_port()]
    a, b = (Link(f"udpin:127.0.0.1:{p}") for p in ports)
    (tx,) = _senders(1)
    for i in range(100):
        for p in ports:
            tx.sendto(b"datagram %d" % i, ("127.0.0.1", p))
    drained = a.read_datagrams(1000)
    one_by_one = []
    while data := b.read():
        one_by_one.append((data, b.arrival_s, b.peer))
    tx.close()
    a.close()
    b.close()
    assert [(d, p) for d, _, p in drained] == [(d, p) for d, _, p in one_by_one]
    assert len(drained) == 100
    # the same datagram arrived at both sockets within the loopback's delivery of the
    # other copy (microseconds) plus the clocks' slew between the conversions
    for (_, ta, _), (_, tb, _) in zip(drained, one_by_one, strict=True):
        assert abs(ta - tb) <= CLOCK_TOLERANCE_S


def test_the_drain_reads_at_most_the_bound_and_the_rest_at_the_next_call(
    link: tuple[Link, int],
) -> None:
    lk, port = link
    (tx,) = _senders(1)
    n = 2 * UDP_DRAIN_BATCH + 5  # more than one system call's batch
    for i in range(n):
        tx.sendto(b"%d" % i, ("127.0.0.1", port))
    first = lk.read_datagrams(UDP_DRAIN_BATCH + 3)
    rest = lk.read_datagrams(1000)
    tx.close()
    assert [d for d, _, _ in first] == [b"%d" % i for i in range(UDP_DRAIN_BATCH + 3)]
    assert [d for d, _, _ in rest] == [b"%d" % i for i in range(UDP_DRAIN_BATCH + 3, n)]
    assert lk.read_datagrams(10) == []  # empty: nothing, no error


def test_an_empty_datagram_is_returned_in_its_place(link: tuple[Link, int]) -> None:
    lk, port = link
    (tx,) = _senders(1)
    for data in (b"one", b"", b"three"):
        tx.sendto(data, ("127.0.0.1", port))
    got = lk.read_datagrams(10)
    tx.close()
    assert [d for d, _, _ in got] == [b"one", b"", b"three"]


def test_a_closed_link_reads_nothing_without_an_error(link: tuple[Link, int]) -> None:
    lk, port = link
    (tx,) = _senders(1)
    tx.sendto(b"late", ("127.0.0.1", port))
    tx.close()
    lk.close()
    assert lk.read_datagrams(10) == []


def test_an_icmp_refusal_ends_the_drain_quietly_and_later_datagrams_are_read() -> None:
    # a connected socket (as a udpout: link's) whose peer does not listen: the ICMP port
    # unreachable of its send comes back as ECONNREFUSED on the next receive
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    addr = peer.getsockname()
    peer.close()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(addr)
    sock.setblocking(False)
    drain = udp_drain.UdpDrain(sock.fileno(), 8, False)
    sock.send(b"to nobody")
    assert drain.drain(10) == []  # the refusal: no exception
    assert drain.drain(10) == []  # (had the ICMP come later, it is read here)
    # the peer's port comes up and answers: its datagrams are read
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(addr)
    peer.sendto(b"reply", sock.getsockname())
    t0 = time.monotonic()
    got = drain.drain(10)
    assert [(d, p) for d, _, p in got] == [(b"reply", addr)]
    # no stamps asked: the arrival is the monotonic clock after the call
    assert t0 <= got[0][1] <= time.monotonic()
    peer.close()
    sock.close()


def test_a_drain_on_a_descriptor_that_is_not_a_socket_raises_oserror() -> None:
    r, w = os.pipe()
    try:
        drain = udp_drain.UdpDrain(r, 4, True)
        with pytest.raises(OSError) as info:
            drain.drain(4)
        assert info.value.errno == errno.ENOTSOCK
    finally:
        os.close(r)
        os.close(w)
    with pytest.raises(ValueError, match="batch"):
        udp_drain.UdpDrain(0, 0, True)
