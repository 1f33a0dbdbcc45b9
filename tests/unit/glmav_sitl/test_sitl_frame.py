"""The compiled MAVLink 2 framing of the simulator's streams gives pymavlink's bytes."""

from __future__ import annotations

import io
import itertools
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.mavlink.frame import frame_v2
from glmav_sitl.runner import run

#: the messages framed by frame_v2 (vehicle.MavlinkVehicle._send_fields), with a random
#: value for each field (in declared order = wire order for these)
STREAMS: list[Any] = [
    mavlink2.MAVLink_raw_imu_message,
    mavlink2.MAVLink_scaled_imu_message,
    mavlink2.MAVLink_highres_imu_message,
    mavlink2.MAVLink_attitude_message,
    mavlink2.MAVLink_local_position_ned_message,
    mavlink2.MAVLink_sim_state_message,
]
_INT = {"Q": (0, 2**63), "I": (0, 2**32), "i": (-(2**31), 2**31), "h": (-(2**15), 2**15)}
_INT |= {"H": (0, 2**16), "B": (0, 2**8)}


def _random_fields(cls: Any, rng: np.random.Generator, zero_tail: bool) -> tuple[Any, ...]:
    fmt = bytes(cls.native_format).decode()[1:]
    assert cls.fieldnames == cls.ordered_fieldnames  # what _send_fields relies on
    out: list[Any] = []
    for i, c in enumerate(fmt):
        if zero_tail and i >= len(fmt) // 2:
            out.append(0.0 if c == "f" else 0)
        elif c == "f":
            out.append(float(rng.normal(0.0, 100.0)))
        else:
            lo, hi = _INT[c]
            out.append(int(rng.integers(lo, hi)))
    return tuple(out)


def _pymavlink_bytes(msg: Any, seq: int, sysid: int, compid: int) -> bytes:
    buf = io.BytesIO()
    mav = mavlink2.MAVLink(buf, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    mav.send(msg)
    return buf.getvalue()


@pytest.mark.parametrize("cls", STREAMS, ids=lambda c: c.msgname)
def test_frame_v2_equals_pymavlink(cls: Any) -> None:
    """Random fields, sequence numbers, system and component ids; half the cases with
    a zero tail, which MAVLink 2 truncates (pymavlink and frame_v2 alike)."""
    rng = np.random.default_rng(cls.id)
    for k in range(200):
        fields = _random_fields(cls, rng, zero_tail=k % 2 == 1)
        seq, sysid, compid = (int(v) for v in rng.integers(0, 256, 3))
        want = _pymavlink_bytes(cls(*fields), seq, sysid, compid)
        got = frame_v2(cls.unpacker.pack(*fields), cls.id, cls.crc_extra, seq, sysid, compid)
        assert got == want
    # all-zero payload: one byte is kept
    zeros = tuple(0.0 if c == "f" else 0 for c in bytes(cls.native_format).decode()[1:])
    got = frame_v2(cls.unpacker.pack(*zeros), cls.id, cls.crc_extra, 0, 1, 1)
    assert got == _pymavlink_bytes(cls(*zeros), 0, 1, 1)
    assert got[1] == 1


def test_frame_v2_rejects_what_does_not_fit() -> None:
    with pytest.raises(ValueError, match="at most 255"):
        frame_v2(b"\x01" * 256, 30, 39, 0, 1, 1)
    with pytest.raises(ValueError, match="24 bits"):
        frame_v2(b"\x01", 1 << 24, 39, 0, 1, 1)


def test_a_flight_tlog_decodes_with_one_sequence(tmp_path: Path) -> None:
    """2 s of the cruise flight to a tlog: every packet (streams framed by frame_v2,
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
