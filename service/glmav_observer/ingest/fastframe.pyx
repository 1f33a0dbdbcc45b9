"""The high-rate MAVLink messages decoded straight from the frame bytes (compiled).

ATTITUDE, RAW_IMU, SCALED_IMU, SCALED_IMU2, SCALED_IMU3, HIGHRES_IMU, LOCAL_POSITION_NED
and SIM_STATE are 99 % of what a vehicle sends the service (design rates: 380 of 381
datagrams a second). Their layouts are fixed (no arrays, no strings), so C code reads a
frame of one (MAVLink 1 or 2, signed or not) into a small extension object:

- :func:`decode` checks the frame's CRC-16/MCRF4XX with the message's CRC extra (both
  from pymavlink's generated dialect, the one source of the wire definitions) and builds
  a :class:`FastMessage`: the header (system, component, sequence, signed) and every
  field under the dialect's name, with the values pymavlink's ``decode`` gives (a
  MAVLink 2 payload's truncated trailing zeros padded back, a longer payload cut;
  tests/unit/glmav_observer/ingest/test_fastframe.py pins both, bit for bit);
- :meth:`FastMessage.sample` turns it into the sample the estimator takes
  (:mod:`glmav_observer.ingest.samples`, SI units; the checks and counters' reasons of
  :mod:`glmav_observer.ingest.convert`), given the vehicle time the clock decided.

A frame of any other message whose fields its reader does not need (``decode``'s
``header_only``: the ids an ingest reads nothing of but the header) has its CRC checked
the same way and comes back as a :class:`HeaderOnly`: the header, and pymavlink's
decode of the same bytes only if a field is asked for. That is a vehicle's and its
ground station's other telemetry, which the ingest counts and ignores: framed in 0.3 µs
against pymavlink's 4.2-5.1 µs (VFR_HUD, SYS_STATUS, GLOBAL_POSITION_INT).

Signature and freshness (MAVLink 2 signing) stay with the framing
(:class:`glmav_observer.ingest.framing.FrameDecoder`), after the CRC as before. Every
other message id is left to pymavlink (``decode`` returns None). A little-endian host
is assumed (x86, ARM): the import refuses any other.
"""

import dataclasses
import struct
import sys

from cpython.bytearray cimport PyByteArray_AS_STRING, PyByteArray_GET_SIZE
from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize, PyBytes_GET_SIZE
from cpython.object cimport PyObject_GenericSetAttr
from libc.math cimport fabs, isfinite
from libc.stdint cimport int16_t, int32_t, uint8_t, uint16_t, uint32_t, uint64_t
from libc.string cimport memcpy, memset

from pymavlink.dialects.v20 import ardupilotmega as _dialect

from glmav_observer.ingest.convert import (
    IMU_MAX_F_MPS2,
    IMU_MAX_OMEGA_RADPS,
    MG_TO_MPS2,
    MRAD_TO_RAD,
    TIME_BOOT_MS,
    TIME_NONE,
    TIME_USEC,
    ConversionError,
)
from glmav_observer.ingest.samples import (
    AttitudeSample,
    ImuSample,
    ImuSource,
    SecondaryImuSample,
    TruthSample,
    VelocitySample,
)

if sys.byteorder != "little":
    raise ImportError("glmav_observer.ingest.fastframe reads MAVLink's little-endian "
                      "fields in place: a big-endian host is not supported")

cdef enum:
    MAGIC_V1 = 0xFE
    MAGIC_V2 = 0xFD
    SIGNATURE_LEN = 13
    MAX_PAYLOAD = 255
    # message ids (common.xml)
    ID_SCALED_IMU = 26
    ID_RAW_IMU = 27
    ID_ATTITUDE = 30
    ID_LOCAL_POSITION_NED = 32
    ID_HIGHRES_IMU = 105
    ID_SIM_STATE = 108
    ID_SCALED_IMU2 = 116
    ID_SCALED_IMU3 = 129

#: The messages decoded here, with the wire layout (struct format, MAVLink 2 extension
#: fields included) the C code below reads, whatever pymavlink version defines them: an
#: older one without an extension field has a prefix of it (the CRC extra covers only the
#: base fields), anything else is refused at import rather than decoded wrong.
_LAYOUTS = {
    "ATTITUDE": "<Iffffff",
    "RAW_IMU": "<QhhhhhhhhhBh",
    "SCALED_IMU": "<Ihhhhhhhhhh",
    "SCALED_IMU2": "<Ihhhhhhhhhh",
    "SCALED_IMU3": "<Ihhhhhhhhhh",
    "HIGHRES_IMU": "<QfffffffffffffHB",
    "LOCAL_POSITION_NED": "<Iffffff",
    "SIM_STATE": "<fffffffffffffffffffffii",
}
#: The messages decoded here (each a fixed layout; everything else is pymavlink's).
FAST_MESSAGES = frozenset(_LAYOUTS)

# per message id < 256 (all of ours): the CRC extra (pymavlink's dialect) and the payload
# size (0: not decoded here), and the message's name
cdef uint8_t _crc_extra[256]
cdef Py_ssize_t _payload_len[256]
cdef object _names = [None] * 256
memset(_crc_extra, 0, sizeof(_crc_extra))
memset(_payload_len, 0, sizeof(_payload_len))
for _name in sorted(FAST_MESSAGES):
    _cls = _dialect.mavlink_map[getattr(_dialect, "MAVLINK_MSG_ID_" + _name)]
    if not _LAYOUTS[_name].startswith(_cls.unpacker.format):
        raise ImportError(
            f"glmav_observer.ingest.fastframe reads {_name} as {_LAYOUTS[_name]}; this "
            f"pymavlink ({_dialect.__file__}) defines it as {_cls.unpacker.format}"
        )
    _crc_extra[_cls.id] = _cls.crc_extra
    _payload_len[_cls.id] = struct.calcsize(_LAYOUTS[_name])
    _names[_cls.id] = _name
# per message id < 256 of the whole dialect: the CRC extra, the longest payload
# (extensions included; 0: no such message) and the name, for :class:`HeaderOnly`
cdef uint8_t _crc_extra_any[256]
cdef Py_ssize_t _max_len_any[256]
cdef object _names_any = [None] * 256
memset(_crc_extra_any, 0, sizeof(_crc_extra_any))
memset(_max_len_any, 0, sizeof(_max_len_any))
for _id, _cls in _dialect.mavlink_map.items():
    if 0 <= _id < 256:
        _crc_extra_any[_id] = _cls.crc_extra
        _max_len_any[_id] = _cls.unpacker.size
        _names_any[_id] = _cls.msgname
#: pymavlink told to accept bad CRCs (MAVLINK_IGNORE_CRC): then so do we
cdef bint _ignore_crc = bool(_dialect.MAVLINK_IGNORE_CRC)

_HIGHRES_IMU, _SCALED_IMU, _RAW_IMU = ImuSource.HIGHRES_IMU, ImuSource.SCALED_IMU, ImuSource.RAW_IMU


cdef tuple _field_names(object cls):
    return tuple(f.name for f in dataclasses.fields(cls))


cdef tuple _ATTITUDE = _field_names(AttitudeSample)
cdef tuple _IMU = _field_names(ImuSample)
cdef tuple _SECONDARY = _field_names(SecondaryImuSample)
cdef tuple _VELOCITY = _field_names(VelocitySample)
cdef tuple _TRUTH = _field_names(TruthSample)


cdef object _new(object cls, tuple names, tuple values):
    """``cls(*values)`` for one of the frozen sample dataclasses, as its ``__init__`` sets
    its fields (``object.__setattr__``, which is PyObject_GenericSetAttr) without the
    Python frame of that ``__init__``: 0.2 µs instead of 1.1 per sample."""
    obj = cls.__new__(cls)
    cdef Py_ssize_t i
    for i in range(len(names)):
        PyObject_GenericSetAttr(obj, names[i], values[i])
    return obj


cdef inline uint16_t _crc_accumulate(const uint8_t* p, Py_ssize_t n, uint16_t crc) noexcept nogil:
    """CRC-16/MCRF4XX (MAVLink's X.25 checksum) of ``n`` bytes, continuing ``crc``."""
    cdef uint8_t tmp
    cdef Py_ssize_t i
    for i in range(n):
        tmp = p[i] ^ <uint8_t>(crc & 0xFF)
        tmp ^= <uint8_t>(tmp << 4)
        crc = <uint16_t>((crc >> 8) ^ (<uint16_t>tmp << 8) ^ (<uint16_t>tmp << 3) ^ (tmp >> 4))
    return crc


cdef const uint8_t* _bytes_of(object data, Py_ssize_t* n) except NULL:
    """The bytes of ``data``, a bytes or bytearray object (callers copy any other buffer
    into bytes first, see :func:`_as_bytes`)."""
    if type(data) is bytes:
        n[0] = PyBytes_GET_SIZE(data)
        return <const uint8_t*>PyBytes_AS_STRING(data)
    if type(data) is bytearray:
        n[0] = PyByteArray_GET_SIZE(data)
        return <const uint8_t*>PyByteArray_AS_STRING(data)
    raise TypeError(f"bytes or bytearray expected, not {type(data).__name__}")


cdef inline object _as_bytes(object data):
    """``data`` itself if bytes or bytearray, else a bytes copy of its buffer (memoryview,
    mmap, array): read in place only what cannot move."""
    if type(data) is bytes or type(data) is bytearray:
        return data
    return bytes(data)


def frame_crc(data, Py_ssize_t start, Py_ssize_t end, int crc_extra):
    """MAVLink's checksum of the frame at ``start`` in ``data`` (its bytes after the magic
    up to ``end``, the end of its payload) followed by the message's CRC extra."""
    cdef Py_ssize_t n
    data = _as_bytes(data)
    cdef const uint8_t* p = _bytes_of(data, &n)
    if not 0 <= start < end <= n or not 0 <= crc_extra <= 255:
        raise ValueError("frame_crc: bounds or CRC extra out of range")
    cdef uint8_t extra = <uint8_t>crc_extra
    return _crc_accumulate(&extra, 1, _crc_accumulate(p + start + 1, end - start - 1, 0xFFFF))


cdef inline uint16_t _u16(const uint8_t* p) noexcept nogil:
    cdef uint16_t v
    memcpy(&v, p, 2)
    return v


cdef inline int16_t _i16(const uint8_t* p) noexcept nogil:
    cdef int16_t v
    memcpy(&v, p, 2)
    return v


cdef inline uint32_t _u32(const uint8_t* p) noexcept nogil:
    cdef uint32_t v
    memcpy(&v, p, 4)
    return v


cdef inline int32_t _i32(const uint8_t* p) noexcept nogil:
    cdef int32_t v
    memcpy(&v, p, 4)
    return v


cdef inline uint64_t _u64(const uint8_t* p) noexcept nogil:
    cdef uint64_t v
    memcpy(&v, p, 8)
    return v


cdef inline double _f32(const uint8_t* p) noexcept nogil:
    cdef float v
    memcpy(&v, p, 4)
    return <double>v  # exact, as Python's struct 'f'


cdef inline bint _finite3(double x, double y, double z) noexcept nogil:
    return isfinite(x) and isfinite(y) and isfinite(z)


cdef object _not_finite(str what, double x, double y, double z):
    return ConversionError("nan_field", f"{what} not finite: {(x, y, z)}")


cdef object _imu_check(double f0, double f1, double f2, double w0, double w1, double w2, str name):
    """None when the IMU vectors are usable, else the ConversionError (convert.py's rules:
    beyond any IMU's range is corruption; an exactly zero specific force is no sensor)."""
    cdef double lim_f = IMU_MAX_F_MPS2, lim_w = IMU_MAX_OMEGA_RADPS
    if (fabs(f0) > lim_f or fabs(f1) > lim_f or fabs(f2) > lim_f
            or fabs(w0) > lim_w or fabs(w1) > lim_w or fabs(w2) > lim_w):
        return ConversionError(
            "implausible", f"{name} beyond any IMU range: f={(f0, f1, f2)} w={(w0, w1, w2)}"
        )
    if f0 == 0.0 and f1 == 0.0 and f2 == 0.0:
        return ConversionError("imu_absent", f"{name} specific force is exactly zero")
    return None


cdef class FrameHeader:
    """A frame whose CRC checked: its header, with pymavlink's accessors for it (the base
    of :class:`FastMessage` and :class:`HeaderOnly`)."""

    cdef readonly str name
    cdef readonly int msgid
    cdef readonly int sysid
    cdef readonly int compid
    cdef readonly int seq
    cdef readonly bint signed
    cdef object _msgbuf

    def get_type(self):
        return self.name

    def get_msgId(self):
        return self.msgid

    def get_srcSystem(self):
        return self.sysid

    def get_srcComponent(self):
        return self.compid

    def get_seq(self):
        return self.seq

    def get_signed(self):
        return self.signed

    def get_msgbuf(self):
        return self._msgbuf


cdef class FastMessage(FrameHeader):
    """A decoded frame of one of :data:`FAST_MESSAGES`: the header (:class:`FrameHeader`)
    and (in each subclass) the message's fields under the dialect's names."""

    #: the kind of the message's time stamp (convert.TimeKind)
    cdef readonly object time_kind

    @property
    def t_us(self):
        """The message's raw time stamp in µs (0 for SIM_STATE: it has none)."""
        return self._t_us()

    cdef object _t_us(self):
        return 0

    def pack(self, mav, force_mavlink1=False):
        """The message framed again by pymavlink's ``mav`` (its system, component, sequence
        and signing): writing stays pymavlink's."""
        cls = _dialect.mavlink_map[self.msgid]
        return cls(*[getattr(self, f) for f in cls.fieldnames]).pack(mav, force_mavlink1)

    def to_dict(self):
        d = {"mavpackettype": self.name}
        for f in _dialect.mavlink_map[self.msgid].fieldnames:
            d[f] = getattr(self, f)
        return d

    def __repr__(self):
        fields = ", ".join(f"{k} : {v}" for k, v in list(self.to_dict().items())[1:])
        return f"{self.name} {{{fields}}}"

    cpdef object sample(self, double t_boot_s, object raw_scale):
        """The sample of this message at vehicle time ``t_boot_s`` (``raw_scale``: the
        vehicle's :class:`~glmav_observer.ingest.convert.RawImuScale`, for RAW_IMU).
        Raises :class:`~glmav_observer.ingest.convert.ConversionError` for a message that
        cannot be used (``nan_field``, ``implausible``, ``imu_absent``)."""
        raise NotImplementedError


cdef class Attitude(FastMessage):
    cdef public uint32_t time_boot_ms
    cdef public double roll, pitch, yaw, rollspeed, pitchspeed, yawspeed

    cdef object _t_us(self):
        return <uint64_t>self.time_boot_ms * 1000

    cpdef object sample(self, double t_boot_s, object raw_scale):
        if not _finite3(self.roll, self.pitch, self.yaw):
            raise _not_finite("ATTITUDE angles", self.roll, self.pitch, self.yaw)
        if not _finite3(self.rollspeed, self.pitchspeed, self.yawspeed):
            raise _not_finite("ATTITUDE rates", self.rollspeed, self.pitchspeed, self.yawspeed)
        return _new(AttitudeSample, _ATTITUDE, (self.sysid, t_boot_s, (self.roll, self.pitch, self.yaw),
                    (self.rollspeed, self.pitchspeed, self.yawspeed)))


cdef class RawImu(FastMessage):
    cdef public uint64_t time_usec
    cdef public int16_t xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag
    cdef public uint8_t id
    cdef public int16_t temperature

    cdef object _t_us(self):
        return self.time_usec

    cpdef object sample(self, double t_boot_s, object raw_scale):
        cdef double ka = raw_scale.accel_mps2_per_lsb, kw = raw_scale.gyro_radps_per_lsb
        cdef double f0 = self.xacc * ka, f1 = self.yacc * ka, f2 = self.zacc * ka
        cdef double w0 = self.xgyro * kw, w1 = self.ygyro * kw, w2 = self.zgyro * kw
        if not _finite3(f0, f1, f2):  # a scale of inf or NaN
            raise _not_finite("RAW_IMU acc", f0, f1, f2)
        if not _finite3(w0, w1, w2):
            raise _not_finite("RAW_IMU gyro", w0, w1, w2)
        err = _imu_check(f0, f1, f2, w0, w1, w2, "RAW_IMU")
        if err is not None:
            raise err
        return _new(ImuSample, _IMU, (self.sysid, t_boot_s, (f0, f1, f2), (w0, w1, w2), _RAW_IMU))


cdef class ScaledImu(FastMessage):
    """SCALED_IMU, SCALED_IMU2 and SCALED_IMU3 (one layout)."""

    cdef public uint32_t time_boot_ms
    cdef public int16_t xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag
    cdef public int16_t temperature

    cdef object _t_us(self):
        return <uint64_t>self.time_boot_ms * 1000

    cpdef object sample(self, double t_boot_s, object raw_scale):
        cdef double ka = MG_TO_MPS2, kw = MRAD_TO_RAD
        cdef double f0 = self.xacc * ka, f1 = self.yacc * ka, f2 = self.zacc * ka
        cdef double w0 = self.xgyro * kw, w1 = self.ygyro * kw, w2 = self.zgyro * kw
        if self.msgid != ID_SCALED_IMU:  # another IMU of the vehicle: compared, not integrated
            err = _imu_check(f0, f1, f2, 0.0, 0.0, 0.0, self.name)
            if err is not None:
                raise err
            return _new(SecondaryImuSample, _SECONDARY, (self.sysid, t_boot_s,
                        2 if self.msgid == ID_SCALED_IMU2 else 3, (f0, f1, f2)))
        err = _imu_check(f0, f1, f2, w0, w1, w2, "SCALED_IMU")
        if err is not None:
            raise err
        return _new(ImuSample, _IMU, (self.sysid, t_boot_s, (f0, f1, f2), (w0, w1, w2),
                    _SCALED_IMU))


cdef class HighresImu(FastMessage):
    cdef public uint64_t time_usec
    cdef public double xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag
    cdef public double abs_pressure, diff_pressure, pressure_alt, temperature
    cdef public uint16_t fields_updated
    cdef public uint8_t id

    cdef object _t_us(self):
        return self.time_usec

    cpdef object sample(self, double t_boot_s, object raw_scale):
        if not _finite3(self.xacc, self.yacc, self.zacc):
            raise _not_finite("HIGHRES_IMU acc", self.xacc, self.yacc, self.zacc)
        if not _finite3(self.xgyro, self.ygyro, self.zgyro):
            raise _not_finite("HIGHRES_IMU gyro", self.xgyro, self.ygyro, self.zgyro)
        err = _imu_check(self.xacc, self.yacc, self.zacc, self.xgyro, self.ygyro, self.zgyro,
                         "HIGHRES_IMU")
        if err is not None:
            raise err
        return _new(ImuSample, _IMU, (self.sysid, t_boot_s, (self.xacc, self.yacc, self.zacc),
                    (self.xgyro, self.ygyro, self.zgyro), _HIGHRES_IMU))


cdef class LocalPositionNed(FastMessage):
    cdef public uint32_t time_boot_ms
    cdef public double x, y, z, vx, vy, vz

    cdef object _t_us(self):
        return <uint64_t>self.time_boot_ms * 1000

    cpdef object sample(self, double t_boot_s, object raw_scale):
        # NaN velocities are kept: a dropout of the autopilot's estimate is data
        return _new(VelocitySample, _VELOCITY, (self.sysid, t_boot_s, (self.x, self.y, self.z),
                    (self.vx, self.vy, self.vz)))


cdef class SimState(FastMessage):
    cdef public double q1, q2, q3, q4, roll, pitch, yaw, xacc, yacc, zacc
    cdef public double xgyro, ygyro, zgyro, lat, lon, alt, std_dev_horz, std_dev_vert
    cdef public double vn, ve, vd
    cdef public int32_t lat_int, lon_int

    cpdef object sample(self, double t_boot_s, object raw_scale):
        if not _finite3(self.roll, self.pitch, self.yaw):
            raise _not_finite("SIM_STATE angles", self.roll, self.pitch, self.yaw)
        if not _finite3(self.vn, self.ve, self.vd):
            raise _not_finite("SIM_STATE velocity", self.vn, self.ve, self.vd)
        return _new(TruthSample, _TRUTH, (self.sysid, t_boot_s, (self.roll, self.pitch, self.yaw),
                    (self.vn, self.ve, self.vd)))


cdef object _fields(int msgid, const uint8_t* p):
    """The message object of ``msgid`` with its fields read from the (padded) payload
    ``p``, in the dialect's wire order (tests pin it to pymavlink's unpacker)."""
    cdef Attitude a
    cdef RawImu r
    cdef ScaledImu s
    cdef HighresImu h
    cdef LocalPositionNed l
    cdef SimState m
    if msgid == ID_HIGHRES_IMU:  # <QfffffffffffffHB
        h = HighresImu.__new__(HighresImu)
        h.time_usec = _u64(p)
        h.xacc, h.yacc, h.zacc = _f32(p + 8), _f32(p + 12), _f32(p + 16)
        h.xgyro, h.ygyro, h.zgyro = _f32(p + 20), _f32(p + 24), _f32(p + 28)
        h.xmag, h.ymag, h.zmag = _f32(p + 32), _f32(p + 36), _f32(p + 40)
        h.abs_pressure, h.diff_pressure = _f32(p + 44), _f32(p + 48)
        h.pressure_alt, h.temperature = _f32(p + 52), _f32(p + 56)
        h.fields_updated = _u16(p + 60)
        h.id = p[62]
        h.time_kind = TIME_USEC
        return h
    if msgid == ID_ATTITUDE:  # <Iffffff
        a = Attitude.__new__(Attitude)
        a.time_boot_ms = _u32(p)
        a.roll, a.pitch, a.yaw = _f32(p + 4), _f32(p + 8), _f32(p + 12)
        a.rollspeed, a.pitchspeed, a.yawspeed = _f32(p + 16), _f32(p + 20), _f32(p + 24)
        a.time_kind = TIME_BOOT_MS
        return a
    if msgid == ID_LOCAL_POSITION_NED:  # <Iffffff
        l = LocalPositionNed.__new__(LocalPositionNed)
        l.time_boot_ms = _u32(p)
        l.x, l.y, l.z = _f32(p + 4), _f32(p + 8), _f32(p + 12)
        l.vx, l.vy, l.vz = _f32(p + 16), _f32(p + 20), _f32(p + 24)
        l.time_kind = TIME_BOOT_MS
        return l
    if msgid == ID_RAW_IMU:  # <QhhhhhhhhhBh
        r = RawImu.__new__(RawImu)
        r.time_usec = _u64(p)
        r.xacc, r.yacc, r.zacc = _i16(p + 8), _i16(p + 10), _i16(p + 12)
        r.xgyro, r.ygyro, r.zgyro = _i16(p + 14), _i16(p + 16), _i16(p + 18)
        r.xmag, r.ymag, r.zmag = _i16(p + 20), _i16(p + 22), _i16(p + 24)
        r.id = p[26]
        r.temperature = _i16(p + 27)
        r.time_kind = TIME_USEC
        return r
    if msgid == ID_SIM_STATE:  # <fffffffffffffffffffffii
        m = SimState.__new__(SimState)
        m.q1, m.q2, m.q3, m.q4 = _f32(p), _f32(p + 4), _f32(p + 8), _f32(p + 12)
        m.roll, m.pitch, m.yaw = _f32(p + 16), _f32(p + 20), _f32(p + 24)
        m.xacc, m.yacc, m.zacc = _f32(p + 28), _f32(p + 32), _f32(p + 36)
        m.xgyro, m.ygyro, m.zgyro = _f32(p + 40), _f32(p + 44), _f32(p + 48)
        m.lat, m.lon, m.alt = _f32(p + 52), _f32(p + 56), _f32(p + 60)
        m.std_dev_horz, m.std_dev_vert = _f32(p + 64), _f32(p + 68)
        m.vn, m.ve, m.vd = _f32(p + 72), _f32(p + 76), _f32(p + 80)
        m.lat_int, m.lon_int = _i32(p + 84), _i32(p + 88)
        m.time_kind = TIME_NONE
        return m
    # SCALED_IMU, SCALED_IMU2, SCALED_IMU3: <Ihhhhhhhhhh
    s = ScaledImu.__new__(ScaledImu)
    s.time_boot_ms = _u32(p)
    s.xacc, s.yacc, s.zacc = _i16(p + 4), _i16(p + 6), _i16(p + 8)
    s.xgyro, s.ygyro, s.zgyro = _i16(p + 10), _i16(p + 12), _i16(p + 14)
    s.xmag, s.ymag, s.zmag = _i16(p + 16), _i16(p + 18), _i16(p + 20)
    s.temperature = _i16(p + 22)
    s.time_kind = TIME_BOOT_MS
    return s


def header_only_ids(names):
    """The ``header_only`` argument of :func:`decode`: 256 bytes, 1 at the id of every
    message of the dialect below 256 whose name is in ``names`` and not one of
    :data:`FAST_MESSAGES`."""
    flags = bytearray(256)
    for i in range(256):
        name = _names_any[i]
        if name is not None and name in names and name not in FAST_MESSAGES:
            flags[i] = 1
    return bytes(flags)


cdef class HeaderOnly(FrameHeader):
    """A frame whose CRC checked, of a message its reader needs only the header of: the
    header (:class:`FrameHeader`); the fields, if asked for after all, from pymavlink's
    decode of the same bytes (:meth:`full`)."""

    def full(self):
        """pymavlink's message of the same frame (its CRC already checked)."""
        return _dialect.MAVLink(None).decode(bytearray(self._msgbuf))

    def to_dict(self):
        return self.full().to_dict()

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.full(), name)

    def __repr__(self):
        return repr(self.full())


#: what :func:`decode` returns for a frame of one of our messages whose CRC is wrong
BAD_CRC = "bad_crc"


def decode(data, Py_ssize_t start, Py_ssize_t length, bytes header_only=None):
    """The candidate frame of ``length`` bytes at ``start`` in ``data`` (bytes, bytearray,
    or any other buffer, which is copied), decoded: a :class:`FastMessage`; a
    :class:`HeaderOnly` for a message flagged in ``header_only`` (:func:`header_only_ids`);
    :data:`BAD_CRC` when it is one of either with a wrong checksum; None for any other
    message id, unknown incompatibility flags, a header whose payload length does not
    make ``length``, or a header-only message's payload longer than its longest form
    (pymavlink's ``decode`` then decides and names the verdict)."""
    cdef Py_ssize_t n
    data = _as_bytes(data)
    cdef const uint8_t* buf = _bytes_of(data, &n)
    if start < 0 or length < 8 or start + length > n:
        return None
    cdef const uint8_t* f = buf + start
    cdef int msgid, hdr, sysid, compid, seq
    cdef bint signed = False
    cdef Py_ssize_t mlen = f[1], tail = 2
    if f[0] == MAGIC_V2:
        if length < 12 or f[8] or f[9]:  # an id of ours is below 256
            return None
        if f[2]:
            if f[2] != 1:  # unknown incompatibility flags (FrameDecoder refuses them first)
                return None
            signed = True
            tail += SIGNATURE_LEN
        msgid, hdr, seq, sysid, compid = f[7], 10, f[4], f[5], f[6]
    elif f[0] == MAGIC_V1:
        msgid, hdr, seq, sysid, compid = f[5], 6, f[2], f[3], f[4]
    else:
        return None
    cdef Py_ssize_t size = _payload_len[msgid]
    if hdr + mlen + tail != length:
        return None
    cdef Py_ssize_t end = hdr + mlen  # offset of the CRC
    cdef uint8_t extra
    cdef uint16_t crc
    cdef HeaderOnly head
    if size == 0:
        if (
            header_only is None
            or PyBytes_GET_SIZE(header_only) != 256
            or not (<const uint8_t*>PyBytes_AS_STRING(header_only))[msgid]
            or mlen > _max_len_any[msgid]
        ):
            return None
        extra = _crc_extra_any[msgid]
        crc = _crc_accumulate(&extra, 1, _crc_accumulate(f + 1, end - 1, 0xFFFF))
        if crc != _u16(f + end) and not _ignore_crc:
            return BAD_CRC
        head = HeaderOnly.__new__(HeaderOnly)
        _set_header(head, _names_any[msgid], msgid, sysid, compid, seq, signed, data, f, start, length, n)
        return head
    extra = _crc_extra[msgid]
    crc = _crc_accumulate(&extra, 1, _crc_accumulate(f + 1, end - 1, 0xFFFF))
    if crc != _u16(f + end) and not _ignore_crc:
        return BAD_CRC
    cdef uint8_t payload[MAX_PAYLOAD + 1]
    cdef const uint8_t* p = f + hdr
    if mlen < size:  # MAVLink 2 truncates trailing zero bytes: padded back
        memset(payload, 0, size)
        memcpy(payload, p, mlen)
        p = payload
    cdef FastMessage msg = _fields(msgid, p)
    _set_header(msg, _names[msgid], msgid, sysid, compid, seq, signed, data, f, start, length, n)
    return msg


cdef void _set_header(
    FrameHeader msg, str name, int msgid, int sysid, int compid, int seq, bint signed,
    object data, const uint8_t* f, Py_ssize_t start, Py_ssize_t length, Py_ssize_t n,
):
    """The header of the frame of ``length`` bytes at ``f`` (``start`` in ``data``, of
    ``n`` bytes) into ``msg``."""
    msg.name = name
    msg.msgid = msgid
    msg.sysid = sysid
    msg.compid = compid
    msg.seq = seq
    msg.signed = signed
    if start == 0 and length == n and type(data) is bytes:
        msg._msgbuf = data  # a datagram of one frame: no copy
    else:
        msg._msgbuf = PyBytes_FromStringAndSize(<const char*>f, length)


def tlog_run(bytes data, Py_ssize_t p, bytes header_only, record, Py_ssize_t max_n):
    """The records of a ``.tlog`` image (an 8-byte big-endian µs time stamp, then a
    frame) from offset ``p`` on, as long as each frame is whole and :func:`decode` gives
    a message (a :class:`FastMessage`, or a :class:`HeaderOnly` by ``header_only``), at
    most ``max_n`` of them: ``(records, p)``, each record ``record(t_us, msg, offset)``,
    and the offset of the first record not taken. Whatever stops the run (a frame of
    another message, a bad CRC, unknown incompatibility flags, a broken header, the end
    of the data) is left at ``p`` for the caller's full path
    (:func:`glmav_observer.ingest.framing.iter_tlog`), which decides and counts it."""
    cdef Py_ssize_t n = PyBytes_GET_SIZE(data), q, length
    cdef const uint8_t* buf = <const uint8_t*>PyBytes_AS_STRING(data)
    cdef const uint8_t* f
    cdef uint64_t t_us
    cdef int k
    out = []
    while p + 8 < n and len(out) < max_n:
        q = p + 8
        f = buf + q
        if f[0] == MAGIC_V2:
            if n - q < 3 or f[2] & ~1:  # incomplete, or incompatibility flags unknown
                break
            length = 12 + f[1] + (SIGNATURE_LEN if f[2] & 1 else 0)
        elif f[0] == MAGIC_V1:
            if n - q < 2:
                break
            length = 8 + f[1]
        else:
            break
        if q + length > n:
            break
        msg = decode(data, q, length, header_only)
        if msg is None or msg is BAD_CRC:
            break
        t_us = 0
        for k in range(8):
            t_us = (t_us << 8) | buf[p + k]
        out.append(record(t_us, msg, p))
        p = q + length
    return out, p
