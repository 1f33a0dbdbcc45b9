"""MAVLink framing and decoding that never raises on bad input: it counts and resyncs.

pymavlink's parser (``MAVLink.parse_char``) with ``robust_parsing`` returns
``BAD_DATA`` for a bad CRC but then skips the whole claimed frame, so a corrupted
length byte swallows the valid frames that follow; without ``robust_parsing`` it
raises. Here framing is ours and decoding is the dialect's ``MAVLink.decode`` (which
checks the CRC with the message's CRC-extra):

- a candidate frame starts at a magic byte (0xFE MAVLink 1, 0xFD MAVLink 2);
- if it decodes, it is emitted; if not, and a magic byte follows right after the
  claimed length, the whole frame is skipped (one rejected frame: a CRC error in an
  intact frame); otherwise we resync one byte after the magic (a corrupt length);
- in datagram mode (UDP: every datagram holds whole frames) bytes left over at the
  end of a datagram are a truncated frame and are dropped; in stream mode (TCP,
  serial) they wait for more bytes.

Fast decode. The messages the service consumes (:data:`FAST_DECODE_MESSAGES`: the sample
messages of ``ingest/convert.py``, ``HEARTBEAT``, ``SYSTEM_TIME``), when they come as
unsigned MAVLink 2, are decoded without ``MAVLink.decode``'s generic path: the payload
(zero-truncation padded back) is unpacked with the message class's own precompiled
``struct.Struct`` into an instance of that class, with the attributes ``decode`` sets, in
its order (:func:`fast_decode`; tests/unit/glmav_observer/ingest/test_fast_decode.py pins
both to the same objects). A datagram of one such frame is decided in one pass, one CRC
for the prefilter and the decoding (:meth:`FrameDecoder._feed_one`). Signed frames,
MAVLink 1, other ids and bad CRCs take ``MAVLink.decode`` as before.

Every rejection is counted by reason in ``FrameCounters`` (``bad_crc``, ``truncated``,
``bad_header``, ``garbage_bytes``, ``unknown_message``; with a signing key also
``unsigned``, ``bad_signature``, ``replayed`` and ``stale``). A ``.tlog`` (8-byte
big-endian µs host timestamp before every frame) is read by :func:`iter_tlog` with
the same rules.
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import json
import logging
import os
import struct
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink_dialect

from glmav_observer.ingest.convert import SAMPLE_MESSAGES

logger = logging.getLogger(__name__)

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_HEADER_V1 = 6
_HEADER_V2 = 10
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = 0x01
_TLOG_STAMP = struct.Struct(">Q")

#: The dialect's message class, for type hints (pymavlink ships no stubs).
MavMessage = Any

#: A frame pre-filter (see :attr:`FrameDecoder.prefilter`): (system id, component id,
#: message id, the payload's first field as an unsigned integer, host time) -> True when
#: the frame was consumed without being decoded.
Prefilter = Callable[[int, int, int, int, float], bool]


@dataclass
class FrameCounters:
    """Rejections and totals of one link, by reason (plain counts, JSON-able)."""

    counts: collections.Counter[str] = field(default_factory=collections.Counter)

    def add(self, reason: str, n: int = 1) -> None:
        self.counts[reason] += n

    def as_dict(self) -> dict[str, int]:
        return dict(sorted(self.counts.items()))

    @property
    def rejected_frames(self) -> int:
        """Candidate frames rejected (bad CRC, bad header, truncated)."""
        return sum(self.counts[k] for k in ("bad_crc", "bad_header", "truncated"))


#: MAVLink 2 signing timestamps: 10 µs units since 2015-01-01T00:00:00Z.
SIGNING_EPOCH_UNIX_S = 1_420_070_400
#: The signing spec's freshness bound: a new stream's first timestamp may be at most one
#: minute older than the newest timestamp known (10 µs units).
SIGNING_NEW_STREAM_MAX_AGE = 6_000_000


def signing_key_id(key: bytes) -> str:
    """A public name of a key (the first 8 bytes of its SHA-256, hex): state files say
    which key their timestamps belong to without holding it."""
    return hashlib.sha256(key).hexdigest()[:16]


class SigningState:
    """MAVLink 2 signing freshness, shared by every link of a service and persisted.

    ``streams``: the last accepted timestamp of each (link id, system, component);
    ``newest``: the newest timestamp accepted on any stream. A frame of a known stream
    must be newer than its stream's last; the first frame of a new stream must be at
    most one minute (``SIGNING_NEW_STREAM_MAX_AGE``) older than ``newest`` (the spec's
    rule; ``newest`` plays the local clock, so a vehicle signing with a boot-relative
    clock works). With a ``path`` the state survives restarts: frames captured before
    a restart are refused as ``replayed`` (known streams) or ``stale`` (new ones). The
    file holds the key's id (:func:`signing_key_id`), never the key, and is written
    atomically (``save``), mode 0600."""

    def __init__(self, key: bytes, path: str | os.PathLike[str] | None = None) -> None:
        self.key_id = signing_key_id(key)
        self.path = None if path is None else os.fspath(path)
        self.streams: dict[tuple[int, int, int], int] = {}
        self.newest = -1
        self.dirty = False
        if self.path is not None:
            self._load()

    def _load(self) -> None:
        assert self.path is not None
        try:
            with open(self.path, encoding="utf-8") as f:
                doc = json.load(f)
        except FileNotFoundError:
            return
        except (OSError, ValueError) as err:
            raise ValueError(f"{self.path}: unreadable signing state: {err}") from None
        if not isinstance(doc, dict) or doc.get("key_id") != self.key_id:
            logger.warning(
                "signing state of another key: starting afresh", extra={"path": self.path}
            )
            return
        try:
            self.newest = int(doc["newest"])
            for k, ts in doc["streams"].items():
                link, sysid, compid = (int(x) for x in k.split(":"))
                self.streams[(link, sysid, compid)] = int(ts)
        except (KeyError, ValueError, TypeError, AttributeError) as err:
            raise ValueError(f"{self.path}: malformed signing state: {err!r}") from None

    def check(self, stream: tuple[int, int, int], ts: int) -> str | None:
        """None if ``ts`` is fresh for ``stream`` (then recorded), else the reason."""
        last = self.streams.get(stream)
        if last is not None:
            if ts <= last:
                return "replayed"
        elif ts < self.newest - SIGNING_NEW_STREAM_MAX_AGE:
            return "stale"
        self.streams[stream] = ts
        self.newest = max(self.newest, ts)
        self.dirty = True
        return None

    def save(self) -> None:
        """Write the state (if persisted and changed); an OSError is logged, not raised."""
        if self.path is None or not self.dirty:
            return
        doc = {
            "key_id": self.key_id,
            "newest": self.newest,
            "streams": {f"{a}:{b}:{c}": ts for (a, b, c), ts in sorted(self.streams.items())},
        }
        tmp = f"{self.path}.tmp"
        try:
            os.makedirs(os.path.dirname(self.path) or ".", mode=0o700, exist_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(doc, f)
            os.replace(tmp, self.path)
            self.dirty = False
        except OSError as err:
            logger.warning("signing state not saved", extra={"path": self.path, "error": str(err)})
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def outgoing_timestamp(self) -> int:
        """A timestamp for what we sign: the wall clock, never below what is known."""
        wall = int((time.time() - SIGNING_EPOCH_UNIX_S) * 100_000)
        return max(wall, self.newest + 1)


def new_dialect(signing: SigningState | None = None, key: bytes | None = None) -> Any:
    """A dialect codec object (ardupilotmega, a superset of common), used for decode and
    pack. With ``key`` (and its ``signing`` state), everything packed with it is signed
    (link id 0) with timestamps from :meth:`SigningState.outgoing_timestamp`."""
    mav = mavlink_dialect.MAVLink(None, srcSystem=255, srcComponent=190)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.link_id = 0
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing.outgoing_timestamp() if signing is not None else 0
    return mav


def _frame_length(buf: bytes | bytearray, p: int, n: int) -> int | None:
    """Total length of the candidate frame at ``p`` or None if the header is incomplete."""
    magic = buf[p]
    if magic == MAGIC_V2:
        if n - p < 3:
            return None
        length = _HEADER_V2 + buf[p + 1] + 2
        if buf[p + 2] & _IFLAG_SIGNED:
            length += _SIGNATURE_LEN
        return length
    if n - p < 2:
        return None
    return _HEADER_V1 + buf[p + 1] + 2


def frame_crc(frame: bytes | bytearray, start: int, end: int, crc_extra: int) -> int:
    """MAVLink's checksum (CRC-16/MCRF4XX) of the frame at ``start`` (its bytes after the
    magic up to ``end``, the end of its payload) followed by the message's CRC extra:
    the dialect's C implementation (fastcrc) when pymavlink found it, else its
    pure-Python one."""
    fast = mavlink_dialect.mcrf4xx
    if fast is not None:
        return int(fast(_EXTRA_BYTE[crc_extra], fast(frame[start + 1 : end], 0xFFFF)))
    body = bytearray(frame[start + 1 : end])
    body.append(crc_extra)
    return int(mavlink_dialect.x25crc(body).crc)


_EXTRA_BYTE = [bytes([i]) for i in range(256)]


@dataclass(frozen=True, slots=True)
class FastSpec:
    """How to decode one message id without pymavlink's generic ``decode``: everything
    comes from pymavlink's generated class (its wire-order field names, its precompiled
    ``struct.Struct``, its CRC extra) and a prototype instance (the attributes its
    constructor sets, in their order)."""

    msg_class: Any  # a pymavlink MAVLink_*_message class (pymavlink has no stubs)
    crc_extra: int
    unpack_from: Callable[[bytes | bytearray, int], tuple[Any, ...]]
    payload_len: int
    wire_names: tuple[str, ...]
    template: dict[str, Any]


def fast_spec(msg_id: int) -> FastSpec | None:
    """The fast decoding of ``msg_id``, or None where pymavlink's ``decode`` must stay
    (unknown id, array or string fields: those it post-processes)."""
    cls = mavlink_dialect.mavlink_map.get(msg_id)
    if cls is None or any(n != 1 for n in cls.lengths):
        return None
    if any(t.startswith("char") for t in cls.fieldtypes):
        return None
    proto = cls(*(0 for _ in cls.fieldnames))
    return FastSpec(
        msg_class=cls,
        crc_extra=cls.crc_extra,
        unpack_from=cls.unpacker.unpack_from,
        payload_len=cls.unpacker.size,
        wire_names=tuple(cls.ordered_fieldnames),
        template=dict(proto.__dict__),
    )


#: The messages the service consumes (ingest/pipeline.py): decoded by :meth:`FrameDecoder.
#: _fast_decode` when they come as unsigned MAVLink 2; a message added to the ingest (to
#: ``SAMPLE_MESSAGES``) joins this table, and any other id falls back to pymavlink.
FAST_DECODE_MESSAGES: frozenset[str] = SAMPLE_MESSAGES | {"HEARTBEAT", "SYSTEM_TIME"}


def _fast_table() -> dict[int, FastSpec]:
    if mavlink_dialect.MAVLINK_IGNORE_CRC:  # pymavlink told to accept bad CRCs: its path
        return {}
    table: dict[int, FastSpec] = {}
    for name in sorted(FAST_DECODE_MESSAGES):
        msg_id = getattr(mavlink_dialect, f"MAVLINK_MSG_ID_{name}", None)
        spec = None if msg_id is None else fast_spec(msg_id)
        if msg_id is not None and spec is not None:
            table[msg_id] = spec
    return table


#: message id -> its fast decoding (see :data:`FAST_DECODE_MESSAGES`)
FAST_DECODE: dict[int, FastSpec] = _fast_table()

_MAVLinkHeader = mavlink_dialect.MAVLink_header


def fast_decode(frame: bytearray) -> MavMessage | None:
    """The message of an unsigned MAVLink 2 ``frame`` (whole, length already checked by
    the framing) whose id is in :data:`FAST_DECODE`, built as pymavlink's ``decode``
    builds it (the same class, attributes, values and their order), or None for any
    other frame and for a bad CRC: pymavlink's ``decode`` then decides and names the
    rejection."""
    if frame[0] != MAGIC_V2 or frame[2]:
        return None
    msg_id = frame[7] | frame[8] << 8 | frame[9] << 16
    spec = FAST_DECODE.get(msg_id)
    mlen = frame[1]
    end = _HEADER_V2 + mlen
    if spec is None or len(frame) != end + 2:
        return None
    crc = frame[end] | frame[end + 1] << 8
    if frame_crc(frame, 0, end, spec.crc_extra) != crc:
        return None
    return _fast_message(spec, frame, msg_id, crc)


def _fast_message(spec: FastSpec, frame: bytearray, msg_id: int, crc: int) -> MavMessage:
    """:func:`fast_decode`'s message, the frame checked (unsigned MAVLink 2, its length,
    its CRC). MAVLink 2 drops a payload's trailing zero bytes: padded back here."""
    mlen = frame[1]
    size = spec.payload_len
    if mlen >= size:
        values = spec.unpack_from(frame, _HEADER_V2)
    else:
        values = spec.unpack_from(
            bytes(frame[_HEADER_V2 : _HEADER_V2 + mlen]) + bytes(size - mlen), 0
        )
    msg = spec.msg_class.__new__(spec.msg_class)
    d = dict(spec.template)  # the constructor's attributes, in its order
    d.update(zip(spec.wire_names, values, strict=True))
    # what pymavlink's decode sets after construction (``_payload`` from byte 6, as it does)
    d["_signed"] = False
    d["_msgbuf"] = frame
    d["_payload"] = frame[6:-2]
    d["_crc"] = crc
    d["_header"] = _MAVLinkHeader(msg_id, 0, frame[3], mlen, frame[4], frame[5], frame[6])
    msg.__dict__ = d
    return msg


#: byte size of a MAVLink field type (the prefilter reads a payload's first field)
_FIELD_SIZE = {"uint64_t": 8, "int64_t": 8, "uint32_t": 4, "int32_t": 4, "uint16_t": 2}


class FrameDecoder:
    """Turns bytes into decoded MAVLink messages (MAVLink 1 and 2), counting every rejection."""

    def __init__(
        self,
        *,
        datagram: bool,
        counters: FrameCounters | None = None,
        signing_key: bytes | None = None,
        signing_state: SigningState | None = None,
    ) -> None:
        self._mav = new_dialect()
        if signing_key is not None and len(signing_key) != 32:
            raise ValueError("a MAVLink 2 signing key is 32 bytes")
        # MAVLink 2 signing: only frames signed with this key pass. Checked here, not by
        # pymavlink (2.4.50 records a stream's timestamp before checking the signature,
        # so one forged frame with a high timestamp would lock the real vehicle out).
        self._signing_key = signing_key
        self.signing_state = (
            signing_state
            if signing_state is not None
            else (SigningState(signing_key) if signing_key is not None else None)
        )
        self._sign_reason = ""
        self._buf = bytearray()
        self._datagram = datagram
        self._quiet = 0
        self.counters = counters if counters is not None else FrameCounters()
        #: Frames of the message ids in :attr:`prefilter_ids` whose CRC is valid are
        #: offered to this callable before they are decoded, with the payload's first
        #: field (the time stamp of the IMU messages: ``time_usec``/``time_boot_ms``);
        #: when it returns True the frame counts as ``frames_ok`` and ``prefiltered``
        #: and is not decoded (2 of 3 IMU streams a vehicle sends are superseded: their
        #: pymavlink decode was a fifth of the service's cost per message). Only for a
        #: datagram holding one frame (UDP as vehicles send it), so that the verdict sees
        #: the state every earlier message left; not with a signing key (a frame is
        #: verified before anything reads it).
        self.prefilter: Prefilter | None = None
        #: message id -> (CRC extra, byte size of the first payload field)
        self.prefilter_ids: dict[int, tuple[int, int]] = {}
        self.prefiltered = 0

    def _try_decode(self, frame: bytearray) -> tuple[MavMessage | None, str | None]:
        if frame[0] == MAGIC_V2 and frame[2] & ~_IFLAG_SIGNED:
            return None, "bad_header"  # unknown incompatibility flags: cannot be parsed
        if self._signing_key is None:
            fast = fast_decode(frame)
            if fast is not None:
                return fast, None
        try:
            msg = self._mav.decode(frame)
        except mavlink_dialect.MAVError as err:
            return None, ("bad_crc" if "CRC" in err.message else "bad_header")
        except (struct.error, ValueError, IndexError, TypeError) as err:  # defensive: dialect bugs
            logger.debug("undecodable frame", extra={"error": str(err)})
            return None, "bad_header"
        if msg.get_msgId() == mavlink_dialect.MAVLINK_MSG_ID_UNKNOWN:
            return None, "unknown_message"
        if self._signing_key is not None:
            return (msg, None) if self._signature_ok(frame) else (None, self._sign_reason)
        return msg, None

    def _signature_ok(self, frame: bytearray) -> bool:
        """MAVLink 2 signature: SHA-256(key + frame without the last 6 bytes)[:6], and a
        48-bit timestamp (10 µs units) fresh by :class:`SigningState`'s rules."""
        if frame[0] != MAGIC_V2 or not frame[2] & _IFLAG_SIGNED:
            self._sign_reason = "unsigned"
            return False
        assert self._signing_key is not None
        if hashlib.sha256(self._signing_key + frame[:-6]).digest()[:6] != frame[-6:]:
            self._sign_reason = "bad_signature"
            return False
        stream = (frame[-13], frame[5], frame[6])
        ts = int.from_bytes(frame[-12:-6], "little")
        assert self.signing_state is not None
        reason = self.signing_state.check(stream, ts)  # only after the signature is verified
        if reason is not None:
            self._sign_reason = reason
            return False
        return True

    def set_prefilter(self, prefilter: Prefilter, msg_ids: Iterable[int]) -> None:
        """Offer valid frames of ``msg_ids`` to ``prefilter`` before decoding them."""
        if self._signing_key is not None:
            return
        self.prefilter = prefilter
        ids: dict[int, tuple[int, int]] = {}
        for i in msg_ids:
            cls = mavlink_dialect.mavlink_map[i]
            first = cls.ordered_fieldnames[0]  # wire order: the first field of the payload
            ids[i] = (cls.crc_extra, _FIELD_SIZE[cls.fieldtypes[cls.fieldnames.index(first)]])
        self.prefilter_ids = ids

    def _prefiltered(self, buf: bytearray, p: int, length: int, t_host_s: float) -> bool:
        """The frame at ``p`` was valid and consumed by :attr:`prefilter`."""
        if buf[p] == MAGIC_V2:
            if buf[p + 2]:  # signed or unknown flags: the full path decides
                return False
            msgid = buf[p + 7] | buf[p + 8] << 8 | buf[p + 9] << 16
            hdr, sysid, compid = _HEADER_V2, buf[p + 5], buf[p + 6]
        else:
            msgid, hdr, sysid, compid = buf[p + 5], _HEADER_V1, buf[p + 3], buf[p + 4]
        spec = self.prefilter_ids.get(msgid)
        if spec is None:
            return False
        crc_extra, t_size = spec
        end = p + length - 2
        if frame_crc(buf, p, end, crc_extra) != buf[end] | buf[end + 1] << 8:
            return False  # the full path counts the rejection
        # MAVLink 2 drops a payload's trailing zero bytes: a short field reads as zero
        first = int.from_bytes(buf[p + hdr : min(p + hdr + t_size, end)], "little")
        assert self.prefilter is not None
        return self.prefilter(sysid, compid, msgid, first, t_host_s)

    def _feed_one(self, data: bytes | bytearray, t_host_s: float) -> list[MavMessage] | None:
        """A datagram that is exactly one valid unsigned MAVLink 2 frame of a message in
        :data:`FAST_DECODE` (what vehicles send): what :meth:`feed`'s loop returns and
        counts for it, with its CRC computed once for the prefilter and the decoding.
        None for any other datagram: the loop decides."""
        n = len(data)
        if n < _HEADER_V2 + 2 or data[0] != MAGIC_V2 or data[2] or n != _HEADER_V2 + data[1] + 2:
            return None
        msg_id = data[7] | data[8] << 8 | data[9] << 16
        spec = FAST_DECODE.get(msg_id)
        if spec is None:
            return None
        end = n - 2
        crc = data[end] | data[end + 1] << 8
        if frame_crc(data, 0, end, spec.crc_extra) != crc:
            return None
        prefilter = self.prefilter
        if prefilter is not None:
            pre = self.prefilter_ids.get(msg_id)
            if pre is not None:
                # as _prefiltered: the first field, a short (zero-truncated) one reads as zero
                first = int.from_bytes(data[_HEADER_V2 : min(_HEADER_V2 + pre[1], end)], "little")
                if prefilter(data[5], data[6], msg_id, first, t_host_s):
                    self.counters.add("frames_ok")
                    self.prefiltered += 1
                    return []
        msg = _fast_message(spec, bytearray(data), msg_id, crc)
        self.counters.add("frames_ok")
        return [msg]

    def feed(self, data: bytes | bytearray, t_host_s: float = 0.0) -> list[MavMessage]:
        """Add bytes; return the messages completed by them (in order).

        In datagram mode ``data`` is one whole datagram and nothing carries over.
        ``t_host_s`` (arrival) is passed to :attr:`prefilter`.
        """
        if self._datagram and self._signing_key is None:
            one = self._feed_one(data, t_host_s)
            if one is not None:
                return one
        buf = self._buf
        buf.extend(data)
        out: list[MavMessage] = []
        p = 0
        n = len(buf)
        counters = self.counters
        prefilter = self.prefilter
        # A rejected candidate with intact boundaries (a magic byte right after it) is
        # counted once; its inner bytes are still scanned (a valid frame may sit inside a
        # span claimed by a corrupt length) but not counted again up to ``quiet``.
        quiet = self._quiet
        while p < n:
            b = buf[p]
            if b not in (MAGIC_V2, MAGIC_V1):
                q1 = buf.find(MAGIC_V2, p)
                q2 = buf.find(MAGIC_V1, p)
                q = min(x for x in (q1, q2, n) if x >= 0)
                if q > quiet:
                    counters.add("garbage_bytes", q - max(p, quiet))
                p = q
                continue
            length = _frame_length(buf, p, n)
            if length is None or p + length > n:
                if self._datagram:  # nothing more will come: not a frame start, resync
                    if p >= quiet:
                        counters.add("truncated")
                    p += 1
                    continue
                break  # incomplete
            # only a datagram's one frame: with frames before it in the same call, their
            # messages (not processed yet) could change the prefilter's verdict
            if (
                prefilter is not None
                and length == n
                and self._datagram
                and self._prefiltered(buf, p, length, t_host_s)
            ):
                counters.add("frames_ok")
                self.prefiltered += 1
                p += length
                continue
            msg, reason = self._try_decode(buf[p : p + length])
            if msg is not None:
                out.append(msg)
                counters.add("frames_ok")
                p += length
                continue
            assert reason is not None
            if p >= quiet:
                counters.add(reason)
                if (p + length < n and buf[p + length] in (MAGIC_V1, MAGIC_V2)) or (
                    p + length == n and self._datagram
                ):
                    quiet = p + length  # intact frame boundaries: one rejected frame
            p += 1  # resync on the next magic byte
        if self._datagram:
            self._buf = bytearray()
            self._quiet = 0
        else:
            del buf[:p]
            self._quiet = max(0, quiet - p)
        return out


@dataclass(frozen=True, slots=True)
class TlogRecord:
    """One decoded frame of a ``.tlog`` with its host timestamp (µs since the UNIX epoch)."""

    t_host_us: int
    msg: MavMessage
    offset: int


def iter_tlog(data: bytes, counters: FrameCounters | None = None) -> Iterator[TlogRecord]:
    """Decode a ``.tlog`` image: records of an 8-byte big-endian µs timestamp and a frame.

    A record whose frame fails to decode is counted and skipped as a whole when the next
    record's frame starts where expected; otherwise we resync on the next offset where
    a frame decodes (the 8 bytes before it are its timestamp). ``counters`` gets the
    same reasons as :class:`FrameDecoder`, plus ``tlog_resync_bytes``.
    """
    ctr = counters if counters is not None else FrameCounters()
    dec = FrameDecoder(datagram=True, counters=FrameCounters())  # only for _try_decode
    n = len(data)
    p = 0
    view = memoryview(data)

    def frame_at(q: int) -> tuple[int | None, MavMessage | None, str | None]:
        if q >= n or data[q] not in (MAGIC_V1, MAGIC_V2):
            return None, None, "bad_header"
        length = _frame_length(data, q, n)
        if length is None or q + length > n:
            return length, None, "truncated"
        msg, reason = dec._try_decode(bytearray(view[q : q + length]))
        return length, msg, reason

    while p + 8 < n:
        (t_us,) = _TLOG_STAMP.unpack_from(data, p)
        length, msg, reason = frame_at(p + 8)
        if msg is not None and length is not None:
            ctr.add("frames_ok")
            yield TlogRecord(t_us, msg, p)
            p += 8 + length
            continue
        assert reason is not None
        ctr.add(reason)
        if length is not None and reason in ("bad_crc", "unknown_message", "bad_header"):
            nxt = p + 8 + length
            if nxt + 8 < n and data[nxt + 8] in (MAGIC_V1, MAGIC_V2):
                p = nxt
                continue
        # resync: the next magic byte (at least 8 bytes in) where a frame decodes
        q = p + 9
        while True:
            q1 = data.find(b"\xfd", q)
            q2 = data.find(b"\xfe", q)
            cands = [x for x in (q1, q2) if x >= 0]
            if not cands:
                q = n
                break
            q = min(cands)
            _, m2, _ = frame_at(q)
            if m2 is not None:
                break
            q += 1
        ctr.add("tlog_resync_bytes", max(0, q - 8 - p))
        p = q - 8
    if 0 < n - p < 8 + _HEADER_V1 + 2 and p < n:
        ctr.add("truncated")
