"""UDP links of ``serve --workers N`` routed by the kernel: one socket per worker.

Without this, the parent process reads every datagram of a ``udpin:`` link and passes it
through a pipe to its vehicle's worker: a read, a pickle, a write, a wake-up and an
unpickle per datagram in a second process, and a batch's wait before the worker sees it.
Here the N workers each hold a socket of one ``SO_REUSEPORT`` group bound to the link's
address, and the group carries a classic BPF program (``SO_ATTACH_REUSEPORT_CBPF``,
Linux ≥ 4.5) that reads the system id from the MAVLink header and returns the owning
worker's socket (:func:`~glmav_observer.fleet.routing.reuseport_program`, the same rule
as the parent's :func:`~glmav_observer.fleet.routing.worker_of_sysid`). Each worker reads
its vehicles' datagrams itself, and answers them (rate requests) from the same port.

The port stays ours: it is first bound without ``SO_REUSEPORT`` (a port another process
holds fails there, with the same :class:`~glmav_observer.ingest.links.LinkError` as one
process), then released and bound as the group. Linux refuses other users' sockets in
the group, but a process of the **same user** that sets ``SO_REUSEPORT`` can join it
and attach its own program, which replaces ours for the whole group: it then receives
every datagram (issue 31 D3: 30,049 of 30,049, and the service said nothing). Linux has
no way to close a group to newcomers, so the port is watched instead
(:class:`PortGuard`): the sockets bound to the port (``/proc/net/udp``, ``udp6``, by
inode) are compared with the group's own. A foreign socket right after the group bind
(it joined between the exclusive bind and ours) is a :class:`LinkError` (exit 2); one
that joins later is warned about at once (the port and the count) and at each change,
counted (``foreign_sockets_on_port``), and our program is attached again at every check
(1 s) while it is there, so that the thief's socket (past the N first) gets nothing
after at most a second.

The sockets are created in the parent, in worker order, and given to the workers when
they start (a ``multiprocessing`` spawn passes the descriptors); the parent closes its
copies once they run, so a worker that dies leaves the group and the kernel hands its
vehicles to the others (the program's index past the group falls back to the kernel's
hash) instead of queueing them on a socket nobody reads.

Where the kernel or a sandbox refuses the program, :func:`bind_group` raises
:class:`ReuseportUnavailableError` and the link is read by the parent as before.
"""

from __future__ import annotations

import ctypes
import errno
import logging
import os
import socket
import struct
import time

from glmav_observer.fleet.routing import reuseport_program
from glmav_observer.ingest.links import LinkError, bind_udp, check_connection_string

logger = logging.getLogger(__name__)

#: linux/asm-generic/socket.h
SO_ATTACH_REUSEPORT_CBPF = 51
#: exclusive bind then group bind, tried this often (another bind between the two)
GROUP_BIND_ATTEMPTS = 3


class ReuseportUnavailableError(OSError):
    """The OS cannot route a UDP port by program (not Linux, an old kernel, a sandbox)."""


def is_kernel_routable(conn: str) -> bool:
    """Whether ``conn`` is a UDP server link the kernel can route (``udpin:``/``udp:``)."""
    try:
        parsed = check_connection_string(conn)
    except LinkError:
        return False
    return parsed is not None and parsed[0] in ("udpin", "udp")


def attach_program(sock: socket.socket, n_workers: int) -> None:
    """Attach the routing program to ``sock``'s reuseport group."""
    program = reuseport_program(n_workers)
    code = b"".join(struct.pack("HBBI", *ins) for ins in program)
    buf = ctypes.create_string_buffer(code, len(code))
    # struct sock_fprog { unsigned short len; struct sock_filter *filter; }: the kernel
    # copies the filter from the pointer during the call (buf is alive until it returns)
    fprog = struct.pack("HP", len(program), ctypes.addressof(buf))
    sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_REUSEPORT_CBPF, fprog)


def bind_group(conn: str, n_workers: int, rcvbuf: int) -> list[socket.socket]:
    """``n_workers`` non-blocking UDP sockets on ``conn``'s address, socket i receiving
    the datagrams of the vehicles worker i owns.

    Raises :class:`LinkError` for a port that is taken or cannot be bound (the message
    names it), :class:`ReuseportUnavailableError` when the OS cannot route by program."""
    parsed = check_connection_string(conn)
    if parsed is None or parsed[0] not in ("udpin", "udp"):
        raise LinkError(f"{conn}: only a udpin:HOST:PORT link is routed by the kernel")
    _, host, port = parsed
    if not hasattr(socket, "SO_REUSEPORT"):
        raise ReuseportUnavailableError(errno.ENOPROTOOPT, "no SO_REUSEPORT on this OS")
    for attempt in range(GROUP_BIND_ATTEMPTS):
        # the exclusive bind: a taken port is a LinkError naming it, as with one process
        bind_udp(conn, host, port, rcvbuf).close()
        socks: list[socket.socket] = []
        try:
            for _ in range(n_workers):
                socks.append(bind_udp(conn, host, port, rcvbuf, reuseport=True))
            try:
                attach_program(socks[0], n_workers)
            except OSError as err:
                raise ReuseportUnavailableError(
                    err.errno, f"routing program refused: {err}"
                ) from None
        except LinkError:
            for s in socks:
                s.close()
            if attempt + 1 == GROUP_BIND_ATTEMPTS:
                raise
            # somebody bound the port between our exclusive bind and the group (a probe
            # that releases it at once): the exclusive bind says whether it is still taken
            time.sleep(0.01)
            continue
        except BaseException:
            for s in socks:
                s.close()
            raise
        foreign = foreign_sockets(host, port, {socket_inode(s) for s in socks})
        if foreign:
            for s in socks:
                s.close()
            raise LinkError(
                f"{conn}: {len(foreign)} socket(s) of another process joined port {port} "
                "with SO_REUSEPORT while it was being bound (a process of the same user): "
                "refusing to share the vehicles' traffic"
            )
        return socks
    raise AssertionError("unreachable")  # the loop returns or raises


def socket_inode(sock: socket.socket) -> int:
    """The socket's inode, as /proc/net/udp lists it."""
    return os.fstat(sock.fileno()).st_ino


def _covers(local_hex: str, host: str) -> bool:
    """Whether a /proc/net/udp local address (hex, 32-bit words in host byte order) is
    ``host`` or a wildcard that covers it."""
    raw = bytes.fromhex(local_hex)
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    if len(words) == 4:
        return socket.inet_ntop(socket.AF_INET, words) in (host, "0.0.0.0")
    return socket.inet_ntop(socket.AF_INET6, words) in ("::", host, f"::ffff:{host}")


def udp_sockets_on_port(host: str, port: int) -> set[int]:
    """Inodes of the UDP sockets of this network namespace bound to ``port`` on ``host``
    or a wildcard address (/proc/net/udp and udp6; empty where they are absent)."""
    found: set[int] = set()
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table, encoding="ascii") as f:
                lines = f.readlines()[1:]
        except OSError:
            continue
        for line in lines:
            cols = line.split()
            if len(cols) < 10:
                continue
            addr_hex, _, port_hex = cols[1].partition(":")
            if int(port_hex, 16) == port and _covers(addr_hex, host):
                found.add(int(cols[9]))
    return found


def foreign_sockets(host: str, port: int, own: set[int]) -> set[int]:
    """The sockets on ``host:port`` that are not ``own`` (inodes)."""
    return udp_sockets_on_port(host, port) - own


class PortGuard:
    """Watches the kernel-routed ports for sockets that are not the workers' (see the
    module doc): :meth:`check` at the parent's periodic checks."""

    def __init__(self) -> None:
        #: link -> (host, port, the group's inodes)
        self._ports: dict[str, tuple[str, int, set[int]]] = {}
        self._last: dict[str, int] = {}
        #: link -> the most foreign sockets seen at once
        self.foreign: dict[str, int] = {}

    def watch(self, conn: str, socks: list[socket.socket]) -> None:
        parsed = check_connection_string(conn)
        assert parsed is not None
        self._ports[conn] = (parsed[1], parsed[2], {socket_inode(s) for s in socks})

    def check(self) -> list[str]:
        """The links with a foreign socket on their port now (warned when the count
        changes)."""
        bad = []
        for conn, (host, port, own) in self._ports.items():
            n = len(foreign_sockets(host, port, own))
            if n != self._last.get(conn, 0):
                if n:
                    logger.warning(
                        "another socket shares the UDP port of this link (SO_REUSEPORT, a "
                        "process of the same user): it may take the vehicles' datagrams; "
                        "the routing program is attached again",
                        extra={"link": conn, "port": port, "foreign_sockets": n},
                    )
                else:
                    logger.warning(
                        "the foreign socket left the UDP port of this link",
                        extra={"link": conn, "port": port},
                    )
                self._last[conn] = n
            if n:
                self.foreign[conn] = max(n, self.foreign.get(conn, 0))
                bad.append(conn)
        return bad
