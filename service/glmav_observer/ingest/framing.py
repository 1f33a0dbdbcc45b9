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

Fast decode. The high-rate messages (ATTITUDE, the IMU messages, LOCAL_POSITION_NED,
SIM_STATE: :data:`~glmav_observer.ingest.fastframe.FAST_MESSAGES`) are decoded straight from
the frame bytes by the compiled :mod:`glmav_observer.ingest.fastframe` (MAVLink 1 and 2,
signed or not; CRC with the message's CRC extra), into objects that also make their own
samples; every other message is the dialect's ``MAVLink.decode``'s. The verdicts and
counters are the same either way (tests/unit/glmav_observer/ingest/test_fastframe.py).

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
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink_dialect

from glmav_observer.ingest import fastframe

logger = logging.getLogger(__name__)

#: every message of the dialect (ardupilotmega, a superset of common), by name
ALL_MESSAGES: frozenset[str] = frozenset(
    cls.msgname for cls in mavlink_dialect.mavlink_map.values()
)

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_HEADER_V1 = 6
_HEADER_V2 = 10
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = 0x01
_TLOG_STAMP = struct.Struct(">Q")
#: Records decoded in one compiled run of ``iter_tlog`` (the frames counted at its end)
_TLOG_RUN = 1024

#: The dialect's message class, for type hints (pymavlink ships no stubs).
MavMessage = Any


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


class FrameDecoder:
    """Turns bytes into decoded MAVLink messages (MAVLink 1 and 2), counting every rejection."""

    def __init__(
        self,
        *,
        datagram: bool,
        counters: FrameCounters | None = None,
        signing_key: bytes | None = None,
        signing_state: SigningState | None = None,
        fields_of: frozenset[str] | None = None,
    ) -> None:
        """``fields_of``: the messages whose fields the reader needs (None: every
        message). The frames of every other message of the dialect are CRC-checked
        without pymavlink's decode and come back as :class:`~glmav_observer.ingest.
        fastframe.HeaderOnly` (the header; the fields only if asked for)."""
        self._mav = new_dialect()
        self._header_only: bytes | None = (
            None if fields_of is None else fastframe.header_only_ids(ALL_MESSAGES - fields_of)
        )
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

    def _try_decode(
        self, buf: bytes | bytearray, p: int, length: int
    ) -> tuple[MavMessage | None, str | None]:
        """The frame of ``length`` bytes at ``p`` in ``buf``: its message, or the reason
        it is rejected."""
        if buf[p] == MAGIC_V2 and buf[p + 2] & ~_IFLAG_SIGNED:
            return None, "bad_header"  # unknown incompatibility flags: cannot be parsed
        msg = fastframe.decode(buf, p, length, self._header_only)
        if msg is None:  # not one of the high-rate messages: the dialect's decode
            try:
                msg = self._mav.decode(bytearray(buf[p : p + length]))
            except mavlink_dialect.MAVError as err:
                return None, ("bad_crc" if "CRC" in err.message else "bad_header")
            except (struct.error, ValueError, IndexError, TypeError) as err:  # dialect bugs
                logger.debug("undecodable frame", extra={"error": str(err)})
                return None, "bad_header"
            if msg.get_msgId() == mavlink_dialect.MAVLINK_MSG_ID_UNKNOWN:
                return None, "unknown_message"
            if buf[p + 1] > msg.unpacker.size:
                # a payload longer than the message's longest form (extensions included)
                # is malformed in MAVLink 1 and 2 alike; pymavlink cuts it silently, so
                # a CRC that matched by chance (1 in 65,536 per candidate in noise) would
                # swallow the valid frames it claims
                return None, "bad_header"
        elif msg is fastframe.BAD_CRC:
            return None, "bad_crc"
        if self._signing_key is not None and not self._signature_ok(buf[p : p + length]):
            return None, self._sign_reason
        return msg, None

    def _signature_ok(self, frame: bytes | bytearray) -> bool:
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

    def feed(self, data: bytes | bytearray) -> list[MavMessage]:
        """Add bytes; return the messages completed by them (in order).

        In datagram mode ``data`` is one whole datagram and nothing carries over.
        """
        if not self._datagram:
            buf = self._buf
            buf.extend(data)
            out, p, quiet = self._scan(buf, 0, self._quiet)
            del buf[:p]
            self._quiet = max(0, quiet - p)
            return out
        n = len(data)
        if self._signing_key is None:
            # a datagram of one valid high-rate frame (what vehicles send): at once
            msg = fastframe.decode(data, 0, n, self._header_only)
            if msg is not None and msg is not fastframe.BAD_CRC:
                self.counters.counts["frames_ok"] += 1
                return [msg]
        # a datagram of one frame: decided at once
        if n > 2 and data[0] in (MAGIC_V2, MAGIC_V1) and _frame_length(data, 0, n) == n:
            msg, reason = self._try_decode(data, 0, n)
            if msg is not None:
                self.counters.add("frames_ok")
                return [msg]
            assert reason is not None
            self.counters.add(reason)  # one rejected frame; a valid one may sit inside
            return self._scan(data, 1, n)[0]
        return self._scan(data, 0, 0)[0]

    def _scan(
        self, buf: bytes | bytearray, p: int, quiet: int
    ) -> tuple[list[MavMessage], int, int]:
        """The frames in ``buf`` from ``p``: their messages, where the scan stopped (an
        incomplete frame in stream mode) and ``quiet``.

        A rejected candidate with intact boundaries (a magic byte right after it) is
        counted once; its inner bytes are still scanned (a valid frame may sit inside a
        span claimed by a corrupt length) but not counted again up to ``quiet``."""
        out: list[MavMessage] = []
        n = len(buf)
        counters = self.counters
        datagram = self._datagram
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
                if datagram:  # nothing more will come: not a frame start, resync
                    if p >= quiet:
                        counters.add("truncated")
                    p += 1
                    continue
                break  # incomplete
            msg, reason = self._try_decode(buf, p, length)
            if msg is not None:
                out.append(msg)
                counters.add("frames_ok")
                p += length
                continue
            assert reason is not None
            if p >= quiet:
                counters.add(reason)
                if (p + length < n and buf[p + length] in (MAGIC_V1, MAGIC_V2)) or (
                    p + length == n and datagram
                ):
                    quiet = p + length  # intact frame boundaries: one rejected frame
            p += 1  # resync on the next magic byte
        return out, p, quiet


class TlogRecord(NamedTuple):
    """One decoded frame of a ``.tlog`` with its host timestamp (µs since the UNIX epoch).

    A named tuple: built once per frame of a replay, in a third of a frozen dataclass's
    time."""

    t_host_us: int
    msg: MavMessage
    offset: int


def iter_tlog(
    data: bytes, counters: FrameCounters | None = None, fields_of: frozenset[str] | None = None
) -> Iterator[TlogRecord]:
    """Decode a ``.tlog`` image: records of an 8-byte big-endian µs timestamp and a frame.

    A record whose frame fails to decode is counted and skipped as a whole when the next
    record's frame starts where expected; otherwise we resync on the next offset where
    a frame decodes (the 8 bytes before it are its timestamp). ``counters`` gets the
    same reasons as :class:`FrameDecoder`, plus ``tlog_resync_bytes``; ``fields_of`` as
    :class:`FrameDecoder`'s.
    """
    ctr = counters if counters is not None else FrameCounters()
    # only for _try_decode
    dec = FrameDecoder(datagram=True, counters=FrameCounters(), fields_of=fields_of)
    n = len(data)
    p = 0
    # the common case compiled (fastframe.tlog_run): whole frames that fastframe decodes,
    # in runs; the first record it leaves is decided (and counted) by the path below
    run = type(data) is bytes

    def frame_at(q: int) -> tuple[int | None, MavMessage | None, str | None]:
        if q >= n or data[q] not in (MAGIC_V1, MAGIC_V2):
            return None, None, "bad_header"
        length = _frame_length(data, q, n)
        if length is None or q + length > n:
            return length, None, "truncated"
        msg, reason = dec._try_decode(data, q, length)
        return length, msg, reason

    while p + 8 < n:
        if run:
            recs, p = fastframe.tlog_run(data, p, dec._header_only, TlogRecord, _TLOG_RUN)
            k = 0  # counted as handed out, as the records below are (a consumer may stop)
            try:
                for rec in recs:
                    k += 1
                    yield rec
            finally:
                ctr.add("frames_ok", k)
            if len(recs) == _TLOG_RUN or p + 8 >= n:
                continue  # a full run: the next one compiled too; or the end
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
