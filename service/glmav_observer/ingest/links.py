"""Links: pymavlink connection strings as byte transports (the edge of ingest).

We use ``pymavlink.mavutil`` only to open what users name in the connection strings
they know (``udpin:``, ``udpout:``, ``tcp:``, ``tcpin:``, serial devices ``/dev/...``
with an optional ``,BAUD``); its own parser is not used: bytes go to our
:class:`~glmav_observer.ingest.framing.FrameDecoder`, which counts every bad frame.
``.tlog`` files are replayed by :func:`glmav_observer.app.replay_tlog`, not here.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import socket
import time
from typing import Any

logger = logging.getLogger(__name__)

_UDP_MAX = 65535
#: TCP client links: reconnect delay after a disconnect, doubling up to the maximum (s).
RECONNECT_FIRST_S = 0.1
RECONNECT_MAX_S = 5.0


class LinkError(ValueError):
    """A connection string that cannot be opened (named in the message)."""


class Link:
    """One open link: ``read()`` returns the bytes available (one datagram for UDP)."""

    def __init__(self, conn: str, *, udp_receive_buffer_bytes: int = 4 * 1024 * 1024) -> None:
        from pymavlink import mavutil  # deferred: mavutil changes os.environ at import

        self.conn = conn
        self.datagram = conn.startswith(("udpin:", "udpout:", "udp:", "udpbcast:"))
        if conn.endswith(".tlog"):
            raise LinkError(f"{conn}: a .tlog is replayed with `glmav-observer replay`")
        try:
            self._m: Any = mavutil.mavlink_connection(
                conn, source_system=255, source_component=190, autoreconnect=True
            )
        except (OSError, ValueError) as err:
            raise LinkError(f"{conn}: cannot open: {err}") from err
        #: the sender of the last datagram read (UDP), to answer that vehicle
        self.peer: Any = None
        #: link events (``tcp_disconnects``, ``tcp_reconnects``)
        self.counters: collections.Counter[str] = collections.Counter()
        #: a TCP client link (``tcp:HOST:PORT``) reconnects on EOF or error, with backoff
        self.reconnects = conn.startswith("tcp:")
        self._down = False
        self._retry_at = 0.0
        self._backoff_s = RECONNECT_FIRST_S
        port = getattr(self._m, "port", None)
        self._sock: socket.socket | None = port if isinstance(port, socket.socket) else None
        if self._sock is not None:
            self._sock.setblocking(False)
            if self.datagram:
                try:
                    self._sock.setsockopt(
                        socket.SOL_SOCKET, socket.SO_RCVBUF, udp_receive_buffer_bytes
                    )
                except OSError as err:  # a limit of the OS: keep the default buffer
                    logger.warning("SO_RCVBUF not set", extra={"link": conn, "error": str(err)})

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
                if self.datagram:
                    data, addr = self._sock.recvfrom(_UDP_MAX)
                    self.peer = addr
                    if getattr(self._m, "udp_server", False):
                        self._m.last_address = addr  # replies go to the sender
                    return data
                data = self._sock.recv(_UDP_MAX)
                if not data and self.reconnects:
                    return self._disconnected("eof")
                return data
            except (BlockingIOError, InterruptedError):
                return b""
            except ConnectionRefusedError:
                return b""
            except OSError as err:
                if self.reconnects:
                    return self._disconnected(str(err))
                raise
        data = self._m.recv(_UDP_MAX)
        return bytes(data) if data else b""

    def write(self, data: bytes, peer: Any = None) -> None:
        """Send ``data``; on a UDP server link to ``peer`` (a vehicle's address) if given."""
        try:
            if peer is not None and self._sock is not None and self.datagram:
                self._sock.sendto(data, peer)
                return
            self._m.write(data)
        except OSError as err:
            logger.warning("link write failed", extra={"link": self.conn, "error": str(err)})

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
        with contextlib.suppress(OSError):
            self._m.close()
