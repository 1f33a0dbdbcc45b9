"""MAVLink 2 framing of the simulator's own streams, compiled (Cython).

``frame_v2`` wraps a packed payload as pymavlink's ``MAVLink_message._pack`` does for an
unsigned MAVLink 2 packet: header (0xFD, length, flags 0, 0, sequence, system,
component, 24-bit message id), the payload without its trailing zero bytes (at least
one kept), and the X.25 CRC of everything after the start byte plus the message's
CRC_EXTRA. The streams at hundreds of messages a second are framed here (~0.3 us
instead of ~10 us through pymavlink's message objects); every other message, and every
signed one, still goes through pymavlink. tests/unit/glmav_sitl/test_sitl_frame.py
holds the bytes equal to pymavlink's.
"""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize, PyBytes_GET_SIZE

cdef enum:
    HEADER_LEN = 10
    MAX_PAYLOAD = 255


cdef inline unsigned short crc_accumulate(unsigned char b, unsigned short crc) noexcept nogil:
    """One byte into the X.25 (CRC-16/MCRF4XX) checksum, as MAVLink defines it."""
    cdef unsigned char tmp = b ^ <unsigned char>(crc & 0xFF)
    tmp ^= <unsigned char>(tmp << 4)
    return <unsigned short>(
        (crc >> 8) ^ (<unsigned short>tmp << 8) ^ (<unsigned short>tmp << 3) ^ (tmp >> 4)
    )


def frame_v2(
    bytes payload,
    unsigned int msgid,
    unsigned char crc_extra,
    unsigned char seq,
    unsigned char sysid,
    unsigned char compid,
):
    """The unsigned MAVLink 2 packet of ``payload`` (module docstring)."""
    cdef Py_ssize_t plen = PyBytes_GET_SIZE(payload)
    if plen > MAX_PAYLOAD:
        raise ValueError(f"payload of {plen} bytes: at most {MAX_PAYLOAD}")
    if msgid > 0xFFFFFF:
        raise ValueError(f"message id {msgid} does not fit 24 bits")
    cdef const unsigned char* p = <const unsigned char*>PyBytes_AS_STRING(payload)
    while plen > 1 and p[plen - 1] == 0:
        plen -= 1
    cdef unsigned char buf[HEADER_LEN + MAX_PAYLOAD + 2]
    buf[0] = 0xFD
    buf[1] = <unsigned char>plen
    buf[2] = 0
    buf[3] = 0
    buf[4] = seq
    buf[5] = sysid
    buf[6] = compid
    buf[7] = msgid & 0xFF
    buf[8] = (msgid >> 8) & 0xFF
    buf[9] = (msgid >> 16) & 0xFF
    cdef Py_ssize_t i
    for i in range(plen):
        buf[HEADER_LEN + i] = p[i]
    cdef unsigned short crc = 0xFFFF
    for i in range(1, HEADER_LEN + plen):
        crc = crc_accumulate(buf[i], crc)
    crc = crc_accumulate(crc_extra, crc)
    buf[HEADER_LEN + plen] = crc & 0xFF
    buf[HEADER_LEN + plen + 1] = crc >> 8
    return PyBytes_FromStringAndSize(<char*>buf, HEADER_LEN + plen + 2)
