"""The fleet generator's compiled send loop (fleet_send.pyx) on real UDP sockets on
127.0.0.1: the frames due are sent once each, in order, on their vehicle's sockets;
failures are counted per socket; a stop request ends the window."""

from __future__ import annotations

import errno
import socket
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from glmav_sitl.fleet import load_tlog, run_fleet
from glmav_sitl.fleet_send import monotonic_s, send_window

#: the receivers' wait for a datagram already sent on loopback (only a stalled machine
#: makes it take more than microseconds; it bounds nothing that is asserted)
RECV_TIMEOUT_S = 2.0


@pytest.fixture
def pairs() -> Iterator[list[tuple[socket.socket, socket.socket]]]:
    """Three (receiver, connected non-blocking sender) pairs on 127.0.0.1."""
    out = []
    for _ in range(3):
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(RECV_TIMEOUT_S)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.connect(rx.getsockname())
        tx.setblocking(False)
        out.append((rx, tx))
    yield out
    for rx, tx in out:
        rx.close()
        tx.close()


def _received(rx: socket.socket) -> list[bytes]:
    """Every datagram waiting on ``rx`` (after the sender's loop returned)."""
    rx.setblocking(False)
    got = []
    while True:
        try:
            got.append(rx.recv(65535))
        except BlockingIOError:
            return got


class _Calls:
    def __init__(self, stop_after: int | None = None) -> None:
        self.flushes = 0
        self.waits: list[float] = []
        self.failures: list[tuple[int, OSError]] = []
        self.emitted: list[bytes] = []
        self.stop_after = stop_after

    def flush(self) -> None:
        self.flushes += 1

    def wait(self, dt: float) -> bool:
        self.waits.append(dt)
        return self.stop_after is not None and len(self.waits) > self.stop_after

    def failed(self, slot: int, err: OSError) -> None:
        self.failures.append((slot, err))

    def emit(self, data: bytes) -> None:
        self.emitted.append(data)


def _window(
    due_s: list[float], owners: list[int], fd_lists: list[list[int]]
) -> tuple[np.ndarray, ...]:
    order = np.argsort(np.array(due_s), kind="stable").astype(np.int64)
    fd_start = np.cumsum([0] + [len(f) for f in fd_lists], dtype=np.int32)
    fds = np.array([fd for f in fd_lists for fd in f], dtype=np.int32)
    return (
        order,
        np.array(due_s, dtype=np.float64),
        np.array(owners, dtype=np.int64),
        fd_start,
        fds,
        np.zeros(len(fds), dtype=np.int64),
    )


def test_frames_due_are_sent_once_in_due_order_on_their_vehicles_sockets(
    pairs: list[tuple[socket.socket, socket.socket]],
) -> None:
    # vehicle 0 on sockets 0 and 1 (a fan-out), vehicle 1 on socket 2, vehicle 2 on none
    # (its frames go to its Python emit only); all due already (no sleep)
    due = [-0.5, -0.9, -0.7, -0.1, -0.3, -0.8]
    owners = [0, 1, 0, 1, 2, 0]
    datas = [f"frame {i} of {k}".encode() for i, k in enumerate(owners)]
    fd_lists = [[pairs[0][1].fileno(), pairs[1][1].fileno()], [pairs[2][1].fileno()], []]
    order, due_s, own, fd_start, fds, sent = _window(due, owners, fd_lists)
    calls = _Calls()
    n, late = send_window(
        order,
        due_s,
        datas,
        own,
        fd_start,
        fds,
        sent,
        [None, None, calls.emit],
        calls.failed,
        calls.flush,
        calls.wait,
        monotonic_s(),
        0.0005,
    )
    assert n == 6
    by_due = [datas[i] for i in order.tolist()]  # frames 1, 5, 2, 0, 4, 3
    mine = [d for d in by_due if d.endswith(b"of 0")]
    assert _received(pairs[0][0]) == mine  # in due order, once each
    assert _received(pairs[1][0]) == mine  # the fan-out: the same frames
    assert _received(pairs[2][0]) == [d for d in by_due if d.endswith(b"of 1")]
    assert calls.emitted == [datas[4]]
    assert sent.tolist() == [3, 3, 2]
    assert calls.failures == [] and calls.waits == [] and calls.flushes == 0
    # the most late: frame 1, due 0.9 s before the clock's first reading (or more)
    assert late >= 0.9


def test_a_frame_not_yet_due_is_waited_for_and_a_stop_ends_the_window(
    pairs: list[tuple[socket.socket, socket.socket]],
) -> None:
    rx, tx = pairs[0]
    # two frames due now, the third in 100 s: the loop flushes, then waits on the stop
    # event, which is set: the window ends with two frames sent
    due = [-0.01, -0.005, 100.0]
    datas = [b"a", b"b", b"c"]
    order, due_s, own, fd_start, fds, sent = _window(due, [0, 0, 0], [[tx.fileno()]])
    calls = _Calls(stop_after=0)
    wall0 = monotonic_s()
    n, _late = send_window(
        order, due_s, datas, own, fd_start, fds, sent, None,
        calls.failed, calls.flush, calls.wait, wall0, 0.0005,
    )  # fmt: skip
    assert n == 2
    assert _received(rx) == [b"a", b"b"]
    assert sent.tolist() == [2]
    assert calls.flushes == 1 and len(calls.waits) == 1
    # the wait asked is the time left until the frame's due time (the clock has run on
    # since wall0 by however long the machine took: only the bounds are certain)
    assert 0.0 < calls.waits[0] <= 100.0


def test_a_wait_that_returns_without_a_stop_sends_the_frame(
    pairs: list[tuple[socket.socket, socket.socket]],
) -> None:
    rx, tx = pairs[0]
    # due 20 ms after wall0 (more than MIN_SLEEP_S away unless the machine stalled 20 ms
    # between the two reads); the fake wait returns at once, not stopped: the loop reads
    # the clock again and sends the frame whether or not its time has come
    order, due_s, own, fd_start, fds, sent = _window([0.02], [0], [[tx.fileno()]])
    calls = _Calls()
    n, _late = send_window(
        order, due_s, [b"x"], own, fd_start, fds, sent, None,
        calls.failed, calls.flush, calls.wait, monotonic_s(), 0.0005,
    )  # fmt: skip
    assert n == 1 and _received(rx) == [b"x"] and sent.tolist() == [1]
    assert len(calls.waits) <= 1 and calls.flushes <= 1


def test_sends_to_a_port_nobody_listens_on_are_counted_as_failures() -> None:
    # a port that was free: nothing listens there. Loopback answers each datagram with
    # an ICMP port unreachable, which the next send on the socket returns as ECONNREFUSED
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.connect(("127.0.0.1", port))
    tx.setblocking(False)
    frames = 10
    order, due_s, own, fd_start, fds, sent = _window(
        [-1.0 + 0.01 * i for i in range(frames)], [0] * frames, [[tx.fileno()]]
    )
    calls = _Calls()
    n, _late = send_window(
        order, due_s, [b"%d" % i for i in range(frames)], own, fd_start, fds, sent, None,
        calls.failed, calls.flush, calls.wait, monotonic_s(), 0.0005,
    )  # fmt: skip
    tx.close()
    assert n == frames  # a failed frame is counted as sent, as the Python loop did
    assert len(calls.failures) >= 1
    assert sent.tolist() == [frames - len(calls.failures)]
    for slot, err in calls.failures:
        assert slot == 0
        assert isinstance(err, ConnectionRefusedError) and err.errno == errno.ECONNREFUSED


def test_a_window_with_an_inconsistent_layout_is_refused() -> None:
    order, due_s, own, fd_start, fds, sent = _window([0.0, 0.0], [0, 3], [[]])
    calls = _Calls()
    with pytest.raises(IndexError, match="vehicle 3"):
        send_window(
            order, due_s, [b"a", b"b"], own, fd_start, fds, sent, None,
            calls.failed, calls.flush, calls.wait, monotonic_s(), 0.0005,
        )  # fmt: skip
    with pytest.raises(ValueError, match="one entry per frame"):
        send_window(
            order, due_s, [b"a"], own, fd_start, fds, sent, None,
            calls.failed, calls.flush, calls.wait, monotonic_s(), 0.0005,
        )  # fmt: skip


def _tlog(path: Path, frames: int) -> Path:
    v2 = mav2.MAVLink(None, srcSystem=7, srcComponent=1)
    with path.open("wb") as f:
        for i in range(frames):
            msg = v2.attitude_encode(i, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(v2)
            f.write(struct.pack(">Q", int(1_700_000_000e6 + 1e3 * i)) + msg)  # 1 kHz
    return path


def test_the_generator_counts_failed_sends_per_link_when_nothing_listens(
    tmp_path: Path,
) -> None:
    log = load_tlog(_tlog(tmp_path / "a.tlog", 40))
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    # 2 vehicles x 40 frames at 50x speed (0.8 ms of log between frames)
    summary = run_fleet([log], [f"udpout:127.0.0.1:{port}"], 2, speed=50.0, stagger_s=0.01)
    assert summary.frames_sent == 80  # every frame attempted once
    assert 1 <= summary.frames_failed <= 80


def test_the_generator_sends_every_frame_to_every_link_of_a_fan_out(tmp_path: Path) -> None:
    log = load_tlog(_tlog(tmp_path / "a.tlog", 30))
    rxs = []
    for _ in range(2):
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.bind(("127.0.0.1", 0))
        rxs.append(rx)
    links = [f"udpout:127.0.0.1:{rx.getsockname()[1]}" for rx in rxs]
    summary = run_fleet([log], links, 3, speed=20.0, stagger_s=0.01, sysid_base=21)
    got = [_received(rx) for rx in rxs]
    for rx in rxs:
        rx.close()
    assert summary.frames_sent == 90 and summary.frames_failed == 0
    assert got[0] == got[1] and len(got[0]) == 90  # both services get every frame
    for sysid in (21, 22, 23):
        assert sum(1 for d in got[0] if d[5] == sysid) == 30
