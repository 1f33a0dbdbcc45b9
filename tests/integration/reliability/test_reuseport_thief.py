"""Issue 31 D3: with ``serve``'s default workers the UDP port is a ``SO_REUSEPORT`` group,
which a process of the same user can join with its own routing program (it then took
30,049 of 30,049 datagrams, and the service said nothing). A real thief process here:
the service must warn naming the port and the count, and take its traffic back."""

from __future__ import annotations

import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_observer.fleet.reuseport import PortGuard, bind_group, foreign_sockets, socket_inode
from glmav_testkit.fleet_helpers import OBS, wait_bound_udp

#: a process of the same user: joins the group, attaches a program that returns its own
#: socket (index 2, after the two workers'), prints the system id of each datagram
THIEF = r"""
import ctypes, socket, struct, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
s.bind(("127.0.0.1", int(sys.argv[1])))
prog = struct.pack("HBBI", 0x06, 0, 0, int(sys.argv[2]))  # BPF_RET|BPF_K index
buf = ctypes.create_string_buffer(prog, len(prog))
s.setsockopt(socket.SOL_SOCKET, 51, struct.pack("HP", 1, ctypes.addressof(buf)))
print("joined", flush=True)
while True:
    d = s.recv(65535)
    print(d[5] if d[:1] == b"\xfd" else -1, flush=True)
"""


def _lines(stream: object, q: queue.Queue[str]) -> None:
    for line in stream:  # type: ignore[attr-defined]
        q.put(line.rstrip("\n"))


def _attitude(mav: mavlink2.MAVLink, k: int) -> bytes:
    return bytes(mavlink2.MAVLink_attitude_message(10 * k, 0, 0, 0, 0, 0, 0).pack(mav))


@pytest.mark.timeout(120)
def test_a_same_user_thief_on_the_workers_port_is_warned_about_and_loses_the_traffic(
    free_udp_port: Callable[[], int],
) -> None:
    port = free_udp_port()
    serve = subprocess.Popen(
        [OBS, "serve", "--workers", "2", "--link", f"udpin:127.0.0.1:{port}", "--no-zenoh"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    errs: queue.Queue[str] = queue.Queue()
    threading.Thread(target=_lines, args=(serve.stderr, errs), daemon=True).start()
    thief: subprocess.Popen[str] | None = None
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mav1 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav9 = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
    stolen: queue.Queue[str] = queue.Queue()
    try:
        wait_bound_udp(port, serve)
        thief = subprocess.Popen(
            [sys.executable, "-c", THIEF, str(port), "2"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        threading.Thread(target=_lines, args=(thief.stdout, stolen), daemon=True).start()
        assert stolen.get(timeout=30.0) == "joined"
        # phase 1: vehicle 1 streams; the thief's program takes it until the service
        # sees the foreign socket (its check runs every second) and attaches its own again
        k = 0
        warned: list[str] = []
        deadline = time.monotonic() + 60.0  # events below; 60 s: a loaded 2-core host
        last_stolen = time.monotonic()
        n_stolen = 0
        while time.monotonic() < deadline:
            tx.sendto(_attitude(mav1, k), ("127.0.0.1", port))
            k += 1
            time.sleep(0.005)
            while not stolen.empty():
                stolen.get()
                n_stolen += 1
                last_stolen = time.monotonic()
            while not errs.empty():
                line = errs.get()
                if "another socket shares the UDP port" in line:
                    warned.append(line)
            # taken back: warned, and nothing stolen for 1 s (200 datagrams sent meanwhile)
            if warned and time.monotonic() - last_stolen > 1.0:
                break
        assert warned, "no warning about the foreign socket"
        assert str(port) in warned[0] and re.search(r"foreign_sockets\W+1\b", warned[0]), warned
        assert time.monotonic() - last_stolen > 1.0, "the thief still receives the traffic"
        # phase 2: 500 datagrams of vehicle 9: none reaches the thief
        for j in range(500):
            tx.sendto(_attitude(mav9, j), ("127.0.0.1", port))
            time.sleep(0.002)
        time.sleep(0.5)  # loopback delivery is immediate; the margin is for a loaded host
        got = []
        while not stolen.empty():
            got.append(stolen.get())
        assert "9" not in got
        n_stolen += len(got)
    finally:
        tx.close()
        if thief is not None:
            thief.kill()
            thief.wait(10.0)
        serve.send_signal(signal.SIGINT)
        stdout, _ = serve.communicate(timeout=60)
    assert serve.returncode == 0
    # every datagram reached one of the two (loopback: none lost), the service all but
    # what the thief took before the service took it back
    m = re.search(r"frames_ok=(\d+)", stdout)
    assert m is not None, stdout[-3000:]
    assert int(m.group(1)) + n_stolen == k + 500
    assert n_stolen < k
    assert re.search(r"foreign_sockets_on_port=1\b", stdout), stdout[-3000:]


def test_the_guard_sees_a_socket_that_joined_the_group(free_udp_port: Callable[[], int]) -> None:
    port = free_udp_port()
    conn = f"udpin:127.0.0.1:{port}"
    socks = bind_group(conn, 2, 1 << 16)
    guard = PortGuard()
    guard.watch(conn, socks)
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert foreign_sockets("127.0.0.1", port, {socket_inode(s) for s in socks}) == set()
        assert guard.check() == []
        other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        other.bind(("127.0.0.1", port))  # same user, same option: Linux lets it join
        assert foreign_sockets("127.0.0.1", port, {socket_inode(s) for s in socks}) == {
            socket_inode(other)
        }
        assert guard.check() == [conn] and guard.foreign == {conn: 1}
    finally:
        other.close()
        for s in socks:
            s.close()
    assert guard.check() == []


@pytest.mark.timeout(120)
def test_a_same_user_thief_cannot_join_the_one_worker_port(
    free_udp_port: Callable[[], int],
) -> None:
    """D3 with ``--workers 1``: the one process binds its port without ``SO_REUSEPORT``,
    so the same thief is refused at its bind and every datagram reaches the service."""
    port = free_udp_port()
    serve = subprocess.Popen(
        [OBS, "serve", "--workers", "1", "--link", f"udpin:127.0.0.1:{port}", "--no-zenoh"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mav1 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    try:
        wait_bound_udp(port, serve)
        thief = subprocess.run(
            [sys.executable, "-c", THIEF, str(port), "0"],
            capture_output=True, text=True, timeout=60, check=False,
        )  # fmt: skip
        assert thief.returncode != 0 and "Address already in use" in thief.stderr
        assert "joined" not in thief.stdout
        for k in range(500):
            tx.sendto(_attitude(mav1, k), ("127.0.0.1", port))
            time.sleep(0.002)
        time.sleep(0.5)  # loopback delivery is immediate; the margin is for a loaded host
    finally:
        tx.close()
        serve.send_signal(signal.SIGINT)
        stdout, stderr = serve.communicate(timeout=60)
    assert serve.returncode == 0, stderr[-3000:]
    assert re.search(r"frames_ok=500\b", stdout), stdout[-3000:]
    assert "foreign_sockets_on_port" not in stdout
