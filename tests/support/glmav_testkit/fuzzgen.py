"""Bad MAVLink input for the ingest fuzz harness (tests and ``benchmarks/fuzz_ingest.py``).

A *case* is one datagram of bytes with the *kind* of damage it carries. The valid stream
comes from the simulator (a real MAVLink 2 stream, captured in memory); the damaged
cases are built from it, from random bytes and from the real corrupt ArduSub log in
``tests/data/real-tlogs/``. Everything is seeded (``random.Random``): a run is
reproducible from its seed.

Kinds (the issue's list):

- ``random_bytes``: uniform random bytes; ``magic_soup``: random bytes rich in the two
  magic bytes (0xFD, 0xFE) so that the framer keeps finding candidate frames;
- ``truncated``: a valid frame cut short; ``spliced``: the head of one frame and the tail
  of another; ``bad_crc``: a valid frame with one byte changed; ``bitflips``: a few bits
  flipped in a run of frames; ``bad_flags``: MAVLink 2 incompatibility flags or a
  signature block that is not ours; ``unknown_id``: a valid CRC on a message id the
  dialect does not have (the CRC then cannot be checked and the frame is dropped);
- ``bad_values``: correctly framed sample messages with NaN, ±inf, ±3.4e38, denormals
  and extreme integers; ``time_jump``: a valid sample message whose time stamp jumps
  back (reboot-like, to near zero) or far forward; ``id_storm``: valid sample messages
  from random system and component ids; ``mav1``: the valid messages packed as MAVLink 1;
- ``real_corrupt``: a random slice of the real corrupt tlog (timestamps, frames and all).

``vehicle_safe=True`` keeps every frame that can pass the CRC away from the vehicle under
test (system id 1, component id 1), so that interleaving cannot change what that vehicle
legitimately sent; with ``False`` anything goes (time jumps and storms on the vehicle).
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

VEHICLE_SYSID = 1
VEHICLE_COMPID = 1
#: the system id the vehicle-safe cases copy the valid stream to
OTHER_SYSID = 200

#: float32 values that break naive arithmetic (struct packs them exactly as float32).
BAD_FLOATS: tuple[float, ...] = (
    float("nan"),
    float("inf"),
    float("-inf"),
    3.4e38,
    -3.4e38,
    1.0e-45,
    -0.0,
    1.0e30,
)
#: integer time stamps at the edges (ms: uint32, µs: uint64).
BAD_MS: tuple[int, ...] = (0, 1, 2**31 - 1, 2**32 - 1)
BAD_US: tuple[int, ...] = (0, 1, 2**63 - 1, 2**64 - 1, 1_700_000_000_000_000)

KINDS: tuple[str, ...] = (
    "random_bytes",
    "magic_soup",
    "truncated",
    "spliced",
    "bad_crc",
    "bitflips",
    "bad_flags",
    "unknown_id",
    "bad_values",
    "time_jump",
    "id_storm",
    "mav1",
    "real_corrupt",
)

_SAMPLE_NAMES = ("ATTITUDE", "HIGHRES_IMU", "SCALED_IMU", "RAW_IMU", "LOCAL_POSITION_NED")


def _packer(sysid: int, compid: int) -> Any:
    return dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)


def pack(msg: Any, sysid: int, compid: int, *, v1: bool = False) -> bytes:
    """``msg`` framed by (sysid, compid), MAVLink 2 unless ``v1``."""
    return bytes(msg.pack(_packer(sysid, compid), force_mavlink1=v1))


def sample_message(name: str, t_ms: int, values: Sequence[float]) -> Any:
    """A sample message of ``name`` at ``t_ms`` with its float fields from ``values`` (cycled)."""
    v = [values[i % len(values)] for i in range(9)]
    t_us = t_ms * 1000
    if name == "ATTITUDE":
        return dialect.MAVLink_attitude_message(t_ms, *v[:6])
    if name == "HIGHRES_IMU":
        return dialect.MAVLink_highres_imu_message(t_us, *v[:9], 0.0, 0.0, 0.0, 0.0, 0, 0)
    if name in ("SCALED_IMU", "RAW_IMU"):
        ints = [_clip_int(x, 16) for x in v[:9]]
        if name == "SCALED_IMU":
            return dialect.MAVLink_scaled_imu_message(t_ms, *ints, 0)
        return dialect.MAVLink_raw_imu_message(t_us, *ints, 0, 0)
    if name == "LOCAL_POSITION_NED":
        return dialect.MAVLink_local_position_ned_message(t_ms, *v[:6])
    raise ValueError(name)


def _clip_int(x: float, bits: int) -> int:
    lim = 2 ** (bits - 1) - 1
    if math.isnan(x):
        return lim
    return int(max(-lim, min(lim, x)))


@dataclass
class ValidStream:
    """The vehicle's frames in sending order, one frame per datagram, with their time."""

    frames: list[bytes]
    sysid: int = VEHICLE_SYSID
    info: dict[str, Any] = field(default_factory=dict)


def sitl_stream(
    scenario: str = "cruise",
    duration_s: float = 6.0,
    seed: int = 1,
    signing_key: bytes | None = None,
) -> ValidStream:
    """Fly ``scenario`` in the simulator (in process, as fast as possible) and keep its frames."""
    from glmav_sitl.mavlink.links import Link
    from glmav_sitl.runner import run

    class _Capture(Link):
        def __init__(self) -> None:
            super().__init__("capture")
            self.frames: list[bytes] = []

        def write(self, buf: bytes) -> None:
            self.frames.append(bytes(buf))

        def read(self) -> list[bytes]:
            return []

        def close(self) -> None:
            pass

    cap = _Capture()
    summary = run(
        scenario,
        [cap],
        duration_s=duration_s,
        speed="max",
        seed=seed,
        sysid=VEHICLE_SYSID,
        signing_key=signing_key,
    )
    return ValidStream(cap.frames, info={"sent": summary.messages_sent})


def tlog_frames(data: bytes) -> list[bytes]:
    """The frames of a clean ``.tlog`` image (8-byte stamp + frame each), without decoding."""
    out = []
    p = 0
    while p + 8 < len(data):
        q = p + 8
        magic = data[q]
        if magic == 0xFD:
            n = 10 + data[q + 1] + 2 + (13 if data[q + 2] & 1 else 0)
        elif magic == 0xFE:
            n = 6 + data[q + 1] + 2
        else:
            raise ValueError(f"not a clean tlog at offset {p}")
        out.append(data[q : q + n])
        p = q + n
    return out


def _reframe(frame: bytes, sysid: int, compid: int) -> bytes:
    """The same message re-packed from another system/component id (valid CRC)."""
    msg = _packer(255, 190).decode(bytearray(frame))
    return pack(msg, sysid, compid, v1=frame[0] == 0xFE)


def _not_vehicle(rng: random.Random) -> tuple[int, int]:
    while True:
        s, c = rng.randrange(256), rng.randrange(256)
        if (s, c) != (VEHICLE_SYSID, VEHICLE_COMPID) and s != VEHICLE_SYSID:
            return s, c


class CaseMaker:
    """Seeded maker of damaged datagrams from a valid stream and a real corrupt log."""

    def __init__(
        self,
        valid: Sequence[bytes],
        corrupt_log: bytes,
        seed: int,
        *,
        vehicle_safe: bool,
    ) -> None:
        self.valid = list(valid)
        if vehicle_safe:
            # cases are built from a copy of the stream sent by another system: damaged
            # or replayed, they cannot pass for the vehicle under test
            self.valid = [_reframe(f, OTHER_SYSID, VEHICLE_COMPID) for f in self.valid]
        self.corrupt = corrupt_log
        self.rng = random.Random(seed)
        self.vehicle_safe = vehicle_safe
        #: the vehicle's current time (ms), kept up to date by the caller
        self.t_ms = 1000
        self._makers: dict[str, Callable[[], bytes]] = {k: getattr(self, "_" + k) for k in KINDS}

    def make(self, kind: str | None = None) -> tuple[str, bytes]:
        k = kind or self.rng.choice(KINDS)
        return k, self._makers[k]()

    def _frame(self) -> bytes:
        return self.rng.choice(self.valid)

    def _ids(self) -> tuple[int, int]:
        if self.vehicle_safe:
            return _not_vehicle(self.rng)
        return self.rng.randrange(256), self.rng.randrange(256)

    # -- unframed damage
    def _random_bytes(self) -> bytes:
        return self.rng.randbytes(self.rng.randrange(1, 300))

    def _magic_soup(self) -> bytes:
        r = self.rng
        b = bytearray(r.randbytes(r.randrange(1, 300)))
        for _ in range(r.randrange(1, 12)):
            b[r.randrange(len(b))] = r.choice((0xFD, 0xFE))
        return bytes(b)

    def _truncated(self) -> bytes:
        f = self._frame()
        return f[: self.rng.randrange(1, len(f))]

    def _spliced(self) -> bytes:
        a, b = self._frame(), self._frame()
        return a[: self.rng.randrange(1, len(a))] + b[self.rng.randrange(1, len(b)) :]

    def _bad_crc(self) -> bytes:
        f = bytearray(self._frame())
        i = self.rng.randrange(1, len(f))
        f[i] ^= self.rng.randrange(1, 256)
        return bytes(f)

    def _bitflips(self) -> bytes:
        r = self.rng
        b = bytearray(b"".join(self._frame() for _ in range(r.randrange(1, 4))))
        for _ in range(r.randrange(1, 6)):
            b[r.randrange(len(b))] ^= 1 << r.randrange(8)
        return bytes(b)

    def _bad_flags(self) -> bytes:
        r = self.rng
        f = bytearray(self._frame())
        if f[0] != 0xFD:
            return bytes(f)
        if r.random() < 0.5:
            f[2] = r.randrange(2, 256)  # unknown incompatibility flags
            return bytes(f)
        f[2] |= 1  # claims a signature: 13 more bytes that are not one
        return bytes(f) + r.randbytes(13)

    def _unknown_id(self) -> bytes:
        f = bytearray(self._frame())
        if f[0] == 0xFD:
            f[7], f[8], f[9] = 0x3F, 0x3F, self.rng.randrange(1, 256)
        return bytes(f)

    # -- well-framed, bad content
    def _bad_values(self) -> bytes:
        r = self.rng
        name = r.choice(_SAMPLE_NAMES)
        vals = [r.choice(BAD_FLOATS) if r.random() < 0.6 else r.uniform(-50, 50) for _ in range(9)]
        t_ms = r.choice(BAD_MS) if r.random() < 0.3 else self.t_ms
        msg = sample_message(name, t_ms, vals)
        if name in ("HIGHRES_IMU", "RAW_IMU") and r.random() < 0.3:
            msg.time_usec = r.choice(BAD_US)
        s, c = self._ids()
        return pack(msg, s, c, v1=r.random() < 0.2)

    def _time_jump(self) -> bytes:
        r = self.rng
        name = r.choice(_SAMPLE_NAMES)
        jump = r.choice((-1, 1))
        if self.vehicle_safe:
            # on the vehicle itself: a corrupt stamp far beyond the forward window (30 s),
            # random over 49 days, so that no five of them agree on a new timeline
            t = self.t_ms + r.randrange(40_000, 2**32 - self.t_ms - 40_000)
            s, c = VEHICLE_SYSID, VEHICLE_COMPID
        else:
            t = max(0, self.t_ms + jump * r.randrange(0, 10**6))
            s, c = self._ids()
        msg = sample_message(name, t, [r.uniform(-3, 3) for _ in range(9)])
        if name == "HIGHRES_IMU":
            msg.zacc = -9.8
        elif name in ("SCALED_IMU", "RAW_IMU"):
            msg.zacc = -1000
        return pack(msg, s, c)

    def _id_storm(self) -> bytes:
        r = self.rng
        out = []
        for _ in range(r.randrange(1, 8)):
            s, c = self._ids()
            out.append(_reframe(self._frame(), s, c))
        return b"".join(out)

    def _mav1(self) -> bytes:
        f = self._frame()
        if self.vehicle_safe:
            s, c = self._ids()
        else:
            s, c = VEHICLE_SYSID, VEHICLE_COMPID
        msg = _packer(255, 190).decode(bytearray(f))
        return pack(msg, s, c, v1=True)

    def _real_corrupt(self) -> bytes:
        r = self.rng
        n = r.randrange(16, 600)
        p = r.randrange(0, max(1, len(self.corrupt) - n))
        chunk = self.corrupt[p : p + n]
        if self.vehicle_safe:
            # the ArduSub log is system 1 too: move its frames off the vehicle's id by
            # changing the system id bytes, which breaks their CRC (counted as bad_crc)
            b = bytearray(chunk)
            for i in range(len(b) - 6):
                if b[i] == 0xFD and i + 5 < len(b) and b[i + 5] == VEHICLE_SYSID:
                    b[i + 5] = 77
                elif b[i] == 0xFE and i + 3 < len(b) and b[i + 3] == VEHICLE_SYSID:
                    b[i + 3] = 77
            chunk = bytes(b)
        return chunk


def load_corrupt_log(real_tlogs: Path) -> bytes:
    """The real corrupt ArduSub log, from a folder holding it plain or xz-compressed."""
    import lzma

    plain = real_tlogs / "ardusub_2023-04-18.tlog"
    if plain.exists():
        return plain.read_bytes()
    return lzma.decompress((real_tlogs / "ardusub_2023-04-18.tlog.xz").read_bytes())


def epoch_pair() -> bytes:
    """A SYSTEM_TIME frame (vehicle-safe id), so that UNIX-epoch mapping is exercised."""
    msg = dialect.MAVLink_system_time_message(1_700_000_000_000_000, 1234)
    return pack(msg, 42, 1)
