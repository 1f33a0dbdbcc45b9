"""Helpers for the simulator's loopback tests: a UDP ground station and a background run."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.mavlink.links import Link
from glmav_sitl.runner import RunSummary, run


class UdpGroundStation:
    """Listens on 127.0.0.1:port, parses MAVLink 2, answers on the sender's address."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.parser = mavlink2.MAVLink(None)
        self.gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.peer: tuple[str, int] | None = None
        self.received: list[tuple[float, Any]] = []  # (wall time, message)

    def poll(self) -> list[Any]:
        try:
            data, addr = self.sock.recvfrom(65535)
        except TimeoutError:
            return []
        self.peer = addr
        t = time.monotonic()
        msgs = self.parser.parse_buffer(data) or []
        self.received += [(t, m) for m in msgs]
        return msgs

    def wait_for(self, mtype: str, timeout_s: float, pred: Any = None) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for m in self.poll():
                if m.get_type() == mtype and (pred is None or pred(m)):
                    return m
        raise TimeoutError(f"no {mtype} within {timeout_s} s")

    def collect_for(self, seconds: float) -> list[tuple[float, Any]]:
        start = len(self.received)
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.poll()
        return self.received[start:]

    def command_long(self, target: int, cmd: int, *params: float) -> None:
        assert self.peer is not None, "no packet from the vehicle yet"
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        buf = mavlink2.MAVLink_command_long_message(target, 1, cmd, 0, *p).pack(self.gcs)
        self.sock.sendto(bytes(buf), self.peer)

    def close(self) -> None:
        self.sock.close()


@contextmanager
def background_run(**kw: Any) -> Iterator[tuple[threading.Event, list[RunSummary]]]:
    """Run the simulator in a thread; stop it (and join) on exit."""
    stop = threading.Event()
    started = threading.Event()
    out: list[RunSummary] = []
    errors: list[BaseException] = []

    def target() -> None:
        try:
            out.append(run(stop_event=stop, started=started, **kw))
        except BaseException as e:
            errors.append(e)
            started.set()

    th = threading.Thread(target=target, daemon=True)
    th.start()
    assert started.wait(10.0), "simulator did not start"
    try:
        yield stop, out
    finally:
        stop.set()
        th.join(10.0)
    assert not th.is_alive(), "simulator did not stop"
    if errors:
        raise errors[0]


class MemoryLink(Link):
    """A simulator link whose peer is the test: bytes out are kept, bytes in are queued."""

    def __init__(self) -> None:
        super().__init__("memory")
        self.out: list[bytes] = []
        self.inbox: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.out.append(bytes(buf))

    def read(self) -> list[bytes]:
        data, self.inbox = self.inbox, []
        return data

    def close(self) -> None:
        pass


def decode_mavlink(bufs: list[bytes]) -> list[Any]:
    """Every MAVLink 2 message in ``bufs`` (the simulator's output), decoded."""
    p = mavlink2.MAVLink(None)
    out: list[Any] = []
    for b in bufs:
        out += p.parse_buffer(b) or []
    return out
