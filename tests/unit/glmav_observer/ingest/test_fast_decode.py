"""The fast decode path (framing.fast_decode) pinned to pymavlink's ``decode``: the same
message objects (class, attributes, values bit for bit, attribute order), and every
frame it does not take is left to pymavlink with the same verdict."""

from __future__ import annotations

import pickle
import random
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.ingest.convert import SAMPLE_MESSAGES
from glmav_observer.ingest.framing import (
    FAST_DECODE,
    FAST_DECODE_MESSAGES,
    FrameDecoder,
    fast_decode,
    frame_crc,
)
from glmav_observer.ingest.pipeline import IMU_MESSAGE_IDS, Ingest, IngestConfig
from glmav_testkit.fuzzgen import KINDS, CaseMaker, sitl_stream

#: the messages ingest/pipeline.py reads (its samples, and the two it handles itself): each
#: must have its fast entry. From the ingest's own set: a hand list here had gone stale
#: (SERVO_OUTPUT_RAW was added to the ingest and not to it)
CONSUMED = SAMPLE_MESSAGES | {"HEARTBEAT", "SYSTEM_TIME"}


def _frame(msg_id: int, payload: bytes, *, seq: int = 7, sysid: int = 3, compid: int = 1) -> bytes:
    """An unsigned MAVLink 2 frame, checksummed with the message's CRC extra."""
    crc_extra = dialect.mavlink_map[msg_id].crc_extra
    body = bytes([len(payload), 0, 0, seq, sysid, compid, msg_id & 0xFF, (msg_id >> 8) & 0xFF])
    body += bytes([msg_id >> 16]) + payload
    frame = b"\xfd" + body
    crc = frame_crc(frame, 0, len(frame), crc_extra)
    return frame + bytes([crc & 0xFF, crc >> 8])


def _state(msg: Any) -> tuple[Any, ...]:
    """Everything a consumer can see of a message, NaN payloads included (pickle keeps
    a float's bits; ``==`` would call two NaNs different)."""
    d = dict(msg.__dict__)
    header = d.pop("_header").__dict__
    return type(msg), list(d), pickle.dumps(list(d.values())), header


def test_every_consumed_message_has_a_fast_entry() -> None:
    assert set(CONSUMED) <= FAST_DECODE_MESSAGES
    names = {spec.msg_class.msgname for spec in FAST_DECODE.values()}
    assert set(CONSUMED) <= names


@pytest.mark.parametrize("msg_id", sorted(FAST_DECODE))
def test_fast_decode_equals_pymavlink_decode(msg_id: int) -> None:
    """Random payloads of every length from empty to longer than the message (MAVLink 2
    truncates trailing zeros; a longer payload is cut): identical objects."""
    rng = random.Random(msg_id)
    size = FAST_DECODE[msg_id].payload_len
    mav = dialect.MAVLink(None)
    for length in range(0, size + 4):
        for _ in range(4):
            payload = bytes(rng.getrandbits(8) for _ in range(length))
            frame = _frame(msg_id, payload, seq=length)
            fast = fast_decode(bytearray(frame))
            assert fast is not None
            ref = mav.decode(bytearray(frame))
            assert _state(fast) == _state(ref)
            assert fast.to_dict() == pytest.approx(ref.to_dict(), nan_ok=True)
            assert fast.get_msgbuf() == bytearray(frame)


def test_frames_it_does_not_take_go_to_pymavlink_with_the_same_verdict() -> None:
    att = dialect.MAVLINK_MSG_ID_ATTITUDE
    good = _frame(att, bytes(range(28)))
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    assert fast_decode(bad_crc) is None
    mav = dialect.MAVLink(None, srcSystem=3, srcComponent=1)
    v1 = bytearray(dialect.MAVLink_attitude_message(1, 0, 0, 0, 0, 0, 0).pack(mav, True))
    assert fast_decode(v1) is None  # MAVLink 1: pymavlink
    statustext = bytearray(dialect.MAVLink_statustext_message(4, b"hi").pack(mav))
    assert fast_decode(statustext) is None  # not consumed (and a string field): pymavlink
    dec = FrameDecoder(datagram=True)
    assert dec.feed(bad_crc) == []
    assert dec.counters.as_dict() == {"bad_crc": 1}
    (msg,) = dec.feed(v1)
    assert msg.get_type() == "ATTITUDE" and msg.time_boot_ms == 1
    (msg,) = dec.feed(good)
    assert msg.get_type() == "ATTITUDE" and msg.get_srcSystem() == 3
    assert dec.counters.as_dict() == {"bad_crc": 1, "frames_ok": 2}


def test_signed_frames_are_not_taken() -> None:
    key = bytes(range(32))
    mav = dialect.MAVLink(None, srcSystem=3, srcComponent=1)
    mav.signing.secret_key = key
    mav.signing.link_id = 0
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = 1000
    signed = bytearray(dialect.MAVLink_attitude_message(5, 0, 0, 0, 0, 0, 0).pack(mav))
    assert fast_decode(signed) is None
    dec = FrameDecoder(datagram=True, signing_key=key)
    (msg,) = dec.feed(signed)
    assert msg.time_boot_ms == 5
    unsigned = _frame(dialect.MAVLINK_MSG_ID_ATTITUDE, bytes(28))
    assert dec.feed(unsigned) == []  # with a key, an unsigned frame is refused as before
    assert dec.counters.as_dict() == {"frames_ok": 1, "unsigned": 1}


def test_one_frame_datagrams_as_the_loop_decides_them() -> None:
    """:meth:`FrameDecoder._feed_one` (a datagram of one fast frame: one CRC for the
    prefilter and the decoding) against :meth:`FrameDecoder.feed`'s loop alone, on the
    simulator's stream with every damaged case of the fuzz benchmark interleaved (sent
    as the vehicle): the same messages, events, counters and superseded IMU frames."""
    stream = sitl_stream("cruise", 3.0, seed=2)
    maker = CaseMaker(stream.frames, b"", seed=5, vehicle_safe=False)
    kinds = [k for k in KINDS if k != "real_corrupt"]
    rng = random.Random(9)
    datagrams: list[bytes] = []
    for f in stream.frames:
        datagrams.append(f)
        if rng.random() < 0.2:
            datagrams.append(maker.make(rng.choice(kinds))[1])

    def run(fast: bool) -> tuple[list[Any], Ingest, FrameDecoder]:
        ingest = Ingest(IngestConfig())
        dec = FrameDecoder(datagram=True)
        dec.set_prefilter(ingest.skip_superseded, IMU_MESSAGE_IDS)
        if not fast:
            dec._feed_one = lambda data, t: None  # type: ignore[method-assign]
        seen: list[Any] = []
        for i, d in enumerate(datagrams):
            for msg in dec.feed(d, i * 1e-3):
                seen.append(_state(msg))
                seen.append(repr(ingest.on_message(msg, i * 1e-3)))
        return seen, ingest, dec

    seen_fast, ingest_fast, dec_fast = run(True)
    seen_loop, ingest_loop, dec_loop = run(False)
    assert dec_fast.prefiltered == dec_loop.prefiltered > 1000  # 2 of 3 IMU streams
    assert seen_fast == seen_loop
    assert dec_fast.counters.as_dict() == dec_loop.counters.as_dict()
    assert dec_fast.counters.rejected_frames > 50  # the damage reached the decoder
    assert ingest_fast.counters == ingest_loop.counters
    assert {s: v.counters for s, v in ingest_fast.vehicles.items()} == {
        s: v.counters for s, v in ingest_loop.vehicles.items()
    }


def test_frame_crc_without_fastcrc_is_the_same(monkeypatch: pytest.MonkeyPatch) -> None:
    """pymavlink without fastcrc: its pure-Python CRC gives the same checksums."""
    rng = random.Random(3)
    frames = [rng.randbytes(rng.randrange(12, 60)) for _ in range(50)]
    with_c = [frame_crc(f, 0, len(f) - 2, i % 256) for i, f in enumerate(frames)]
    monkeypatch.setattr(dialect, "mcrf4xx", None)  # what pymavlink sets without fastcrc
    monkeypatch.setattr(dialect, "x25crc", dialect._x25crc_slow)
    assert [frame_crc(f, 0, len(f) - 2, i % 256) for i, f in enumerate(frames)] == with_c
