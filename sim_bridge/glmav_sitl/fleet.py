"""``glmav-sitl fleet``: replay recorded ``.tlog`` files as K vehicles, cheaply.

A traffic generator that measures the service, not the simulator: one process reads
each log once, keeps the frames of the log's vehicle (the system id that sent most
frames; the ground station's own frames are left out), and sends them again as K
vehicles with distinct system ids (``--sysid-base`` + k) at their recorded rates.

Rewriting a frame is two byte writes: the system id (MAVLink 1: byte 3, MAVLink 2:
byte 5) and the CRC. The X.25 CRC is affine over GF(2), so the CRC of the rewritten
frame is the recorded CRC XOR a term that depends only on the changed bits and on how
many bytes follow them; that term is computed once per (distance, delta) and cached.
Signed MAVLink 2 frames cannot be re-signed without the key: their signature is
removed and the signed flag cleared (the output is unsigned), counted in
``signatures_stripped`` and said once on stderr. Frames whose recorded CRC is wrong, or
whose message the dialect does not know, are left out and counted.

Vehicle k starts ``k * stagger_s / K`` after the first (so K copies of one log do not
send in lock-step). Scheduling is a heap of vehicles keyed by the send time of their
next frame; a due vehicle sends every frame that is due (a bisect over the log's
times), then sleeps until the next one is. Links (repeat ``--link`` to fan the same
traffic out to several services, as mavlink-router does):

- ``udpout:HOST:PORT``: one UDP socket per vehicle (its own source port, as K radios),
  one datagram per frame;
- ``tcp:HOST:PORT`` (connect) / ``tcpin:HOST:PORT`` (listen): one stream carrying all
  vehicles, as from a router; the frames due at one turn are written together. A
  ``tcp:`` stream blocks when the reader is slow (the generator runs late, as the
  summary's lateness shows) rather than cutting a frame.

The summary gives the frames sent and the generator's own CPU time over wall time (the
fraction of one core it used).
"""

from __future__ import annotations

import argparse
import bisect
import heapq
import struct
import sys
import threading
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType

from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_sitl.mavlink.links import Link, LinkError, TcpClientLink, open_link

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_HEADER_V1 = 6
_HEADER_V2 = 10
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = 0x01
_STAMP = struct.Struct(">Q")
#: the MAVLink system id of a ground station (left out when picking the log's vehicle)
GCS_SYSID = 255


class FleetError(ValueError):
    """A log or option the generator cannot use (the message names it)."""


def _crc_byte(b: int, crc: int) -> int:
    """One step of the X.25 (CRC-16/MCRF4XX) checksum MAVLink uses."""
    tmp = b ^ (crc & 0xFF)
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


def x25_crc(data: bytes | bytearray, crc: int = 0xFFFF) -> int:
    for b in data:
        crc = _crc_byte(b, crc)
    return crc


_DELTA: dict[tuple[int, int], int] = {}


def crc_delta(delta: int, following: int) -> int:
    """The change of the CRC when one byte changes by ``delta`` (XOR) and ``following``
    bytes come after it in the checksummed span (the linear part of the CRC)."""
    key = (following, delta)
    d = _DELTA.get(key)
    if d is None:
        c = _crc_byte(delta, 0)
        for _ in range(following):
            c = _crc_byte(0, c)
        d = _DELTA[key] = c
    return d


@dataclass(frozen=True, slots=True)
class Frame:
    """One recorded frame, unsigned, ready to rewrite: where its sysid is and its CRC."""

    t_s: float  # host time from the log's first frame
    data: bytes  # the frame (signature removed)
    sysid_pos: int
    crc_pos: int  # the two CRC bytes (little-endian)
    crc_following: int  # bytes after the sysid in the checksummed span, crc_extra included


@dataclass
class Log:
    """The frames of one log's vehicle, in time order."""

    path: str
    sysid: int
    frames: list[Frame]
    counters: Counter[str] = field(default_factory=Counter)

    @property
    def duration_s(self) -> float:
        return self.frames[-1].t_s if self.frames else 0.0

    @property
    def times(self) -> list[float]:
        return [f.t_s for f in self.frames]


def _crc_extra(msgid: int) -> int | None:
    cls = dialect.mavlink_map.get(msgid)
    return None if cls is None else int(cls.crc_extra)


def _parse_frame(data: bytes, p: int) -> tuple[int, int, int, int] | None:
    """(length with signature, sysid, msgid, header length) of the frame at ``p``."""
    n = len(data)
    if p >= n:
        return None
    magic = data[p]
    if magic == MAGIC_V2:
        if p + _HEADER_V2 > n:
            return None
        plen = data[p + 1]
        length = _HEADER_V2 + plen + 2 + (_SIGNATURE_LEN if data[p + 2] & _IFLAG_SIGNED else 0)
        msgid = data[p + 7] | data[p + 8] << 8 | data[p + 9] << 16
        return length, data[p + 5], msgid, _HEADER_V2
    if magic == MAGIC_V1:
        if p + _HEADER_V1 > n:
            return None
        return _HEADER_V1 + data[p + 1] + 2, data[p + 3], data[p + 5], _HEADER_V1
    return None


def load_tlog(path: str | Path) -> Log:
    """Read a ``.tlog`` once: the frames of its vehicle, unsigned, CRC-checked.

    Raises :class:`FleetError` for a file that cannot be read or holds no vehicle."""
    name = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise FleetError(f"{name}: cannot read: {err.strerror or err}") from err
    counters: Counter[str] = Counter()
    raw: list[tuple[int, int, bytes, int]] = []  # (t_us, sysid, frame, header length)
    p = 0
    n = len(data)
    while p + 8 < n:
        (t_us,) = _STAMP.unpack_from(data, p)
        hdr = _parse_frame(data, p + 8)
        if hdr is None or p + 8 + hdr[0] > n:
            # not a record start: resync one byte on (the next magic with a stamp before it)
            counters["resync_bytes"] += 1
            p += 1
            continue
        length, sysid, msgid, hlen = hdr
        frame = data[p + 8 : p + 8 + length]
        extra = _crc_extra(msgid)
        signed = frame[0] == MAGIC_V2 and frame[2] & _IFLAG_SIGNED
        end = length - (_SIGNATURE_LEN if signed else 0)
        if extra is None:
            counters["unknown_message"] += 1
        elif x25_crc(bytes([extra]), x25_crc(frame[1 : end - 2])) != int.from_bytes(
            frame[end - 2 : end], "little"
        ):
            counters["bad_crc"] += 1
            p += 1
            continue
        else:
            raw.append((t_us, sysid, frame, hlen))
        p += 8 + length
    by_sysid = Counter(s for _, s, _, _ in raw if s != GCS_SYSID)
    if not by_sysid:
        raise FleetError(f"{name}: no vehicle frames (a .tlog of MAVLink frames is expected)")
    sysid = by_sysid.most_common(1)[0][0]
    t0 = min(t for t, s, _, _ in raw if s == sysid)
    frames: list[Frame] = []
    last_t = 0.0
    for t_us, s, frame, _hlen in raw:
        if s != sysid:
            counters["other_system"] += 1
            continue
        buf = bytearray(frame)
        if buf[0] == MAGIC_V2 and buf[2] & _IFLAG_SIGNED:
            # unsigned copy: drop the signature, clear the flag, fix the CRC for that bit
            del buf[-_SIGNATURE_LEN:]
            buf[2] &= ~_IFLAG_SIGNED
            crc = int.from_bytes(buf[-2:], "little") ^ crc_delta(_IFLAG_SIGNED, len(buf) - 2 - 2)
            buf[-2:] = crc.to_bytes(2, "little")
            counters["signatures_stripped"] += 1
        sysid_pos = 5 if buf[0] == MAGIC_V2 else 3
        # checksummed span: bytes 1 .. len-3, then crc_extra; bytes after the sysid in it
        following = (len(buf) - 2) - (sysid_pos + 1) + 1
        t_s = max(last_t, (t_us - t0) * 1e-6)  # a log's clock never runs back here
        last_t = t_s
        frames.append(Frame(t_s, bytes(buf), sysid_pos, len(buf) - 2, following))
    counters["frames"] = len(frames)
    return Log(name, sysid, frames, counters)


def rewrite(frame: Frame, sysid: int) -> bytes:
    """``frame`` as sent by system ``sysid`` (CRC fixed)."""
    data = frame.data
    old = data[frame.sysid_pos]
    if old == sysid:
        return data
    buf = bytearray(data)
    buf[frame.sysid_pos] = sysid
    c = frame.crc_pos
    crc = (buf[c] | buf[c + 1] << 8) ^ crc_delta(old ^ sysid, frame.crc_following)
    buf[c] = crc & 0xFF
    buf[c + 1] = crc >> 8
    return bytes(buf)


@dataclass
class FleetSummary:
    vehicles: int
    frames_sent: int
    frames_failed: int
    wall_s: float
    cpu_s: float
    late_max_s: float
    counters: dict[str, int]

    @property
    def core_fraction(self) -> float:
        """The generator's CPU time over wall time: the fraction of one core it used."""
        return self.cpu_s / self.wall_s if self.wall_s > 0 else 0.0

    def to_text(self) -> str:
        return (
            f"fleet: {self.vehicles} vehicles, {self.frames_sent} frames sent "
            f"({self.frames_sent / max(self.wall_s, 1e-9):.0f}/s) in {self.wall_s:.2f} s, "
            f"{self.frames_failed} failed sends; generator CPU {self.cpu_s:.2f} s "
            f"= {100 * self.core_fraction:.1f} % of a core; max lateness "
            f"{1e3 * self.late_max_s:.1f} ms; log: "
            + ", ".join(f"{k}={v}" for k, v in sorted(self.counters.items()))
        )


class _Vehicle:
    __slots__ = ("frames", "idx", "links", "log", "offset_s", "sysid", "times")

    def __init__(self, log: Log, times: list[float], sysid: int, offset_s: float) -> None:
        self.log = log
        self.frames = log.frames
        self.times = times
        self.sysid = sysid
        self.offset_s = offset_s
        self.idx = 0
        self.links: list[Link] = []


def run_fleet(
    logs: Sequence[Log],
    links: Sequence[str],
    vehicles: int,
    *,
    sysid_base: int = 1,
    duration_s: float | None = None,
    speed: float = 1.0,
    stagger_s: float = 1.0,
    stop_event: threading.Event | None = None,
    started: threading.Event | None = None,
) -> FleetSummary:
    """Send ``vehicles`` copies of ``logs`` (vehicle k replays ``logs[k % len(logs)]``).

    Stops at the end of the logs, after ``duration_s`` of wall time, or when
    ``stop_event`` is set. ``speed`` scales the recorded rates (2.0: twice as fast)."""
    if not logs:
        raise FleetError("at least one --tlog is needed")
    if vehicles < 1 or sysid_base < 1 or sysid_base + vehicles - 1 > 254:
        raise FleetError(
            f"{vehicles} vehicles from system id {sysid_base}: ids must stay in 1..254"
        )
    if not speed > 0:
        raise FleetError(f"speed must be > 0, got {speed}")
    if not links:
        raise FleetError("at least one --link is needed")
    stop = stop_event or threading.Event()
    times = {id(lg): lg.times for lg in logs}
    fleet = [
        _Vehicle(
            logs[k % len(logs)],
            times[id(logs[k % len(logs)])],
            sysid_base + k,
            k * stagger_s / vehicles,
        )
        for k in range(vehicles)
    ]
    opened: list[Link] = []
    shared: list[Link] = []  # stream links: every vehicle on one stream
    try:
        for conn in links:
            kind = conn.partition(":")[0]
            if kind in ("tcp", "tcpin"):
                lk = open_link(conn)
                if isinstance(lk, TcpClientLink) and lk.sock is not None:
                    # a slow reader makes the generator late (counted), never cuts a frame
                    lk.sock.setblocking(True)
                opened.append(lk)
                shared.append(lk)
            elif kind == "udpout":
                for v in fleet:
                    lk = open_link(conn)
                    opened.append(lk)
                    v.links.append(lk)
            else:
                raise FleetError(f"{conn}: the generator sends on udpout:, tcp: or tcpin: links")
        if started is not None:
            started.set()
        return _send(fleet, shared, opened, duration_s=duration_s, speed=speed, stop=stop)
    finally:
        for lk in opened:
            lk.close()


def _send(
    fleet: list[_Vehicle],
    shared: list[Link],
    opened: list[Link],
    *,
    duration_s: float | None,
    speed: float,
    stop: threading.Event,
) -> FleetSummary:
    cpu0 = time.process_time()
    wall0 = time.perf_counter()
    end_wall = float("inf") if duration_s is None else duration_s
    # heap of (due wall time from start, vehicle index)
    heap = [(v.offset_s, k) for k, v in enumerate(fleet) if v.frames]
    heapq.heapify(heap)
    sent = 0
    late_max = 0.0
    batch: list[bytes] = []
    while heap and not stop.is_set():
        due, k = heap[0]
        now = time.perf_counter() - wall0
        if now >= end_wall:
            break
        if due > now:
            if batch:
                out = b"".join(batch)
                batch.clear()
                for lk in shared:
                    lk.write(out)
            wait = min(due, end_wall) - now
            if wait > 0.0005 and stop.wait(wait):
                break
            continue
        late_max = max(late_max, now - due)
        v = fleet[k]
        # every frame of this vehicle due by now
        t_log = (now - v.offset_s) * speed
        j = bisect.bisect_right(v.times, t_log, lo=v.idx)
        sysid = v.sysid
        for f in v.frames[v.idx : j]:
            data = rewrite(f, sysid)
            for lk in v.links:
                lk.write(data)
            if shared:
                batch.append(data)
            sent += 1
        v.idx = j
        if j < len(v.frames):
            heapq.heapreplace(heap, (v.offset_s + v.times[j] / speed, k))
        else:
            heapq.heappop(heap)
    if batch:
        out = b"".join(batch)
        for lk in shared:
            lk.write(out)
    wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0
    counters: Counter[str] = Counter()
    for lg in {id(v.log): v.log for v in fleet}.values():
        counters.update(lg.counters)
    return FleetSummary(
        vehicles=len(fleet),
        frames_sent=sent,
        frames_failed=sum(lk.failed_writes for lk in opened),
        wall_s=wall,
        cpu_s=cpu,
        late_max_s=late_max,
        counters=dict(counters),
    )


#: The design's input streams (ATTITUDE 100 Hz, HIGHRES_IMU 250 Hz, LOCAL_POSITION_NED
#: 30 Hz, HEARTBEAT 1 Hz): RAW_IMU and SCALED_IMU off (the service uses HIGHRES_IMU), and
#: SERVO_OUTPUT_RAW off (the cyclic regressors are off in the service by default; the fleet
#: traffic stays the issue's design rates, 381 datagrams/s per vehicle).
DESIGN_RATES_HZ: dict[str, float] = {"raw_imu": 0.0, "scaled_imu": 0.0, "servo_output_raw": 0.0}


def record_tlog(
    path: str | Path,
    seconds: float,
    *,
    scenario: str = "hover",
    truth: bool = True,
    seed: int = 0,
) -> Path:
    """Fly ``scenario`` at full speed and record a log at the design rates (``truth``:
    with SIM_STATE at 50 Hz as well). About 0.15-0.25 s of CPU per simulated second."""
    from dataclasses import replace

    from glmav_sitl.runner import run
    from glmav_sitl.scenario import load_sitl_config

    sitl = load_sitl_config()
    rates = {**sitl.rates_hz, **DESIGN_RATES_HZ}
    if not truth:
        rates["sim_state"] = 0.0
    run(
        scenario,
        (),
        seconds,
        "max",
        seed,
        path,
        sitl=replace(sitl, rates_hz=rates),
    )
    return Path(path)


def main(ns: argparse.Namespace) -> int:
    """The ``glmav-sitl fleet`` command (options from :mod:`glmav_sitl.cli`)."""
    import signal

    try:
        logs = [load_tlog(p) for p in ns.tlog]
    except FleetError as err:
        print(f"glmav-sitl fleet: {err}", file=sys.stderr)
        return 2
    stripped = sum(lg.counters["signatures_stripped"] for lg in logs)
    if stripped:
        print(
            f"glmav-sitl fleet: {stripped} signed frames are sent unsigned (the signing key "
            "is not known here; a service that requires signing rejects them)",
            file=sys.stderr,
        )
    stop = threading.Event()

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    try:
        summary = run_fleet(
            logs,
            ns.link,
            ns.vehicles,
            sysid_base=ns.sysid_base,
            duration_s=ns.duration,
            speed=ns.speed,
            stagger_s=ns.stagger,
            stop_event=stop,
        )
    except (FleetError, LinkError) as err:
        print(f"glmav-sitl fleet: {err}", file=sys.stderr)
        return 2
    print(summary.to_text())
    return 0


__all__ = [
    "FleetError",
    "FleetSummary",
    "Frame",
    "Log",
    "crc_delta",
    "load_tlog",
    "main",
    "record_tlog",
    "rewrite",
    "run_fleet",
    "x25_crc",
]
