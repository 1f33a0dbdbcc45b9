"""Byte links for the simulator, named by pymavlink-style connection strings.

Supported (the strings users know from pymavlink / MAVProxy):

- ``udpout:HOST:PORT``: send to HOST:PORT; replies come back on the same socket. The
  socket is connected to HOST:PORT: the kernel binds it to the address that reaches
  HOST (loopback for 127.0.0.1, never ``0.0.0.0``) and delivers only that peer's
  datagrams, so commands from any other sender never reach the vehicle.
- ``udpin:HOST:PORT`` (alias ``udp:``): listen on HOST:PORT; send to the last peer heard.
- ``tcp:HOST:PORT``: connect to a TCP server.
- ``tcpin:HOST:PORT``: listen for TCP clients; send to all of them.

All sockets are non-blocking; a failed send is counted and logged once, never raised
(a ground station that is not up yet must not stop the vehicle). We do not use
``pymavlink.mavutil`` here: it changes ``os.environ`` at import and keeps globals.
"""

from __future__ import annotations

import errno
import logging
import socket
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

_MAX_UDP = 65535


class LinkError(ValueError):
    """A connection string is malformed or its socket cannot be opened."""


def _host_port(conn: str, rest: str) -> tuple[str, int]:
    host, sep, port_s = rest.rpartition(":")
    if not sep or not host:
        raise LinkError(f"{conn!r}: expected KIND:HOST:PORT")
    try:
        port = int(port_s)
    except ValueError:
        raise LinkError(f"{conn!r}: port {port_s!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise LinkError(f"{conn!r}: port {port} out of range")
    return host, port


@dataclass
class Link:
    """One open link: ``write(bytes)``, ``read() -> list[bytes]``, ``close()``."""

    name: str
    sent_packets: int = 0
    failed_writes: int = 0
    received_bytes: int = 0
    _warned: bool = field(default=False, repr=False)

    def write(self, buf: bytes) -> None:
        raise NotImplementedError

    def read(self) -> list[bytes]:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def _failed(self, e: OSError) -> None:
        self.failed_writes += 1
        if not self._warned:
            self._warned = True
            log.warning(
                "link %s: send failed (%s); counting further failures silently", self.name, e
            )


class UdpLink(Link):
    def __init__(self, name: str, host: str, port: int, *, listen: bool) -> None:
        super().__init__(name)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if listen:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.sock.bind((host, port))
                self.peer: tuple[str, int] | None = None
            else:
                # resolve now so that a bad host fails at open, not on first send
                infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
                self.sock.connect(infos[0][4])  # bound to the route's address; peer only
                self.peer = (host, port)
        except OSError as e:
            self.sock.close()
            raise LinkError(f"{name!r}: {e}") from None
        self.sock.setblocking(False)
        self.listen = listen

    def write(self, buf: bytes) -> None:
        if self.peer is None:
            return
        try:
            if self.listen:
                self.sock.sendto(buf, self.peer)
            else:
                self.sock.send(buf)  # connected
            self.sent_packets += 1
        except OSError as e:
            self._failed(e)

    def read(self) -> list[bytes]:
        out = []
        while True:
            try:
                data, addr = self.sock.recvfrom(_MAX_UDP)
            except BlockingIOError:
                break
            except OSError as e:
                if e.errno in (errno.ECONNREFUSED, errno.ECONNRESET):
                    continue  # ICMP port unreachable from an earlier send
                break
            if self.listen:
                self.peer = (addr[0], addr[1])
            self.received_bytes += len(data)
            out.append(data)
        return out

    def close(self) -> None:
        self.sock.close()


class TcpClientLink(Link):
    def __init__(self, name: str, host: str, port: int) -> None:
        super().__init__(name)
        try:
            self.sock: socket.socket | None = socket.create_connection((host, port), timeout=5.0)
        except OSError as e:
            raise LinkError(f"{name!r}: {e}") from None
        self.sock.setblocking(False)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def write(self, buf: bytes) -> None:
        if self.sock is None:
            return
        try:
            self.sock.sendall(buf)
            self.sent_packets += 1
        except BlockingIOError as e:
            self._failed(e)  # peer too slow: drop, as a radio would
        except OSError as e:
            self._failed(e)
            self.close()

    def read(self) -> list[bytes]:
        out = []
        while self.sock is not None:
            try:
                data = self.sock.recv(_MAX_UDP)
            except BlockingIOError:
                break
            except OSError:
                self.close()
                break
            if not data:
                self.close()
                break
            self.received_bytes += len(data)
            out.append(data)
        return out

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class TcpServerLink(Link):
    def __init__(self, name: str, host: str, port: int) -> None:
        super().__init__(name)
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.server.bind((host, port))
            self.server.listen(8)
        except OSError as e:
            self.server.close()
            raise LinkError(f"{name!r}: {e}") from None
        self.server.setblocking(False)
        self.clients: list[socket.socket] = []

    def _accept(self) -> None:
        while True:
            try:
                c, _ = self.server.accept()
            except (BlockingIOError, OSError):
                return
            c.setblocking(False)
            c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.clients.append(c)

    def write(self, buf: bytes) -> None:
        for c in list(self.clients):
            try:
                c.sendall(buf)
                self.sent_packets += 1
            except BlockingIOError as e:
                self._failed(e)
            except OSError as e:
                self._failed(e)
                c.close()
                self.clients.remove(c)

    def read(self) -> list[bytes]:
        self._accept()
        out = []
        for c in list(self.clients):
            while True:
                try:
                    data = c.recv(_MAX_UDP)
                except BlockingIOError:
                    break
                except OSError:
                    data = b""
                if not data:
                    c.close()
                    self.clients.remove(c)
                    break
                self.received_bytes += len(data)
                out.append(data)
        return out

    def close(self) -> None:
        for c in self.clients:
            c.close()
        self.clients.clear()
        self.server.close()


def open_link(conn: str) -> Link:
    """Open the link named by a connection string (see the module docstring)."""
    kind, sep, rest = conn.partition(":")
    if not sep:
        raise LinkError(f"{conn!r}: expected KIND:HOST:PORT (udpout, udpin, udp, tcp, tcpin)")
    if kind not in ("udpout", "udpin", "udp", "tcp", "tcpin"):
        raise LinkError(
            f"{conn!r}: unsupported link kind {kind!r} (udpout, udpin, udp, tcp, tcpin)"
        )
    host, port = _host_port(conn, rest)
    if kind == "udpout":
        return UdpLink(conn, host, port, listen=False)
    if kind in ("udpin", "udp"):
        return UdpLink(conn, host, port, listen=True)
    if kind == "tcp":
        return TcpClientLink(conn, host, port)
    if kind == "tcpin":
        return TcpServerLink(conn, host, port)
    raise LinkError(f"{conn!r}: unsupported link kind {kind!r} (udpout, udpin, udp, tcp, tcpin)")
