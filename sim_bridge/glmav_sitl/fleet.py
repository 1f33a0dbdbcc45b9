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

Vehicle k starts ``(k + {k/φ}) * stagger_s / K`` after the first (:func:`start_offsets_s`):
the starts are spread over ``stagger_s`` and, above all, each vehicle's frames fall at its
own phase of the log's frame periods, as K vehicles with their own clocks would send. A
start of ``k * stagger_s / K`` alone is a whole number of the simulator's 2 ms ticks for
most K (1 s / 10 = 50 ticks): K copies of one log then send in lock-step, each tick's
frames of every vehicle in one burst, and the service's latency measures the burst.
Scheduling is by windows of wall time (``WINDOW_S``, 20 ms): the
frames every vehicle has due in the window (a bisect over its log's times) are merged by
due time, and each is sent once its time has come (sleeping when the next is more than
``MIN_SLEEP_S`` away). Frames are rewritten for a vehicle a chunk at a time
(:class:`LogArrays`, numpy), and a window is sent by a compiled loop
(:mod:`glmav_sitl.fleet_send`) that calls ``send(2)`` on the ``udpout:`` sockets'
descriptors itself; the stream links' part of a frame stays in Python. What is left per
frame is mostly the system call: at 100 vehicles (38,100 frames/s) 7.8 µs of CPU per frame
sent, 30 % of a core, against 9.4 µs and 36 % with a Python ``sock.send`` per frame
(``benchmarks/bench_io.py``, same run, load 2.5-4.3); the kernel's side of a loopback
send is about 4.6 µs of it, the window's merge in Python about 0.8. Links (repeat
``--link`` to fan the same traffic out to several services, as mavlink-router does):

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
import struct
import sys
import threading
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_sitl.fleet_send import monotonic_s, send_window
from glmav_sitl.mavlink.links import Link, LinkError, TcpClientLink, UdpLink, open_link
from glmav_sitl.stop import stop_on_signals

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_HEADER_V1 = 6
_HEADER_V2 = 10
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = 0x01
_STAMP = struct.Struct(">Q")
#: the MAVLink system id of a ground station (left out when picking the log's vehicle)
GCS_SYSID = 255
#: 1/φ, the golden ratio's fractional part: {k/φ} is the most evenly spread sequence in [0, 1)
GOLDEN_FRACTION = 0.6180339887498949


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


#: frames rewritten for a vehicle at once (numpy over the chunk instead of two byte writes
#: and a table look-up per frame in Python); K vehicles hold at most K such chunks
REWRITE_CHUNK = 256


class LogArrays:
    """A log's frames as arrays, to rewrite a run of them for one system id at once: the
    same bytes as :func:`rewrite` frame by frame (the CRC change looked up in a table of
    :func:`crc_delta` per changed sysid bits and per span length after the sysid)."""

    def __init__(self, log: Log) -> None:
        frames = log.frames
        #: the frames' times (s), for the due times of a window's run of frames
        self.t_s = np.array([f.t_s for f in frames], dtype=np.float64)
        self.blob = np.frombuffer(b"".join(f.data for f in frames), dtype=np.uint8)
        lens = np.array([len(f.data) for f in frames], dtype=np.int64)
        self.starts = np.concatenate(([0], np.cumsum(lens)))
        first = self.starts[:-1]
        self.sysid_at = first + np.array([f.sysid_pos for f in frames], dtype=np.int64)
        self.crc_at = first + np.array([f.crc_pos for f in frames], dtype=np.int64)
        self.old_sysid = self.blob[self.sysid_at].astype(np.intp)
        blob16 = self.blob.astype(np.uint16)
        self.old_crc = blob16[self.crc_at] | (blob16[self.crc_at + 1] << 8)
        following = np.array([f.crc_following for f in frames], dtype=np.int64)
        spans, self.span_col = np.unique(following, return_inverse=True)
        self.delta_table = np.array(
            [[crc_delta(d, int(f)) for f in spans] for d in range(256)], dtype=np.uint16
        )

    def rewrite(self, a: int, b: int, sysid: int) -> list[bytes]:
        """Frames ``a`` to ``b`` (exclusive) as sent by system ``sysid`` (CRCs fixed)."""
        s0 = int(self.starts[a])
        buf = self.blob[s0 : int(self.starts[b])].copy()
        crc = self.old_crc[a:b] ^ self.delta_table[self.old_sysid[a:b] ^ sysid, self.span_col[a:b]]
        buf[self.sysid_at[a:b] - s0] = sysid
        crc_at = self.crc_at[a:b] - s0
        buf[crc_at] = crc & 0xFF
        buf[crc_at + 1] = crc >> 8
        raw = buf.tobytes()
        offs = (self.starts[a : b + 1] - s0).tolist()
        return [raw[offs[i] : offs[i + 1]] for i in range(b - a)]


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
    __slots__ = (
        "arrays", "batch", "chunk", "chunk_from", "chunk_to", "frames", "idx", "index",
        "links", "log", "offset_s", "sysid", "times", "udp",
    )  # fmt: skip

    def __init__(
        self,
        log: Log,
        arrays: LogArrays,
        times: list[float],
        sysid: int,
        offset_s: float,
        *,
        index: int = 0,
    ) -> None:
        self.log = log
        self.arrays = arrays
        self.frames = log.frames
        self.times = times
        self.sysid = sysid
        self.offset_s = offset_s
        #: this vehicle's place in the fleet (the owner of its frames in a window)
        self.index = index
        self.idx = 0
        #: the other links of this vehicle (written from Python by :meth:`emit`)
        self.links: list[Link] = []
        #: the connected UDP links: their descriptors are sent on by the compiled loop
        self.udp: list[UdpLink] = []
        #: frames chunk_from .. chunk_to - 1, rewritten for this vehicle
        self.chunk: list[bytes] = []
        self.chunk_from = self.chunk_to = 0
        #: the frames gathered for the stream links (shared by every vehicle), if any
        self.batch: list[bytes] | None = None

    def emit(self, data: bytes) -> None:
        """The Python part of sending one frame, after the compiled loop's UDP sends: its
        other links, and the stream links' batch (failures counted by the link)."""
        for lk in self.links:
            lk.write(data)
        if self.batch is not None:
            self.batch.append(data)

    def rewritten(self, a: int, b: int) -> list[bytes]:
        """Frames ``a`` to ``b`` (exclusive) rewritten for this vehicle, from the chunk
        held (the next ``REWRITE_CHUNK`` frames are rewritten when ``a`` leaves it)."""
        out: list[bytes] = []
        while a < b:
            if not self.chunk_from <= a < self.chunk_to:
                self.chunk_from = a
                self.chunk_to = min(len(self.frames), a + REWRITE_CHUNK)
                self.chunk = self.arrays.rewrite(a, self.chunk_to, self.sysid)
            take = min(b, self.chunk_to)
            out += self.chunk[a - self.chunk_from : take - self.chunk_from]
            a = take
        return out


def start_offsets_s(vehicles: int, stagger_s: float) -> list[float]:
    """When each of ``vehicles`` starts, in s after the first: ``(k + {k/φ}) stagger_s / K``.

    ``k stagger_s / K`` spreads the starts; ``{k/φ} stagger_s / K`` (the fractional part
    of k times 1/φ, a low-discrepancy sequence) moves each vehicle off the others' phase
    of the log's frame periods, whatever the period and K (for the fleet benchmark's K
    and the design log's 2, 4 and 10 ms periods, no two vehicles' phases are closer than
    a sixth of period/K; ``k stagger_s / K`` alone puts most of them at one phase)."""
    return [(k + (k * GOLDEN_FRACTION) % 1.0) * stagger_s / vehicles for k in range(vehicles)]


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
    arrays = {id(lg): LogArrays(lg) for lg in logs}
    fleet = [
        _Vehicle(
            logs[k % len(logs)],
            arrays[id(logs[k % len(logs)])],
            times[id(logs[k % len(logs)])],
            sysid_base + k,
            offset_s,
            index=k,
        )
        for k, offset_s in enumerate(start_offsets_s(vehicles, stagger_s))
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
                    if isinstance(lk, UdpLink) and not lk.listen:
                        v.udp.append(lk)  # connected: send(2) on its descriptor
                    else:
                        v.links.append(lk)
            else:
                raise FleetError(f"{conn}: the generator sends on udpout:, tcp: or tcpin: links")
        if started is not None:
            started.set()
        return _send(fleet, shared, opened, duration_s=duration_s, speed=speed, stop=stop)
    finally:
        for lk in opened:
            lk.close()


#: the send schedule is merged across vehicles per this much wall time (s): the frames of
#: every vehicle due in the window, sorted by due time, are sent in that order
WINDOW_S = 0.02
#: a frame is sent once its due time has come; shorter waits than this are not slept
#: (a sleep's own wake-up takes about as long)
MIN_SLEEP_S = 0.0005


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
    clock = monotonic_s  # the compiled loop's clock
    wall0 = clock()
    end_wall = float("inf") if duration_s is None else duration_s
    sent = 0
    late_max = 0.0
    batch: list[bytes] = []  # the frames gathered for the stream links

    def flush() -> None:
        if batch:
            out = b"".join(batch)
            batch.clear()
            for lk in shared:
                lk.write(out)

    for v in fleet:
        v.batch = batch if shared else None
    # every vehicle's connected UDP links, as descriptors for the compiled loop: vehicle
    # k's are fds[fd_start[k]:fd_start[k + 1]], their successful sends counted in sent_by
    udp = [lk for v in fleet for lk in v.udp]
    fds = np.array([lk.sock.fileno() for lk in udp], dtype=np.int32)
    fd_start = np.cumsum([0] + [len(v.udp) for v in fleet], dtype=np.int32)
    sent_by = np.zeros(len(udp), dtype=np.int64)
    # the Python part of a frame's send (stream links, other links), only where needed
    emits: list[Any] | None = None
    if any(v.links or v.batch is not None for v in fleet):
        emits = [v.emit if v.links or v.batch is not None else None for v in fleet]

    def failed(slot: int, err: OSError) -> None:
        udp[slot]._failed(err)

    live = [v for v in fleet if v.frames]
    t_window = 0.0
    while live and not stop.is_set() and t_window < end_wall:
        w_end = min(t_window + WINDOW_S, end_wall)
        # every vehicle's frames due in [t_window, w_end), merged by due time
        dues: list[np.ndarray] = []  # the log times of each vehicle's run
        datas: list[bytes] = []
        owners: list[int] = []
        offsets: list[float] = []
        counts: list[int] = []
        for v in live:
            j = bisect.bisect_left(v.times, (w_end - v.offset_s) * speed, lo=v.idx)
            if j > v.idx:
                dues.append(v.arrays.t_s[v.idx : j])
                datas += v.rewritten(v.idx, j)
                owners.append(v.index)
                offsets.append(v.offset_s)
                counts.append(j - v.idx)
                v.idx = j
        if dues:
            # due: the vehicle's start offset + log time / speed (s from the fleet's start)
            due_all = np.concatenate(dues) / speed + np.repeat(offsets, counts)
            order = np.argsort(due_all, kind="stable").astype(np.int64, copy=False)
            n, late = send_window(
                order,
                due_all,
                datas,
                np.repeat(np.array(owners, dtype=np.int64), counts),
                fd_start,
                fds,
                sent_by,
                emits,
                failed,
                flush,
                stop.wait,
                wall0,
                MIN_SLEEP_S,
            )
            sent += n
            late_max = max(late_max, late)
        t_window = w_end
        live = [v for v in live if v.idx < len(v.frames)]
        if not dues:  # nothing due in this window: wait for its end (or the next frame)
            nxt = min((v.offset_s + v.times[v.idx] / speed for v in live), default=end_wall)
            t_window = max(t_window, min(nxt, end_wall) - WINDOW_S / 2)
            now = clock() - wall0
            if t_window - now > MIN_SLEEP_S and stop.wait(t_window - now):
                break
    flush()
    wall = clock() - wall0
    cpu = time.process_time() - cpu0
    for lk, c in zip(udp, sent_by.tolist(), strict=True):
        lk.sent_packets += c
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
    with SIM_STATE at 50 Hz as well). About 0.01 s of CPU per simulated second."""
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
    stop_on_signals(stop)
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
