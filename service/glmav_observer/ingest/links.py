"""Links: pymavlink connection strings as byte transports (the edge of ingest).

We use ``pymavlink.mavutil`` only to open what users name in the connection strings
they know (``udpin:``, ``udpout:``, ``tcp:``, ``tcpin:``, serial devices ``/dev/...``
with an optional ``,BAUD``); its own parser is not used: bytes go to our
:class:`~glmav_observer.ingest.framing.FrameDecoder`, which counts every bad frame.
``.tlog`` files are replayed by :func:`glmav_observer.app.replay_tlog`, not here.
"""

from __future__ import annotations

import logging
import socket
from typing import Any

logger = logging.getLogger(__name__)

_UDP_MAX = 65535


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

    def fileno(self) -> int:
        fd: int = self._m.fd if getattr(self._m, "fd", None) is not None else self._m.port.fileno()
        return fd

    def read(self) -> bytes:
        """Bytes available now (b"" if none). UDP: exactly one datagram (sender in ``peer``)."""
        if self._sock is not None:
            try:
                if self.datagram:
                    data, addr = self._sock.recvfrom(_UDP_MAX)
                    self.peer = addr
                    if getattr(self._m, "udp_server", False):
                        self._m.last_address = addr  # replies go to the sender
                    return data
                return self._sock.recv(_UDP_MAX)
            except (BlockingIOError, InterruptedError):
                return b""
            except ConnectionRefusedError:
                return b""
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
        self._m.close()
