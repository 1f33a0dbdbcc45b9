"""MAVLink frames cut and routed without decoding them (the parent of ``serve --workers``).

The sender's system id is read from the frame header (MAVLink 2, magic 0xFD: byte 5;
MAVLink 1, magic 0xFE: byte 3); stream links (TCP, serial) are cut into frames by the
header's length (a frame is taken when a magic byte follows it or the buffer ends with it,
as the decoder's own resync rule does).

Which worker owns a vehicle is one rule, :func:`worker_of_sysid` (Fibonacci hashing of
the system id): the parent applies it in Python, the kernel applies it as the classic BPF
program of :func:`reuseport_program` (``SO_ATTACH_REUSEPORT_CBPF``,
:mod:`glmav_observer.fleet.reuseport`), so a vehicle goes to the same worker whichever
link it is heard on, and after a restart.
"""

from __future__ import annotations

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_SIGNATURE_LEN = 13
#: 2^32 / φ, odd: Knuth's multiplicative (Fibonacci) hash. frac(sysid · φ⁻¹) spreads
#: consecutive ids (1, 2, 3, ...) and strided ones (10, 20, ...) evenly over [0, 1).
SYSID_HASH = 0x9E3779B1


def worker_of_sysid(sysid: int, n_workers: int) -> int:
    """The worker (0..n-1) that owns ``sysid``: ⌊frac(sysid · SYSID_HASH / 2³²) · n⌋,
    with the fraction cut to 16 bits (as the kernel program computes it in 32-bit
    arithmetic). Consecutive ids 1..K (K ≤ 255, n ≤ 8) leave the workers' counts at most
    3 apart (the golden ratio's multiples are the most evenly spread: three-gap theorem);
    a least-loaded choice would be even, but would depend on the order vehicles appear."""
    frac16 = ((sysid * SYSID_HASH) & 0xFFFFFFFF) >> 16
    return (frac16 * n_workers) >> 16


#: classic BPF opcodes (linux/filter.h) used by :func:`reuseport_program`
_LDB_ABS, _JEQ_K, _JA, _RET_K, _RET_A = 0x30, 0x15, 0x05, 0x06, 0x16
_MUL_K, _RSH_K = 0x24, 0x74


def reuseport_program(n_workers: int) -> list[tuple[int, int, int, int]]:
    """The routing rule as a classic BPF program ``(code, jt, jf, k)`` for a reuseport
    group of ``n_workers`` UDP sockets: the kernel runs it on each datagram's payload
    and delivers the datagram to the socket at the index it returns.

    MAVLink 2 (0xFD at byte 0): system id at byte 5; MAVLink 1 (0xFE): byte 3; anything
    else, or a datagram too short for its header (the load fails: the program returns
    0), goes to index 0, as :func:`sysid_of` gives None and the parent sends it to worker 0.
    Then :func:`worker_of_sysid` in 32-bit arithmetic (ids < 256: no overflow but the
    product's wanted wrap)."""
    if not 1 <= n_workers <= 256:
        raise ValueError(f"{n_workers} workers: must be 1..256")
    return [
        (_LDB_ABS, 0, 0, 0),  # 0: A = byte 0 (the magic)
        (_JEQ_K, 2, 0, MAGIC_V2),  # 1: v2 -> 4
        (_JEQ_K, 3, 0, MAGIC_V1),  # 2: v1 -> 6
        (_RET_K, 0, 0, 0),  # 3: no header: worker 0
        (_LDB_ABS, 0, 0, 5),  # 4: A = v2 system id
        (_JA, 0, 0, 1),  # 5: -> 7
        (_LDB_ABS, 0, 0, 3),  # 6: A = v1 system id
        (_MUL_K, 0, 0, SYSID_HASH),  # 7: A = sysid · SYSID_HASH mod 2³²
        (_RSH_K, 0, 0, 16),  # 8: the 16-bit fraction
        (_MUL_K, 0, 0, n_workers),  # 9: · n (< 2³²: 2¹⁶ · 256)
        (_RSH_K, 0, 0, 16),  # 10: ⌊·⌋
        (_RET_A, 0, 0, 0),  # 11: the socket index
    ]


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


def datagram_sysid(data: bytes | bytearray) -> int | None:
    """The system id a datagram is routed by: its first header's (garbage before it is
    skipped), None when it holds no header (it goes to worker 0)."""
    sysid = sysid_of(data)
    if sysid is None and data and data[0] not in (MAGIC_V1, MAGIC_V2):
        q = min((x for x in (data.find(MAGIC_V2), data.find(MAGIC_V1)) if x >= 0), default=-1)
        sysid = sysid_of(data, q) if q >= 0 else None
    return sysid


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
