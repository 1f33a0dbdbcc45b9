"""A small MAVLink vehicle on a link of its own, for the rate-request tests: a TCP server on
127.0.0.1 (as ArduPilot's SITL serves 5760), a pseudo-terminal (a serial port: the service
opens its other end as ``/dev/pts/N,BAUD``) or a UDP sender (one frame a datagram). It streams at its own rates, answers
SET_MESSAGE_INTERVAL and GET_MESSAGE_INTERVAL as an autopilot does, logs every command in
its own boot time, and can drop its TCP link, come back and reboot (its time_boot going back
to 0, its rates to its defaults, as a real autopilot's do).

Its clock runs at real speed (host monotonic time since its boot), so that "within 2 s of
the reboot" is read off the vehicle's own time of each command.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from glmav_observer.ingest.rates import MESSAGE_IDS

_NAMES = {i: m for m, i in MESSAGE_IDS.items()}

#: an autopilot's highest stream rate (ArduPilot's streams are capped by its loop, 50 Hz on
#: a SITL serial port); requests above are served at this rate
MAX_HZ = 50.0
_CMD_GET = mavlink.MAV_CMD_GET_MESSAGE_INTERVAL
_CMD_SET = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
#: a SiK radio's transmit buffer (bytes)
RADIO_BUFFER_BYTES = 2048
#: the streams it can send
STREAMS = ("ATTITUDE", "HIGHRES_IMU", "LOCAL_POSITION_NED", "GPS_RAW_INT", "EKF_STATUS_REPORT")


@dataclass(frozen=True)
class Command:
    """One command received: the boot it came in, its time in that boot (s), the command,
    the message id and the interval asked (param2, µs)."""

    boot: int
    t_boot_s: float
    command: int
    message: str
    interval_us: float


@dataclass
class StreamVehicle:
    """The vehicle (see the module). ``defaults_hz``: its rates at boot (0: not sent);
    ``radio_bytes_per_s``: behind a telemetry radio that carries this many bytes per second
    (None: none), which buffers up to ``RADIO_BUFFER_BYTES`` (then drops frames) and
    reports its free buffer in a RADIO_STATUS at 1 Hz, as a SiK radio does."""

    port: int
    defaults_hz: Mapping[str, float]
    sysid: int = 1
    radio_bytes_per_s: float | None = None
    radio_dropped_frames: int = 0
    commands: list[Command] = field(default_factory=list)
    #: per boot: the boot time (s) a client connected
    accepted: list[tuple[int, float]] = field(default_factory=list)
    boot: int = 0
    bytes_sent: int = 0
    _t0: float = 0.0
    _hz: dict[str, float] = field(default_factory=dict)
    _next: dict[str, float] = field(default_factory=dict)
    _listener: socket.socket | None = None
    _client: socket.socket | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _mav: Any = None
    _parser: Any = None
    _radio_mav: Any = None
    _radio_buf: bytearray = field(default_factory=bytearray)
    _radio_t: float = 0.0
    _radio_allowance: float = 0.0
    _pty_slave: int | None = None

    # -- control (from the test) ---------------------------------------------------------
    def start(self) -> StreamVehicle:
        self.reboot()
        self.listen()
        self._thread = threading.Thread(target=self._serve, name="tcp-vehicle", daemon=True)
        self._thread.start()
        return self

    def start_udp(self, service_port: int) -> StreamVehicle:
        """Start as a UDP sender to ``udpin:127.0.0.1:service_port`` (one frame a datagram),
        from 127.0.0.1:``port``, instead of a TCP server."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", self.port))
        sock.connect(("127.0.0.1", service_port))
        sock.setblocking(False)
        self.reboot()
        with self._lock:
            self._client = sock
            self.accepted.append((self.boot, 0.0))
        self._thread = threading.Thread(target=self._serve, name="udp-vehicle", daemon=True)
        self._thread.start()
        return self

    def start_pty(self) -> str:
        """Start on a pseudo-terminal instead of TCP; returns the serial device's path."""
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline before the service opens it
        os.set_blocking(master, False)
        self._pty_slave = slave
        self.reboot()
        with self._lock:
            self._client = _PtyEnd(master)  # type: ignore[assignment]
            self.accepted.append((self.boot, 0.0))
        self._thread = threading.Thread(target=self._serve, name="pty-vehicle", daemon=True)
        self._thread.start()
        return os.ttyname(slave)

    def reboot(self) -> None:
        """time_boot back to 0, the rates back to the defaults (the link stays)."""
        with self._lock:
            self.boot += 1
            self._t0 = time.monotonic()
            self._hz = {m: float(self.defaults_hz.get(m, 0.0)) for m in STREAMS}
            self._next = {m: 0.0 for m in STREAMS}
            self._next["HEARTBEAT"] = 0.0
            self._next["RADIO_STATUS"] = 0.0
            self._mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
            self._radio_mav = mavlink.MAVLink(None, srcSystem=51, srcComponent=68)
            self._parser = mavlink.MAVLink(None)
            self._parser.robust_parsing = True

    def listen(self) -> None:
        """Accept a connection on the port (again)."""
        ls = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        ls.bind(("127.0.0.1", self.port))
        ls.listen(1)
        ls.setblocking(False)
        with self._lock:
            self._listener = ls

    def drop(self) -> None:
        """The link goes away: the connection and the listener close (connections refused)."""
        with self._lock:
            for s in (self._client, self._listener):
                if s is not None:
                    s.close()
            self._client = self._listener = None

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.drop()
        if self._pty_slave is not None:
            os.close(self._pty_slave)
            self._pty_slave = None

    def t_boot_s(self) -> float:
        return time.monotonic() - self._t0

    def rate_hz(self, message: str) -> float:
        """The rate the vehicle sends ``message`` at now."""
        with self._lock:
            return self._hz.get(message, 0.0)

    def sets(self, message: str, boot: int | None = None) -> list[Command]:
        """The SET_MESSAGE_INTERVAL commands for ``message`` (in ``boot``, if given)."""
        with self._lock:
            return [
                c
                for c in self.commands
                if c.command == _CMD_SET
                and c.message == message
                and (boot is None or c.boot == boot)
            ]

    def gets(self, message: str) -> list[Command]:
        with self._lock:
            return [c for c in self.commands if c.command == _CMD_GET and c.message == message]

    # -- the vehicle ---------------------------------------------------------------------
    def _serve(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                ls, cl = self._listener, self._client
            if cl is None and ls is not None:
                with contextlib.suppress(BlockingIOError, OSError):
                    conn, _ = ls.accept()
                    conn.setblocking(False)
                    with self._lock:
                        self._client = conn
                        self.accepted.append((self.boot, self.t_boot_s()))
                    continue
            if cl is not None:
                self._read(cl)
                self._stream(cl)
            time.sleep(0.002)

    def _read(self, cl: socket.socket) -> None:
        try:
            ready, _, _ = select.select([cl], [], [], 0)
            if not ready:
                return
            data = cl.recv(65536)
        except OSError:
            return
        if not data:
            with self._lock:
                if self._client is cl:
                    cl.close()
                    self._client = None
            return
        with self._lock:
            msgs = self._parser.parse_buffer(data) or []
            for m in msgs:
                if m.get_type() == "COMMAND_LONG" and m.target_system in (0, self.sysid):
                    self._command(cl, m)

    def _command(self, cl: socket.socket, m: Any) -> None:
        """One COMMAND_LONG (the caller holds the lock)."""
        cmd = int(m.command)
        name = _NAMES.get(int(m.param1), str(int(m.param1)))
        self.commands.append(Command(self.boot, self.t_boot_s(), cmd, name, float(m.param2)))
        result = mavlink.MAV_RESULT_UNSUPPORTED
        if cmd in (_CMD_GET, _CMD_SET) and name in STREAMS:
            result = mavlink.MAV_RESULT_ACCEPTED
            if cmd == _CMD_GET:
                hz = self._hz[name]
                self._send(
                    cl,
                    mavlink.MAVLink_message_interval_message(
                        MESSAGE_IDS[name], round(1e6 / hz) if hz > 0 else -1
                    ),
                )
            else:
                iv = float(m.param2)
                default = float(self.defaults_hz.get(name, 0.0))
                self._hz[name] = 0.0 if iv < 0 else default if iv == 0 else min(1e6 / iv, MAX_HZ)
        self._send(
            cl,
            mavlink.MAVLink_command_ack_message(
                cmd, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()
            ),
        )

    def _send(self, cl: socket.socket, msg: Any) -> None:
        frame = bytes(msg.pack(self._mav))
        if self.radio_bytes_per_s is not None:
            if len(self._radio_buf) + len(frame) > RADIO_BUFFER_BYTES:
                self.radio_dropped_frames += 1
            else:
                self._radio_buf += frame
            return
        with contextlib.suppress(OSError):
            cl.sendall(frame)
            self.bytes_sent += len(frame)

    def _radio(self, cl: socket.socket) -> None:
        """The radio sends what its capacity allows since the last turn (the caller holds
        the lock)."""
        now = time.monotonic()
        if self._radio_t == 0.0:
            self._radio_t = now
        assert self.radio_bytes_per_s is not None
        self._radio_allowance += (now - self._radio_t) * self.radio_bytes_per_s
        self._radio_t = now
        n = min(int(self._radio_allowance), len(self._radio_buf))
        if n <= 0:
            self._radio_allowance = min(self._radio_allowance, 100.0)  # no credit when idle
            return
        with contextlib.suppress(OSError):
            cl.sendall(bytes(self._radio_buf[:n]))
            self.bytes_sent += n
        del self._radio_buf[:n]
        self._radio_allowance -= n

    def _stream(self, cl: socket.socket) -> None:
        with self._lock:
            t = self.t_boot_s()
            ms, us = int(t * 1e3), int(t * 1e6)
            out: list[Any] = []
            if t >= self._next["HEARTBEAT"]:
                self._next["HEARTBEAT"] = t + 1.0
                out.append(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))  # quad, ArduPilot
            if self.radio_bytes_per_s is not None and t >= self._next["RADIO_STATUS"]:
                # the radio's own status (SiK: system 51, component 68), first in its queue
                self._next["RADIO_STATUS"] = t + 1.0
                free = round(100 * (1 - len(self._radio_buf) / RADIO_BUFFER_BYTES))
                status = mavlink.MAVLink_radio_status_message(200, 190, free, 40, 40, 0, 0)
                self._radio_buf[:0] = bytes(status.pack(self._radio_mav))
            for name in STREAMS:
                hz = self._hz[name]
                if hz <= 0 or t < self._next[name]:
                    continue
                nxt = self._next[name] + 1.0 / hz
                self._next[name] = nxt if nxt > t else t + 1.0 / hz
                out.append(_stream_message(name, ms, us))
            for msg in out:
                self._send(cl, msg)
            if self.radio_bytes_per_s is not None:
                self._radio(cl)


def _stream_message(name: str, t_ms: int, t_us: int) -> Any:
    """A hovering vehicle's sample of ``name`` stamped ``t_ms``/``t_us`` (boot time)."""
    if name == "ATTITUDE":
        return mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if name == "HIGHRES_IMU":
        return mavlink.MAVLink_highres_imu_message(
            t_us, 0.0, 0.0, -9.80665, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1013.0, 0.0, 0.0, 20.0, 0x3F
        )
    if name == "LOCAL_POSITION_NED":
        return mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -10.0, 0.0, 0.0, 0.0)
    if name == "GPS_RAW_INT":
        return mavlink.MAVLink_gps_raw_int_message(t_us, 3, 0, 0, 10000, 100, 100, 0, 0, 12)
    return mavlink.MAVLink_ekf_status_report_message(0x1FF, 0.1, 0.1, 0.1, 0.1, 0.0)


class _PtyEnd:
    """The vehicle's end of a pseudo-terminal, read and written like its TCP socket."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def fileno(self) -> int:
        return self.fd

    def recv(self, n: int) -> bytes:
        return os.read(self.fd, n)

    def sendall(self, data: bytes) -> None:
        view = memoryview(data)
        while view:  # a full terminal buffer (nobody reads) raises: the rest is lost
            view = view[os.write(self.fd, view) :]

    def close(self) -> None:
        os.close(self.fd)
