"""Links: pymavlink connection strings as byte transports (the edge of ingest).

We use ``pymavlink.mavutil`` only to open what users name in the connection strings
they know (``udpout:``, ``tcp:``, ``tcpin:``, serial devices ``/dev/...`` with an
optional ``,BAUD``, through pyserial); its own parser is not used: bytes go to our
:class:`~glmav_observer.ingest.framing.FrameDecoder`, which counts every bad frame.
``.tlog`` files are replayed by :func:`glmav_observer.app_replay.replay_tlog`, not here.

``udpin:HOST:PORT`` (and its alias ``udp:``) is opened here, not by mavutil: mavutil
sets ``SO_REUSEADDR``, with which any local process that binds the same port with the
same option shares it and takes the vehicle's datagrams. Our socket sets neither
``SO_REUSEADDR`` nor ``SO_REUSEPORT``, so the port is ours alone: a port another
process holds (a ground station, a second ``serve``) is a :class:`LinkError` naming
it, and nobody can bind it while we hold it.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import importlib.util
import logging
import socket
import struct
import sys
import time
from collections.abc import Mapping
from typing import Any

from glmav_observer.ingest import udp_drain

logger = logging.getLogger(__name__)

_UDP_MAX = 65535
#: the kernel's receive time stamp of each datagram (linux/asm-generic/socket.h: 35)
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
#: struct timespec of the stamp: seconds and nanoseconds (CLOCK_REALTIME)
_TIMESPEC = struct.Struct("@qq")
_ANCILLARY_BYTES = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0
#: getsockopt(SOL_SOCKET, SO_MEMINFO) (linux/asm-generic/socket.h: 55; Python does not
#: name it): a socket's memory counters, SK_MEMINFO_DROPS the datagrams the kernel dropped
#: on it (the column ``drops`` of /proc/net/udp). Linux only: elsewhere 55 is another option
SO_MEMINFO = 55
_SK_MEMINFO = struct.Struct("=9I")  # SK_MEMINFO_RMEM_ALLOC ... SK_MEMINFO_DROPS (index 8)
_SK_MEMINFO_DROPS = 8
#: TCP client links: reconnect delay after a disconnect, doubling up to the maximum (s).
RECONNECT_FIRST_S = 0.1
RECONNECT_MAX_S = 5.0


class LinkError(ValueError):
    """A connection string that cannot be opened (named in the message)."""


#: kinds of connection string that name HOST:PORT (the port is checked before opening)
_NET_KINDS = ("udpin", "udp", "udpout", "udpbcast", "tcp", "tcpin")


def check_connection_string(conn: str) -> tuple[str, str, int] | None:
    """(kind, host, port) of a network connection string, None for a serial device.

    Raises :class:`LinkError` for an empty string, a missing host or a port that is
    not a number in 1..65535 (pymavlink would raise OverflowError or ValueError)."""
    if not conn or not conn.strip():
        raise LinkError("empty connection string (e.g. udpin:127.0.0.1:14551)")
    kind, sep, rest = conn.partition(":")
    if not sep or kind not in _NET_KINDS:
        if conn.startswith(("/", "COM")):
            return None  # a serial device, opened by mavutil through pyserial
        raise LinkError(
            f"{conn}: unknown connection string (udpin:HOST:PORT, udpout:HOST:PORT, "
            "tcp:HOST:PORT, tcpin:HOST:PORT or a serial device /dev/...[,BAUD])"
        )
    host, sep, port_s = rest.rpartition(":")
    if not sep or not host:
        raise LinkError(f"{conn}: expected {kind}:HOST:PORT")
    try:
        port = int(port_s)
    except ValueError:
        raise LinkError(f"{conn}: port {port_s!r} is not a number") from None
    if not 1 <= port <= 65535:
        raise LinkError(f"{conn}: port {port} is not in 1..65535")
    return kind, host, port


def bind_udp(
    conn: str, host: str, port: int, rcvbuf: int, *, reuseport: bool = False
) -> socket.socket:
    """A non-blocking UDP socket bound to host:port that no other process can share (see
    the module); with ``reuseport``, one of a ``SO_REUSEPORT`` group (the workers' sockets
    of :mod:`glmav_observer.fleet.reuseport`, which binds it exclusively first)."""
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except OSError as err:
        raise LinkError(f"{conn}: cannot resolve {host!r}: {err}") from None
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
        if reuseport:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        sock.bind(infos[0][4])
    except OSError as err:
        sock.close()
        if err.errno == errno.EADDRINUSE:
            raise LinkError(
                f"{conn}: UDP port {port} is already taken by another process "
                "(a ground station, a router or another serve?); "
                "choose another port or stop that process"
            ) from None
        raise LinkError(f"{conn}: cannot bind {host}:{port}: {err}") from None
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    except OSError as err:  # a limit of the OS: keep the default buffer
        logger.warning("SO_RCVBUF not set", extra={"link": conn, "error": str(err)})
    sock.setblocking(False)
    return sock


def _enable_stamps(sock: socket.socket) -> bool:
    """Ask for the kernel's receive stamps on ``sock``; False where the OS has none."""
    if not _ANCILLARY_BYTES or not hasattr(sock, "recvmsg"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def _arrival_s(ancillary: list[tuple[int, int, bytes]]) -> float:
    """The kernel's receive stamp of a datagram on ``time.monotonic``'s clock (now when
    there is none): the stamp is CLOCK_REALTIME, moved by the two clocks' offset now.
    Linux turns receive stamps on for the whole machine a moment after the first socket
    asks; a datagram that arrived before then is stamped when it is read."""
    now = time.monotonic()
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            t: float = sec + nsec * 1e-9 - (time.time() - now)
            return min(t, now)  # a clock step between the two reads must not make it later
    return now


#: datagrams read by one ``recvmmsg`` call of :meth:`Link.read_datagrams`
UDP_DRAIN_BATCH = 64

#: SO_RCVBUF asked for on UDP links (the OS may cap it: net.core.rmem_max).
DEFAULT_UDP_RECEIVE_BUFFER_BYTES = 4 * 1024 * 1024


class Link:
    """One open link: ``read()`` returns the bytes available (one datagram for UDP)."""

    def __init__(
        self,
        conn: str,
        *,
        udp_receive_buffer_bytes: int = DEFAULT_UDP_RECEIVE_BUFFER_BYTES,
        sock: socket.socket | None = None,
    ) -> None:
        """Open ``conn``; with ``sock``, a ``udpin:`` link on that socket, already bound
        (a worker's socket of a reuseport group: :mod:`glmav_observer.fleet.reuseport`)."""
        self.conn = conn
        self.datagram = conn.startswith(("udpin:", "udpout:", "udp:", "udpbcast:"))
        if conn.endswith(".tlog"):
            raise LinkError(f"{conn}: a .tlog is replayed with `glmav-observer replay`")
        parsed = check_connection_string(conn)
        #: the sender of the last datagram read (UDP), to answer that vehicle
        self.peer: Any = None
        #: when the last datagram read arrived, on ``time.monotonic``'s clock: the kernel's
        #: receive stamp on a ``udpin:`` socket (it includes the wait in the receive queue,
        #: which a backlog makes long), else the time it was read
        self.arrival_s = 0.0
        self._stamps = False
        self._m: Any = None
        if sock is not None:
            if parsed is None or parsed[0] not in ("udpin", "udp"):
                raise LinkError(f"{conn}: only a udpin:HOST:PORT link is opened on a socket")
            self._sock: socket.socket | None = sock
            sock.setblocking(False)
            self._stamps = _enable_stamps(sock)
        elif parsed is not None and parsed[0] in ("udpin", "udp"):
            self._sock = bind_udp(conn, parsed[1], parsed[2], udp_receive_buffer_bytes)
            self._stamps = _enable_stamps(self._sock)
        else:
            self._sock = self._open_mavutil(conn, serial=parsed is None)
            if self._sock is not None:
                self._sock.setblocking(False)
                if self.datagram:
                    try:
                        self._sock.setsockopt(
                            socket.SOL_SOCKET, socket.SO_RCVBUF, udp_receive_buffer_bytes
                        )
                    except OSError as err:  # a limit of the OS: keep the default buffer
                        logger.warning("SO_RCVBUF not set", extra={"link": conn, "error": str(err)})
        #: the UDP socket's drain (recvmmsg), where the OS has one
        self._drain: udp_drain.UdpDrain | None = None
        if (
            udp_drain.AVAILABLE
            and self.datagram
            and self._sock is not None
            and self._sock.family == socket.AF_INET
        ):
            self._drain = udp_drain.UdpDrain(self._sock.fileno(), UDP_DRAIN_BATCH, self._stamps)
        #: link events (``tcp_disconnects``, ``tcp_reconnects``)
        self.counters: collections.Counter[str] = collections.Counter()
        #: a TCP client link (``tcp:HOST:PORT``) reconnects on EOF or error, with backoff
        self.reconnects = conn.startswith("tcp:")
        self._down = False
        self._closed = False
        self._retry_at = 0.0
        self._backoff_s = RECONNECT_FIRST_S

    def _open_mavutil(self, conn: str, *, serial: bool) -> socket.socket | None:
        """Open ``conn`` with mavutil; its socket if it has one (None for serial)."""
        from pymavlink import mavutil  # deferred: mavutil changes os.environ at import

        if serial and importlib.util.find_spec("serial") is None:
            raise LinkError(f"{conn}: serial links need pyserial (pip install pyserial)")
        try:
            self._m = mavutil.mavlink_connection(
                conn, source_system=255, source_component=190, autoreconnect=True
            )
        except (OSError, ValueError, OverflowError) as err:
            raise LinkError(f"{conn}: cannot open: {err}") from None
        except Exception as err:  # pyserial's SerialException and other driver errors
            raise LinkError(f"{conn}: cannot open: {err}") from None
        port = getattr(self._m, "port", None)
        return port if isinstance(port, socket.socket) else None

    def fileno(self) -> int | None:
        """The descriptor to wait on, None while a TCP link is down (``read`` reconnects)."""
        if self._down:
            return None
        if self._sock is not None:
            return self._sock.fileno()
        fd: int = self._m.fd if getattr(self._m, "fd", None) is not None else self._m.port.fileno()
        return fd

    @property
    def down(self) -> bool:
        return self._down

    def _disconnected(self, why: str) -> bytes:
        self.counters["tcp_disconnects"] += 1
        logger.warning("link down", extra={"link": self.conn, "reason": why})
        if self._sock is not None:
            self._sock.close()
        self._down = True
        self._backoff_s = RECONNECT_FIRST_S
        self._retry_at = time.monotonic() + self._backoff_s
        return b""

    def _try_reconnect(self) -> None:
        now = time.monotonic()
        if now < self._retry_at:
            return
        host, port = self._m.destination_addr
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.settimeout(1.0)
        try:
            sock.connect((host, port))
        except OSError:
            sock.close()
            self._backoff_s = min(2.0 * self._backoff_s, RECONNECT_MAX_S)
            self._retry_at = now + self._backoff_s
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._m.port = sock  # mavutil writes through its port
        self._sock = sock
        self._down = False
        self.counters["tcp_reconnects"] += 1
        logger.info("link reconnected", extra={"link": self.conn})

    def read(self) -> bytes:
        """Bytes available now (b"" if none). UDP: exactly one datagram (sender in ``peer``).

        A TCP client link that reads EOF or an error goes down and is reconnected by later
        calls (0.1 s, doubling to 5 s between attempts).
        """
        if self._down:
            self._try_reconnect()
            return b""
        if self._sock is not None:
            try:
                if self._stamps:
                    data, anc, _flags, addr = self._sock.recvmsg(_UDP_MAX, _ANCILLARY_BYTES)
                    self.peer = addr
                    self.arrival_s = _arrival_s(anc)
                    return data
                if self.datagram:
                    data, addr = self._sock.recvfrom(_UDP_MAX)
                    self.arrival_s = time.monotonic()
                    self.peer = addr
                    if self._m is not None and getattr(self._m, "udp_server", False):
                        self._m.last_address = addr  # replies go to the sender
                    return data
                data = self._sock.recv(_UDP_MAX)
                self.arrival_s = time.monotonic()
                if not data and self.reconnects:
                    return self._disconnected("eof")
                return data
            except (BlockingIOError, InterruptedError):
                return b""
            except ConnectionRefusedError:
                return b""
            except OSError as err:
                if self._closed:
                    return b""  # closed by another thread while reading: nothing more comes
                if self.reconnects:
                    return self._disconnected(str(err))
                raise
        data = self._m.recv(_UDP_MAX)
        self.arrival_s = time.monotonic()
        return bytes(data) if data else b""

    def read_datagrams(self, max_n: int) -> list[tuple[bytes, float, Any]]:
        """Up to ``max_n`` datagrams waiting on a UDP link, in order: (bytes, arrival on
        ``time.monotonic``'s clock, sender) each, as :meth:`read` gives them one at a time
        (the same peers and arrival times; ``peer`` and ``arrival_s`` are left at the last
        datagram's). Fewer than ``max_n``: the socket is empty. An empty datagram is in
        the list as ``b""``. One ``recvmmsg`` system call reads ``UDP_DRAIN_BATCH`` of
        them (:mod:`glmav_observer.ingest.udp_drain`); elsewhere, one :meth:`read` each."""
        if self._drain is None:
            out: list[tuple[bytes, float, Any]] = []
            while len(out) < max_n:
                data = self.read()
                if not data:
                    break
                out.append((data, self.arrival_s, self.peer))
            return out
        try:
            got = self._drain.drain(max_n)
        except OSError:
            if self._closed:
                return []  # closed by another thread while reading: nothing more comes
            raise
        if got:
            _, self.arrival_s, self.peer = got[-1]
            if self._m is not None and getattr(self._m, "udp_server", False):
                self._m.last_address = self.peer  # replies go to the sender
        return got

    def write(self, data: bytes, peer: Any = None) -> bool:
        """Send ``data``; on a UDP server link to ``peer`` (a vehicle's address) if given.
        False if nothing was sent: the link is down (TCP), has no peer yet, or failed."""
        if self._down or self._closed:
            return False
        try:
            if self._m is None:  # our own udpin socket: answer the given or last sender
                to = peer if peer is not None else self.peer
                if to is None or self._sock is None:
                    return False
                self._sock.sendto(data, to)
                return True
            if peer is not None and self._sock is not None and self.datagram:
                self._sock.sendto(data, peer)
                return True
            if self.reconnects and self._sock is not None:
                # a TCP client link: our socket (mavutil's write hides errors, reconnects
                # by itself and blocks doing it)
                self._sock.sendall(data)
                return True
            self._m.write(data)
            return True
        except OSError as err:
            logger.warning("link write failed", extra={"link": self.conn, "error": str(err)})
            return False

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped on this link's UDP socket since it was opened: its
        receive buffer was full, because the service read too slowly (None: not a UDP
        socket of ours, closed, or an OS that does not say)."""
        if self._sock is None or not self.datagram or self._closed or sys.platform != "linux":
            return None
        try:
            raw = self._sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, _SK_MEMINFO.size)
        except OSError:
            return None
        if len(raw) < _SK_MEMINFO.size:
            return None
        return int(_SK_MEMINFO.unpack_from(raw)[_SK_MEMINFO_DROPS])

    def close(self) -> None:
        self._closed = True
        self._drain = None  # it holds the descriptor's number, which the OS will reuse
        if self._sock is not None:
            self._sock.close()
        if self._m is not None:
            with contextlib.suppress(OSError):
                self._m.close()


#: the summary's per-link counter of :class:`KernelDrops`
KERNEL_DROPS_COUNTER = "datagrams_dropped_by_kernel"


class KernelDrops:
    """Datagrams the kernel dropped on the UDP links because the service fell behind
    (:meth:`Link.kernel_drops`): read at each :meth:`check` (the service's periodic
    checks and its stop), kept per link, and said in a warning at the first drop and
    each time the count reaches ten times the last one said. A service over its capacity
    otherwise loses datagrams without a word: only the latency would show it."""

    def __init__(self) -> None:
        #: link id -> datagrams dropped (only links that dropped any)
        self.drops: dict[str, int] = {}
        self._warn_at: dict[str, int] = {}

    def check(self, links: Mapping[str, Link]) -> None:
        for lid, lk in links.items():
            n = lk.kernel_drops()
            if not n or n <= self.drops.get(lid, 0):
                continue
            self.drops[lid] = n
            if n >= self._warn_at.get(lid, 1):
                warn_at = 10
                while warn_at <= n:
                    warn_at *= 10
                self._warn_at[lid] = warn_at
                logger.warning(
                    "the kernel dropped datagrams: the service reads this link too slowly "
                    "(more vehicles or higher rates than its cores estimate: see "
                    "docs/deployment.md, serve --workers)",
                    extra={"link": lid, "dropped": n},
                )
