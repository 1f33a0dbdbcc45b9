"""MAVLink 2 packing and framing of the simulator's sensor streams, compiled (Cython).

:class:`StreamWriter` packs RAW_IMU, SCALED_IMU, HIGHRES_IMU, ATTITUDE,
LOCAL_POSITION_NED and SIM_STATE (~930 messages a simulated second in the ideal
profile) from their values, and frames each as pymavlink's ``MAVLink_message._pack``
does: header (0xFD, length, incompatibility flags, 0, sequence, system, component,
24-bit message id), the payload without its trailing zero bytes (at least one kept),
the X.25 CRC of everything after the start byte plus the message's CRC_EXTRA, and, when
signing, link id, 48-bit timestamp and the first 6 bytes of SHA-256(key + packet). A
packet costs ~1 us here against ~10 us through pymavlink's message objects; every
other message still goes through pymavlink, with the same sequence number.
tests/unit/glmav_sitl/test_sitl_frame.py holds the bytes equal to pymavlink's.
"""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize
from libc.math cimport isfinite, isinf, nearbyint
from libc.string cimport memcpy, memset

from hashlib import sha256 as _sha256

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


# ----------------------------------------------------------------------------- streams

cdef inline void _u16(unsigned char* b, unsigned int v) noexcept nogil:
    b[0] = v & 0xFF
    b[1] = (v >> 8) & 0xFF


cdef inline void _u32(unsigned char* b, unsigned long long v) noexcept nogil:
    cdef int i
    for i in range(4):
        b[i] = (v >> (8 * i)) & 0xFF


cdef inline void _u64(unsigned char* b, unsigned long long v) noexcept nogil:
    cdef int i
    for i in range(8):
        b[i] = (v >> (8 * i)) & 0xFF


cdef inline void _f32(unsigned char* b, double x) except *:
    """x as a little-endian IEEE float, rounded as struct's "f" (and, like it, an
    OverflowError for a finite x beyond the float range)."""
    cdef float y = <float>x
    if isinf(y) and not isinf(x):
        raise OverflowError("float too large to pack with f format")
    cdef unsigned int u
    memcpy(&u, &y, 4)
    _u32(b, u)


cdef inline int _i16(double x) noexcept nogil:
    """vehicle's int16 quantisation: round half to even (Python's round), saturated at
    +-32767, 0 for a non-finite x."""
    if not isfinite(x):
        return 0
    cdef double v = nearbyint(x)
    return -32767 if v < -32767.0 else (32767 if v > 32767.0 else <int>v)


def i16(double x):
    """The int16 quantisation of RAW_IMU and SCALED_IMU (:func:`_i16`), from Python."""
    return _i16(x)


cdef class StreamWriter:
    """The six stream messages packed, framed and written in C: to every link and, with
    an 8-byte big-endian timestamp before each packet, to the tlog.

    ``mav`` is the vehicle's pymavlink encoder: its sequence number (one across both
    paths) and, when it signs, its signing state (key, link id, timestamp) are used and
    advanced as pymavlink's ``send`` does."""

    cdef object mav
    cdef list links
    cdef object tlog
    cdef unsigned char sysid, compid
    cdef unsigned char payload[MAX_PAYLOAD]

    def __init__(self, mav, links, tlog):
        self.mav = mav
        self.links = list(links)
        self.tlog = tlog
        self.sysid = mav.srcSystem
        self.compid = mav.srcComponent

    cdef _send(self, int plen, unsigned int msgid, unsigned char crc_extra, unsigned long long stamp_us):
        cdef object mav = self.mav
        cdef unsigned char seq = mav.seq
        cdef unsigned char buf[8 + HEADER_LEN + MAX_PAYLOAD + 2 + 13]
        cdef unsigned char* pk = buf + 8
        cdef const unsigned char* p = self.payload
        cdef object signing = mav.signing
        cdef bint sign = signing.sign_outgoing
        cdef Py_ssize_t i, n
        cdef unsigned short crc = 0xFFFF
        cdef unsigned long long ts
        while plen > 1 and p[plen - 1] == 0:
            plen -= 1
        pk[0] = 0xFD
        pk[1] = <unsigned char>plen
        pk[2] = 0x01 if sign else 0  # MAVLINK_IFLAG_SIGNED
        pk[3] = 0
        pk[4] = seq
        pk[5] = self.sysid
        pk[6] = self.compid
        pk[7] = msgid & 0xFF
        pk[8] = (msgid >> 8) & 0xFF
        pk[9] = (msgid >> 16) & 0xFF
        memcpy(pk + HEADER_LEN, p, plen)
        for i in range(1, HEADER_LEN + plen):
            crc = crc_accumulate(pk[i], crc)
        crc = crc_accumulate(crc_extra, crc)
        n = HEADER_LEN + plen
        pk[n] = crc & 0xFF
        pk[n + 1] = crc >> 8
        n += 2
        if sign:
            ts = signing.timestamp
            pk[n] = <unsigned char>signing.link_id
            for i in range(6):
                pk[n + 1 + i] = (ts >> (8 * i)) & 0xFF
            n += 7
            h = _sha256(signing.secret_key)
            h.update(PyBytes_FromStringAndSize(<char*>pk, n))
            sig = h.digest()
            memcpy(pk + n, PyBytes_AS_STRING(sig), 6)
            n += 6
            signing.timestamp = ts + 1
        packet = PyBytes_FromStringAndSize(<char*>pk, n)
        for w in self.links:
            w.write(packet)
        if self.tlog is not None:
            _u64(buf, 0)
            for i in range(8):
                buf[i] = (stamp_us >> (8 * (7 - i))) & 0xFF
            self.tlog.write(PyBytes_FromStringAndSize(<char*>buf, n + 8))
        mav.seq = (seq + 1) % 256
        mav.total_packets_sent += 1
        mav.total_bytes_sent += n

    def highres_imu(self, unsigned long long stamp_us, unsigned long long t_us, gyro, acc):
        """HIGHRES_IMU (105): accel m/s^2, gyro rad/s, fields_updated 0x3F."""
        cdef unsigned char* b = self.payload
        cdef int i
        _u64(b, t_us)
        for i in range(3):
            _f32(b + 8 + 4 * i, acc[i])
            _f32(b + 20 + 4 * i, gyro[i])
        memset(b + 32, 0, 28)
        _u16(b + 60, 0x3F)
        b[62] = 0
        self._send(63, 105, 93, stamp_us)

    def raw_imu(
        self, unsigned long long stamp_us, unsigned long long t_us, gyro, acc, double ka,
        double kg,
    ):
        """RAW_IMU (27): accel in units of 1/ka m/s^2, gyro in units of 1/kg rad/s, int16."""
        cdef unsigned char* b = self.payload
        cdef int i
        _u64(b, t_us)
        for i in range(3):
            _u16(b + 8 + 2 * i, <unsigned int>(_i16(<double>acc[i] * ka) & 0xFFFF))
            _u16(b + 14 + 2 * i, <unsigned int>(_i16(<double>gyro[i] * kg) & 0xFFFF))
        memset(b + 20, 0, 9)
        self._send(29, 27, 144, stamp_us)

    def scaled_imu(self, unsigned long long stamp_us, unsigned long long t_ms, gyro, acc):
        """SCALED_IMU (26): accel mG, gyro mrad/s, int16."""
        cdef unsigned char* b = self.payload
        cdef int i
        cdef double ka = 1000.0 / 9.80665
        _u32(b, <unsigned int>t_ms)
        for i in range(3):
            _u16(b + 4 + 2 * i, <unsigned int>(_i16(<double>acc[i] * ka) & 0xFFFF))
            _u16(b + 10 + 2 * i, <unsigned int>(_i16(<double>gyro[i] * 1000.0) & 0xFFFF))
        memset(b + 16, 0, 8)
        self._send(24, 26, 170, stamp_us)

    def attitude(self, unsigned long long stamp_us, unsigned int t_ms, eul, w):
        """ATTITUDE (30): roll, pitch, yaw (rad), body rates (rad/s)."""
        cdef unsigned char* b = self.payload
        cdef int i
        _u32(b, t_ms)
        for i in range(3):
            _f32(b + 4 + 4 * i, eul[i])
            _f32(b + 16 + 4 * i, w[i])
        self._send(28, 30, 39, stamp_us)

    def local_position_ned(self, unsigned long long stamp_us, unsigned int t_ms, pos, vel):
        """LOCAL_POSITION_NED (32): x, y, z (m), vx, vy, vz (m/s)."""
        cdef unsigned char* b = self.payload
        cdef int i
        _u32(b, t_ms)
        for i in range(3):
            _f32(b + 4 + 4 * i, pos[i])
            _f32(b + 16 + 4 * i, vel[i])
        self._send(28, 32, 185, stamp_us)

    def sim_state(self, unsigned long long stamp_us, floats, int lat_int, int lon_int):
        """SIM_STATE (108): its 21 float fields in order, then lat_int, lon_int (degE7)."""
        cdef unsigned char* b = self.payload
        cdef int i
        if len(floats) != 21:
            raise ValueError(f"SIM_STATE: 21 floats expected, got {len(floats)}")
        for i in range(21):
            _f32(b + 4 * i, floats[i])
        _u32(b + 84, <unsigned int>lat_int)
        _u32(b + 88, <unsigned int>lon_int)
        self._send(92, 108, 32, stamp_us)
