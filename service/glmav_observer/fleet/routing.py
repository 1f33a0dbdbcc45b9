"""MAVLink frames cut and routed without decoding them (the parent of ``serve --workers``).

The sender's system id is read from the frame header (MAVLink 2, magic 0xFD: byte 5;
MAVLink 1, magic 0xFE: byte 3); stream links (TCP, serial) are cut into frames by the
header's length (a frame is taken when a magic byte follows it or the buffer ends with it,
as the decoder's own resync rule does).
"""

from __future__ import annotations

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_SIGNATURE_LEN = 13


def sysid_of(data: bytes | bytearray, p: int = 0) -> int | None:
    """The sender's system id from the MAVLink header at ``p`` (None: no header there)."""
    n = len(data)
    if p >= n:
        return None
    magic = data[p]
    if magic == MAGIC_V2:
        return data[p + 5] if p + 5 < n else None
    if magic == MAGIC_V1:
        return data[p + 3] if p + 3 < n else None
    return None


def frame_length(data: bytes | bytearray, p: int) -> int | None:
    """Total length of the frame at ``p`` (None: header incomplete or no magic)."""
    n = len(data)
    magic = data[p]
    if magic == MAGIC_V2:
        if p + 3 > n:
            return None
        return 12 + data[p + 1] + (_SIGNATURE_LEN if data[p + 2] & 0x01 else 0)
    if magic == MAGIC_V1:
        if p + 2 > n:
            return None
        return 8 + data[p + 1]
    return None


def crc_ok(buf: bytes | bytearray, p: int, length: int) -> bool:
    """Whether the frame at ``p`` has a good CRC (only for ambiguous frames: it costs)."""
    from pymavlink.dialects.v20 import ardupilotmega as dialect
    from pymavlink.generator.mavcrc import x25crc

    v2 = buf[p] == MAGIC_V2
    if v2:
        msgid = buf[p + 7] | buf[p + 8] << 8 | buf[p + 9] << 16
        end = p + 10 + buf[p + 1]
    else:
        msgid = buf[p + 5]
        end = p + 6 + buf[p + 1]
    cls = dialect.mavlink_map.get(msgid)
    if cls is None or end + 2 > p + length:
        return False
    crc = x25crc(bytes(buf[p + 1 : end]))
    crc.accumulate(bytes([cls.crc_extra]))
    return bool(crc.crc == (buf[end] | buf[end + 1] << 8))


class StreamSplitter:
    """Cuts a byte stream into frames by header length, without decoding them.

    ``feed(data)`` returns ``(sysid or None, bytes)`` pieces: whole frames with their
    sender's system id, and runs of bytes that are not a frame (sysid None). A candidate
    frame is taken when a magic byte follows it or it ends the bytes received so far;
    when other bytes follow it, it is taken only if its CRC is good (a corrupt length
    byte claims a wrong span); otherwise its magic byte is passed on as garbage and the
    scan resumes one byte later, as the decoder's own resync does."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int | None, bytes]]:
        buf = self._buf
        buf.extend(data)
        out: list[tuple[int | None, bytes]] = []
        p = 0
        n = len(buf)
        garbage_from = -1
        while p < n:
            b = buf[p]
            if b not in (MAGIC_V2, MAGIC_V1):
                if garbage_from < 0:
                    garbage_from = p
                p += 1
                continue
            length = frame_length(buf, p)
            if length is None or p + length > n:
                break  # wait for more
            end = p + length
            if end < n and buf[end] not in (MAGIC_V1, MAGIC_V2) and not crc_ok(buf, p, length):
                if garbage_from < 0:
                    garbage_from = p
                p += 1
                continue
            if garbage_from >= 0:
                out.append((None, bytes(buf[garbage_from:p])))
                garbage_from = -1
            out.append((sysid_of(buf, p), bytes(buf[p:end])))
            p = end
        if garbage_from >= 0:
            out.append((None, bytes(buf[garbage_from:p])))
        del buf[:p]
        return out
