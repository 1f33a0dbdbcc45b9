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
process), then released and bound as the group. Only a process of the same user that
sets ``SO_REUSEPORT`` itself could join the group (Linux refuses other users); the
program never routes to a socket past the N first, so it would receive nothing.

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
import socket
import struct
import time

from glmav_observer.fleet.routing import reuseport_program
from glmav_observer.ingest.links import LinkError, bind_udp, check_connection_string

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


def _attach(sock: socket.socket, n_workers: int) -> None:
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
                _attach(socks[0], n_workers)
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
        return socks
    raise AssertionError("unreachable")  # the loop returns or raises
