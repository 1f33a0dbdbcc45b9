"""The compiled decode of the high-rate messages (ingest/fastframe.pyx) pinned to pymavlink:
the same field values bit for bit (every payload length, MAVLink 1 and 2, signed or not),
the same checksums, and through the framing the same verdicts and counters as a reference
decoder that hands every frame to pymavlink's ``MAVLink.decode``."""

from __future__ import annotations

import math
import pickle
import random
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.ingest import fastframe
from glmav_observer.ingest.convert import MG_TO_MPS2, MRAD_TO_RAD, ConversionError, RawImuScale
from glmav_observer.ingest.fastframe import BAD_CRC, FAST_MESSAGES, FastMessage, frame_crc
from glmav_observer.ingest.framing import FrameCounters, FrameDecoder, iter_tlog
from glmav_observer.ingest.pipeline import Ingest, IngestConfig
from glmav_observer.ingest.samples import (
    AttitudeSample,
    ImuSample,
    ImuSource,
    SecondaryImuSample,
    TruthSample,
    VelocitySample,
)
from glmav_testkit.fuzzgen import KINDS, CaseMaker, sitl_stream

IDS = {name: getattr(dialect, f"MAVLINK_MSG_ID_{name}") for name in sorted(FAST_MESSAGES)}
KEY = bytes(range(32))


def _frame(
    msg_id: int, payload: bytes, *, v1: bool = False, seq: int = 7, sysid: int = 3, compid: int = 1
) -> bytes:
    """A MAVLink frame of any payload, checksummed with the message's CRC extra."""
    crc_extra = dialect.mavlink_map[msg_id].crc_extra
    if v1:
        frame = bytes([0xFE, len(payload), seq, sysid, compid, msg_id]) + payload
    else:
        head = [0xFD, len(payload), 0, 0, seq, sysid, compid, msg_id & 0xFF, msg_id >> 8, 0]
        frame = bytes(head) + payload
    crc = dialect.x25crc(bytearray(frame[1:]) + bytes([crc_extra])).crc
    return frame + bytes([crc & 0xFF, crc >> 8])


def _signer(timestamp: int = 1000) -> Any:
    mav = dialect.MAVLink(None, srcSystem=3, srcComponent=1)
    mav.signing.secret_key = KEY
    mav.signing.link_id = 0
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = timestamp
    return mav


def _fields(msg: Any) -> tuple[Any, ...]:
    """What a consumer can see of a message: its type, header and every field (pickled:
    a float's bits, NaN payloads included)."""
    names = dialect.mavlink_map[msg.get_msgId()].fieldnames
    values = [getattr(msg, n) for n in names]
    head = (msg.get_type(), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq())
    return head, pickle.dumps(values)


@pytest.mark.parametrize("name", sorted(FAST_MESSAGES))
def test_fields_equal_pymavlink_decode_for_every_payload_length(name: str) -> None:
    """Random payloads of every length from empty to longer than the message (MAVLink 2
    truncates trailing zeros; MAVLink 1 and a longer payload are padded or cut the same
    way by pymavlink): identical fields, header and frame bytes."""
    msg_id = IDS[name]
    size = dialect.mavlink_map[msg_id].unpacker.size
    rng = random.Random(msg_id)
    mav = dialect.MAVLink(None)
    n = 0
    for length in range(0, size + 4):
        for v1 in (False, True):
            for _ in range(3):
                payload = rng.randbytes(length)
                frame = _frame(msg_id, payload, v1=v1, seq=length, sysid=rng.randrange(1, 255))
                fast = fastframe.decode(frame, 0, len(frame))
                assert isinstance(fast, FastMessage)
                ref = mav.decode(bytearray(frame))
                assert _fields(fast) == _fields(ref)
                assert fast.get_msgbuf() == frame and not fast.get_signed()
                assert fast.to_dict() == pytest.approx(ref.to_dict(), nan_ok=True)
                enc = dialect.MAVLink(None, srcSystem=9, srcComponent=2)
                enc2 = dialect.MAVLink(None, srcSystem=9, srcComponent=2)
                assert fast.pack(enc) == ref.pack(enc2)  # written again by pymavlink
                n += 1
    assert n == (size + 4) * 6


@pytest.mark.parametrize("name", sorted(FAST_MESSAGES))
def test_signed_frames_decode_to_the_same_fields(name: str) -> None:
    cls = dialect.mavlink_map[IDS[name]]
    rng = random.Random(7)
    values = [rng.randrange(0, 100) if t != "float" else rng.uniform(-5, 5) for t in cls.fieldtypes]
    frame = bytes(cls(*values).pack(_signer()))
    assert frame[2] == 1  # signed
    fast = fastframe.decode(frame, 0, len(frame))
    assert isinstance(fast, FastMessage) and fast.get_signed()
    assert _fields(fast) == _fields(dialect.MAVLink(None).decode(bytearray(frame)))


def test_frame_crc_is_pymavlinks_pure_python_x25() -> None:
    rng = random.Random(3)
    for i in range(300):
        frame = rng.randbytes(rng.randrange(3, 300))
        extra = i % 256
        ref = dialect._x25crc_slow(bytearray(frame[1:]) + bytes([extra])).crc
        assert frame_crc(frame, 0, len(frame), extra) == ref
        assert frame_crc(bytearray(frame), 0, len(frame), extra) == ref
    with pytest.raises(ValueError):
        frame_crc(b"\xfd\x00", 0, 5, 1)


def test_what_it_does_not_take_is_left_to_pymavlink() -> None:
    att = IDS["ATTITUDE"]
    good = _frame(att, bytes(range(28)))
    bad = good[:-1] + bytes([good[-1] ^ 0xFF])
    assert fastframe.decode(bad, 0, len(bad)) is BAD_CRC == "bad_crc"
    hb = bytes(dialect.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(dialect.MAVLink(None)))
    assert fastframe.decode(hb, 0, len(hb)) is None  # not a high-rate message
    assert fastframe.decode(good, 0, len(good) - 1) is None  # length disagrees with header
    assert fastframe.decode(good, 5, len(good)) is None  # out of the buffer
    # within a larger buffer (a tlog, a stream): decoded in place
    buf = b"\x00" * 5 + good + b"\x01"
    fast = fastframe.decode(buf, 5, len(good))
    assert isinstance(fast, FastMessage) and fast.get_msgbuf() == good
    # any other buffer (a memoryview of a receive buffer, an mmap of a log) is copied
    view = fastframe.decode(memoryview(buf), 5, len(good))  # type: ignore[arg-type]
    assert isinstance(view, FastMessage) and _fields(view) == _fields(fast)
    with pytest.raises(TypeError):
        fastframe.decode("not bytes", 0, 12)  # type: ignore[arg-type]


def _sample(msg: Any, t_s: float = 2.0, scale: RawImuScale | None = None) -> Any:
    return msg.sample(t_s, scale if scale is not None else RawImuScale())


def _decoded(msg: Any, sysid: int = 4) -> Any:
    mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=1)
    frame = bytes(msg.pack(mav))
    return fastframe.decode(frame, 0, len(frame))


def test_samples_in_si_units() -> None:
    """Each message's sample: convert.py's units (mG, mrad/s, the vehicle's RAW_IMU scale)
    against the formulas written out here (float32 fields as pymavlink reads them)."""
    d = dialect
    f32 = lambda x: float(__import__("numpy").float32(x))  # noqa: E731
    att = _sample(_decoded(d.MAVLink_attitude_message(1500, 0.1, -0.2, 0.3, 1, 2, 3)))
    assert att == AttitudeSample(4, 2.0, (f32(0.1), f32(-0.2), f32(0.3)), (1.0, 2.0, 3.0))
    scale = RawImuScale(accel_mps2_per_lsb=0.01, gyro_radps_per_lsb=0.002)
    raw = _decoded(d.MAVLink_raw_imu_message(1_004_000, 100, -50, -1000, 10, 20, 30, 0, 0, 0))
    assert raw.t_us == 1_004_000
    assert _sample(raw, 1.004, scale) == ImuSample(
        4, 1.004, (100 * 0.01, -50 * 0.01, -1000 * 0.01), (10 * 0.002, 20 * 0.002, 30 * 0.002),
        ImuSource.RAW_IMU,
    )  # fmt: skip
    sc = _decoded(d.MAVLink_scaled_imu_message(1008, 0, 0, -1000, 0, 0, 100, 0, 0, 0))
    assert sc.t_us == 1_008_000
    assert _sample(sc) == ImuSample(
        4, 2.0, (0.0, 0.0, -1000 * MG_TO_MPS2), (0.0, 0.0, 100 * MRAD_TO_RAD), ImuSource.SCALED_IMU
    )
    for inst, cls in ((2, d.MAVLink_scaled_imu2_message), (3, d.MAVLink_scaled_imu3_message)):
        s2 = _sample(_decoded(cls(1008, 5, 0, -1000, 0, 0, 100, 0, 0, 0)))
        assert s2 == SecondaryImuSample(4, 2.0, inst, (5 * MG_TO_MPS2, 0.0, -1000 * MG_TO_MPS2))
    hr = _decoded(d.MAVLink_highres_imu_message(7, 0.5, 0, -9.75, 0.25, 0, 0, *[0.0] * 7, 0))
    assert hr.t_us == 7
    assert _sample(hr) == ImuSample(
        4, 2.0, (0.5, 0.0, -9.75), (0.25, 0.0, 0.0), ImuSource.HIGHRES_IMU
    )
    nan = float("nan")
    lp = _sample(_decoded(d.MAVLink_local_position_ned_message(1010, 1, 2, 3, 0.5, nan, -0.5)))
    assert isinstance(lp, VelocitySample) and lp.position_ned_m == (1.0, 2.0, 3.0)
    assert lp.v_ned_mps[0] == 0.5 and math.isnan(lp.v_ned_mps[1])  # a dropout is data
    st = _decoded(
        d.MAVLink_sim_state_message(*[0.0] * 4, 0.5, 0.25, 1.5, *[0.0] * 11, 1, 2, 3, 0, 0)
    )
    assert st.t_us == 0
    assert _sample(st) == TruthSample(4, 2.0, (0.5, 0.25, 1.5), (1.0, 2.0, 3.0))


@pytest.mark.parametrize(
    ("msg", "reason"),
    [
        (dialect.MAVLink_attitude_message(1, float("nan"), 0, 0, 0, 0, 0), "nan_field"),
        (dialect.MAVLink_attitude_message(1, 0, 0, 0, 0, float("inf"), 0), "nan_field"),
        (dialect.MAVLink_highres_imu_message(1, 0, float("nan"), 0, *[0.0] * 10, 0), "nan_field"),
        (
            dialect.MAVLink_highres_imu_message(1, 0, 0, -9.8, 0, 0, 71.0, *[0.0] * 7, 0),
            "implausible",
        ),
        (dialect.MAVLink_highres_imu_message(1, 2001.0, 0, 0, *[0.0] * 10, 0), "implausible"),
        (dialect.MAVLink_highres_imu_message(1, *[0.0] * 13, 0), "imu_absent"),
        (dialect.MAVLink_raw_imu_message(1, 0, 0, 0, 0, 0, 0, 0, 0, 0), "imu_absent"),
        (dialect.MAVLink_scaled_imu2_message(1, 0, 0, 0, 0, 0, 0, 0, 0, 0), "imu_absent"),
        (dialect.MAVLink_sim_state_message(*[0.0] * 18, float("nan"), 0, 0, 0, 0), "nan_field"),
    ],
)
def test_unusable_messages_raise_the_counters_reason(msg: Any, reason: str) -> None:
    with pytest.raises(ConversionError) as err:
        _sample(_decoded(msg))
    assert err.value.reason == reason


def test_raw_imu_beyond_range_with_the_vehicles_scale() -> None:
    """RAW_IMU counts are scaled per vehicle: 30000 counts at 1 mG is 294 m/s² (usable), at
    0.1 m/s² per count 3000 m/s² (beyond any IMU)."""
    msg = _decoded(dialect.MAVLink_raw_imu_message(1, 0, 0, 30000, 0, 0, 0, 0, 0, 0))
    assert _sample(msg).f_body_mps2[2] == pytest.approx(30000 * MG_TO_MPS2, rel=1e-15)
    with pytest.raises(ConversionError) as err:
        _sample(msg, scale=RawImuScale(accel_mps2_per_lsb=0.1))
    assert err.value.reason == "implausible"


def test_fields_are_writable_like_pymavlinks() -> None:
    """A test kit injects faults into decoded messages (glmav_testkit.fault_replay)."""
    lp = _decoded(dialect.MAVLink_local_position_ned_message(1010, 1, 2, 3, 0.5, 0.25, 0.0))
    lp.vz = 1.5
    assert _sample(lp).v_ned_mps == (0.5, 0.25, 1.5)


def _run(datagrams: list[bytes], *, datagram: bool, reference: bool, mp: Any, **kw: Any) -> Any:
    if reference:
        mp.setattr(fastframe, "decode", lambda data, start, length, header_only=None: None)
        kw.pop("fields_of", None)  # the reference decodes every frame with pymavlink
    try:
        counters = FrameCounters()
        dec = FrameDecoder(datagram=datagram, counters=counters, **kw)
        msgs = [m for d in datagrams for m in dec.feed(d)]
    finally:
        mp.undo()
    compiled = sum(isinstance(m, FastMessage) for m in msgs)
    # the reference decodes nothing itself; the compiled path all but the low-rate messages
    assert compiled == 0 if reference else compiled > 0.9 * len(msgs)
    # header-only: every message the ingest reads no field of (the stream's SERVO_OUTPUT_RAW
    # is read: a control sample), and none other
    heads = {m.get_type() for m in msgs if isinstance(m, fastframe.HeaderOnly)}
    fields_of = kw.get("fields_of")
    if fields_of is None or reference:
        assert not heads
    else:
        every = {m.get_type() for m in msgs} - FAST_MESSAGES
        assert heads == every - fields_of and "GLOBAL_POSITION_INT" in heads
    return [_fields(m) for m in msgs], counters.as_dict()


@pytest.mark.parametrize("header_only", [False, True])
@pytest.mark.parametrize("datagram", [True, False])
def test_verdicts_and_counters_equal_a_pymavlink_reference(
    datagram: bool, header_only: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The simulator's stream (every message kind a vehicle sends, MAVLink 2) with every
    damaged case of the fuzz benchmark interleaved (bit flips, truncation, corrupt lengths,
    garbage, MAVLink 1, duplicates...): the same messages and the same counters by reason
    as the framing that gives every frame to pymavlink's decode. As UDP datagrams and as a
    TCP byte stream cut at random places. ``header_only``: the framing the service uses
    (``fields_of`` its ingest's): the messages it reads no field of come back header-only,
    with the same verdicts, and the same fields when asked for after all."""
    stream = sitl_stream("cruise", 3.0, seed=2)
    maker = CaseMaker(stream.frames, b"", seed=5, vehicle_safe=False)
    kinds = [k for k in KINDS if k != "real_corrupt"]
    rng = random.Random(9)
    datagrams: list[bytes] = []
    for f in stream.frames:
        datagrams.append(f)
        if rng.random() < 0.3:
            datagrams.append(maker.make(rng.choice(kinds))[1])
    if not datagram:
        blob = b"".join(datagrams)
        cuts = sorted(rng.sample(range(1, len(blob)), len(datagrams) // 3))
        datagrams = [blob[a:b] for a, b in zip([0, *cuts], [*cuts, len(blob)], strict=True)]
    kw = {"fields_of": Ingest(IngestConfig()).fields_of} if header_only else {}
    seen, counts = _run(datagrams, datagram=datagram, reference=False, mp=monkeypatch, **kw)
    ref_seen, ref_counts = _run(datagrams, datagram=datagram, reference=True, mp=monkeypatch)
    assert counts == ref_counts
    assert counts["bad_crc"] > 20 and counts["frames_ok"] > 1000  # the damage reached it
    assert seen == ref_seen


def test_signing_checks_are_the_frameworks_as_before(monkeypatch: pytest.MonkeyPatch) -> None:
    """With a key: a signed high-rate frame passes; unsigned, forged and replayed ones are
    refused with today's reasons, exactly as the pymavlink reference counts them."""
    att = dialect.MAVLink_attitude_message(5, 0.1, 0, 0, 0, 0, 0)
    signed = bytes(att.pack(_signer(1000)))
    later = bytes(dialect.MAVLink_attitude_message(6, 0, 0, 0, 0, 0, 0).pack(_signer(2000)))
    forged = signed[:-1] + bytes([signed[-1] ^ 1])
    unsigned = bytes(att.pack(dialect.MAVLink(None, srcSystem=3, srcComponent=1)))
    datagrams = [signed, signed, forged, unsigned, later]
    seen, counts = _run(datagrams, datagram=True, reference=False, mp=monkeypatch, signing_key=KEY)
    ref_seen, ref_counts = _run(
        datagrams, datagram=True, reference=True, mp=monkeypatch, signing_key=KEY
    )
    assert counts == ref_counts == {
        "bad_signature": 1, "frames_ok": 2, "replayed": 1, "unsigned": 1
    }  # fmt: skip
    assert seen == ref_seen and len(seen) == 2
    # without a key, a signed frame is decoded (its signature is not ours to judge)
    (msg,) = FrameDecoder(datagram=True).feed(signed)
    assert isinstance(msg, FastMessage) and msg.get_signed() and msg.time_boot_ms == 5


def test_tlog_records_decode_in_place() -> None:
    """iter_tlog hands the compiled decoder its frames inside the log image."""
    mav = dialect.MAVLink(None, srcSystem=2, srcComponent=1)
    msgs = [dialect.MAVLink_attitude_message(t, 0.1, 0, 0, 0, 0, 0) for t in (10, 20)]
    msgs.append(dialect.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))
    data = b"".join((1000 + i).to_bytes(8, "big") + bytes(m.pack(mav)) for i, m in enumerate(msgs))
    recs = list(iter_tlog(data))
    assert [(r.t_host_us, r.msg.get_type()) for r in recs] == [
        (1000, "ATTITUDE"), (1001, "ATTITUDE"), (1002, "HEARTBEAT")
    ]  # fmt: skip
    assert isinstance(recs[1].msg, FastMessage) and recs[1].msg.time_boot_ms == 20


def test_ingest_refuses_a_high_rate_message_not_decoded_here() -> None:
    """A caller that decodes ATTITUDE with pymavlink itself would get no samples: a bug
    said loudly (a TypeError naming the decoders to use), never a silent drop."""
    ing = Ingest(IngestConfig())
    (heartbeat,) = FrameDecoder(datagram=True).feed(
        bytes(dialect.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(dialect.MAVLink(None)))
    )
    ing.on_message(heartbeat, 0.0)
    att = dialect.MAVLink_attitude_message(5, 0, 0, 0, 0, 0, 0)
    att.pack(dialect.MAVLink(None))
    with pytest.raises(TypeError, match="FrameDecoder"):
        ing.on_message(att, 0.0)


def test_header_only_frames_are_checked_and_decoded_on_demand() -> None:
    """A message flagged header-only: its CRC checked like a high-rate one's, its header
    read, its fields pymavlink's when asked for; not flagged, or its payload longer than
    the message's longest form, or an id above 255: left to pymavlink (None)."""
    flags = fastframe.header_only_ids({"SERVO_OUTPUT_RAW", "VFR_HUD", "ATTITUDE"})
    assert len(flags) == 256 and sum(flags) == 2  # ATTITUDE is decoded in full anyway
    servo = dialect.MAVLink_servo_output_raw_message(123456, 0, *range(1000, 1008))
    for mav1 in (False, True):
        mav = dialect.MAVLink(None, srcSystem=7, srcComponent=3)
        frame = bytes(servo.pack(mav, force_mavlink1=mav1))
        msg = fastframe.decode(frame, 0, len(frame), flags)
        assert isinstance(msg, fastframe.HeaderOnly)
        assert (msg.get_type(), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_msgId()) == (
            "SERVO_OUTPUT_RAW", 7, 3, 36,
        )  # fmt: skip
        assert msg.get_msgbuf() == frame
        ref = dialect.MAVLink(None).decode(bytearray(frame))
        assert _fields(msg) == _fields(ref) and msg.servo8_raw == 1007
        assert msg.to_dict() == ref.to_dict()
        assert fastframe.decode(frame, 0, len(frame)) is None  # not flagged: pymavlink's
        bad = frame[:-1] + bytes([frame[-1] ^ 0x55])
        assert fastframe.decode(bad, 0, len(bad), flags) == BAD_CRC
    # a MAVLink 2 payload longer than SERVO_OUTPUT_RAW's longest (37 bytes): pymavlink's
    frame = bytes(servo.pack(dialect.MAVLink(None)))
    payload = frame[10:-2].ljust(40, b"\x01")  # 3 bytes beyond the longest form
    long = bytes([frame[0], len(payload)]) + frame[2:10] + payload
    long += frame_crc(long, 1, len(long), 222).to_bytes(2, "little")
    assert fastframe.decode(long, 0, len(long), flags) is None
    # an id above 255 (MAVLink 2 only): pymavlink's
    wide = dialect.MAVLink_adap_tuning_message(1, *[0.5] * 12)  # id 11010
    f2 = bytes(wide.pack(dialect.MAVLink(None)))
    assert fastframe.decode(f2, 0, len(f2), fastframe.header_only_ids({"ADAP_TUNING"})) is None


def test_the_service_ignores_header_only_messages_as_before() -> None:
    """The service's framing skips pymavlink's decode of what its ingest does not read;
    those messages are counted as ignored exactly as when they were decoded."""
    from glmav_observer.app import Service
    from glmav_observer.config import ServiceConfig

    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = bytes(dialect.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mav))
    vfr = bytes(dialect.MAVLink_vfr_hud_message(1, 2, 3, 4, 5, 6).pack(mav))
    service = Service(ServiceConfig(), [])
    for d in (hb, vfr, vfr):
        service.feed_bytes("udp", d, 0.0)
    assert service.ingest.counters["ignored_messages"] == 2
    assert service.decoders["udp"].counters.as_dict() == {"frames_ok": 3}
