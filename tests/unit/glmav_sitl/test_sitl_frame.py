"""The compiled packing and framing of the simulator's streams gives pymavlink's bytes."""

from __future__ import annotations

import io
import itertools
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.mavlink.frame import StreamWriter
from glmav_sitl.mavlink.frame import i16 as compiled_i16
from glmav_sitl.runner import run

KEY = bytes(range(32))


class _Link:
    """What the writer writes to (a Link's write)."""

    def __init__(self) -> None:
        self.out: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.out.append(bytes(buf))


def _encoder(sysid: int, compid: int, seq: int, signed: bool) -> Any:
    mav = mavlink2.MAVLink(io.BytesIO(), srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    if signed:
        mav.signing.secret_key = KEY
        mav.signing.link_id = 3
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = 123_456_789
    return mav


def i16(x: float) -> int:
    """The quantiser as the Python code had it (the oracle of frame.i16)."""
    if not math.isfinite(x):
        return 0
    v = round(x)
    return max(-32767, min(32767, v))


def _f(rng: np.random.Generator, n: int, zero: bool) -> list[float]:
    return [0.0] * n if zero else [float(v) for v in rng.normal(0.0, 30.0, n)]


def _cases(rng: np.random.Generator, zero: bool) -> list[tuple[str, tuple[Any, ...], Any]]:
    """(writer method, its arguments after the stamp, pymavlink's message of them)."""
    t_us = 0 if zero else int(rng.integers(0, 2**40))
    t_ms = 0 if zero else int(rng.integers(0, 2**32))
    g, a = _f(rng, 3, zero), _f(rng, 3, zero)
    ka, kg = 1.0 / 9.80665e-3, 1.0 / 1e-3
    mg = 1000.0 / 9.80665
    s = _f(rng, 21, zero)
    lat_i, lon_i = (0, 0) if zero else (int(v) for v in rng.integers(-(2**31), 2**31, 2))
    return [
        (
            "highres_imu",
            (t_us, g, a),
            mavlink2.MAVLink_highres_imu_message(t_us, *a, *g, *[0.0] * 7, 0x3F),
        ),
        (
            "raw_imu",
            (t_us, g, a, ka, kg),
            mavlink2.MAVLink_raw_imu_message(
                t_us, *(i16(v * ka) for v in a), *(i16(v * kg) for v in g), 0, 0, 0
            ),
        ),
        (
            "scaled_imu",
            (t_ms, g, a),
            mavlink2.MAVLink_scaled_imu_message(
                t_ms, *(i16(v * mg) for v in a), *(i16(v * 1000.0) for v in g), 0, 0, 0
            ),
        ),
        ("attitude", (t_ms, g, a), mavlink2.MAVLink_attitude_message(t_ms, *g, *a)),
        (
            "local_position_ned",
            (t_ms, g, a),
            mavlink2.MAVLink_local_position_ned_message(t_ms, *g, *a),
        ),
        ("sim_state", (s, lat_i, lon_i), mavlink2.MAVLink_sim_state_message(*s, lat_i, lon_i)),
    ]


@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
def test_stream_writer_equals_pymavlink(signed: bool) -> None:
    """Random values, sequence numbers, system and component ids: the writer's packets,
    to a link and to the tlog (8-byte big-endian stamp first), are pymavlink's bytes
    for the same messages; one case in four is all zeros, which MAVLink 2 truncates; with signing, the signature and the signing clock match too."""
    rng = np.random.default_rng(11)
    for k in range(150):
        sysid, compid, seq = (int(v) for v in rng.integers(0, 256, 3))
        stamp = int(rng.integers(0, 2**62))
        for method, args, msg in _cases(rng, zero=k % 4 == 0):
            ref = _encoder(sysid, compid, seq, signed)
            ref.send(msg)
            want = ref.file.getvalue()
            mav = _encoder(sysid, compid, seq, signed)
            link, tlog = _Link(), io.BytesIO()
            getattr(StreamWriter(mav, [link], tlog), method)(stamp, *args)
            assert link.out == [want], method
            assert tlog.getvalue() == struct.pack(">Q", stamp) + want
            assert mav.seq == (seq + 1) % 256
            assert mav.signing.timestamp == ref.signing.timestamp
            if k % 4 == 0:  # the zero tail is cut (HIGHRES_IMU keeps fields_updated)
                assert want[1] == (61 if method == "highres_imu" else 1)


def test_the_quantiser_rounds_half_to_even_and_saturates() -> None:
    rng = np.random.default_rng(3)
    xs = [float(v) for v in rng.normal(0.0, 2e4, 2000)]
    xs += [0.5, 1.5, 2.5, -0.5, -2.5, 32766.5, -32767.5, 4e4, math.inf, -math.inf, 1e300]
    for x in xs:
        assert compiled_i16(x) == i16(x)
    assert compiled_i16(math.nan) == 0


def test_sim_state_wants_its_21_floats() -> None:
    w = StreamWriter(_encoder(1, 1, 0, False), [], None)
    with pytest.raises(ValueError, match="21 floats"):
        w.sim_state(0, [0.0] * 20, 0, 0)


def test_a_flight_tlog_decodes_with_one_sequence(tmp_path: Path) -> None:
    """2 s of the cruise flight to a tlog: every packet (streams by StreamWriter,
    heartbeat and servo outputs by pymavlink) passes pymavlink's CRC check, and the
    sequence numbers run on by one across both paths."""
    tlog = tmp_path / "f.tlog"
    summary = run("cruise", [], duration_s=2.0, speed="max", seed=1, tlog_path=tlog)
    data = tlog.read_bytes()
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = False
    seqs: list[int] = []
    names: set[str] = set()
    i = 0
    while i < len(data):
        i += 8  # the tlog's timestamp
        plen = data[i + 1]
        end = i + 10 + plen + 2
        msg = parser.decode(bytearray(data[i:end]))  # raises on a bad CRC
        seqs.append(msg.get_seq())
        names.add(msg.get_type())
        i = end
    assert i == len(data)
    assert {"ATTITUDE", "HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SIM_STATE"} <= names
    assert {"HEARTBEAT", "SERVO_OUTPUT_RAW", "LOCAL_POSITION_NED"} <= names
    assert all((b - a) % 256 == 1 for a, b in itertools.pairwise(seqs))
    assert len(seqs) == sum(summary.messages_sent.values())
    assert struct.unpack(">Q", data[:8])[0] > 0
