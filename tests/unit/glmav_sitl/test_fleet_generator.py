"""The fleet generator's log reading and system-id rewriting (no sockets)."""

from __future__ import annotations

import itertools
import random
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav2

from glmav_sitl.fleet import (
    FleetError,
    LogArrays,
    crc_delta,
    load_tlog,
    rewrite,
    start_offsets_s,
    x25_crc,
)

KEY = bytes(range(32))


def _attitude(i: int) -> tuple[int, float, float, float, float, float, float]:
    return (1000 * i, 0.1 * i, -0.2, 0.3, 0.01, 0.02, 0.03)


def _write_tlog(path: Path, frames: list[tuple[float, bytes]]) -> None:
    with path.open("wb") as f:
        for t_s, frame in frames:
            f.write(struct.pack(">Q", int(1_700_000_000e6 + t_s * 1e6)) + frame)


def _decode(frame: bytes) -> object:
    m = mav2.MAVLink(None)
    return m.decode(bytearray(frame))


def test_rewritten_frames_decode_with_the_new_system_id(tmp_path: Path) -> None:
    v2 = mav2.MAVLink(None, srcSystem=7, srcComponent=1)
    v1 = mav1.MAVLink(None, srcSystem=7, srcComponent=1)
    gcs = mav2.MAVLink(None, srcSystem=255, srcComponent=190)
    frames: list[tuple[float, bytes]] = []
    for i in range(20):
        frames.append((0.01 * i, v2.attitude_encode(*_attitude(i)).pack(v2)))
        frames.append((0.01 * i + 0.001, v1.attitude_encode(*_attitude(i)).pack(v1)))
    frames.append((0.5, gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs)))
    bad = bytearray(frames[0][1])
    bad[-1] ^= 0xFF  # a corrupted CRC in the log
    frames.append((0.6, bytes(bad)))
    _write_tlog(tmp_path / "a.tlog", frames)

    log = load_tlog(tmp_path / "a.tlog")
    assert log.sysid == 7
    assert len(log.frames) == 40
    assert log.counters["other_system"] == 1  # the ground station's heartbeat
    assert log.counters["bad_crc"] == 1
    assert log.frames[0].t_s == 0.0 and log.frames[-1].t_s == pytest.approx(0.191, abs=1e-6)
    for k, f in enumerate(log.frames):
        for sysid in (1, 42, 254):
            msg = _decode(rewrite(f, sysid))
            assert msg.get_srcSystem() == sysid  # type: ignore[attr-defined]
            assert msg.get_type() == "ATTITUDE"  # type: ignore[attr-defined]
            assert msg.time_boot_ms == 1000 * (k // 2)  # type: ignore[attr-defined]
    # the generator rewrites runs of frames at once (numpy): byte for byte the same, for
    # any run, including the log's own id (a zero CRC change) and runs that mix versions
    arrays = LogArrays(log)
    for sysid in (1, 7, 42, 254):
        for a, b in ((0, 40), (3, 4), (5, 33), (39, 40)):
            assert arrays.rewrite(a, b, sysid) == [rewrite(f, sysid) for f in log.frames[a:b]]


def test_signed_frames_are_sent_unsigned_and_counted(tmp_path: Path) -> None:
    v2 = mav2.MAVLink(None, srcSystem=3, srcComponent=1)
    v2.signing.secret_key = KEY
    v2.signing.sign_outgoing = True
    v2.signing.link_id = 0
    v2.signing.timestamp = 1
    frames = [(0.01 * i, v2.attitude_encode(*_attitude(i)).pack(v2)) for i in range(5)]
    assert all(f[2] & 0x01 for _, f in frames)  # signed
    _write_tlog(tmp_path / "s.tlog", frames)
    log = load_tlog(tmp_path / "s.tlog")
    assert log.counters["signatures_stripped"] == 5
    for f in log.frames:
        out = rewrite(f, 9)
        assert out[2] & 0x01 == 0 and len(out) == len(frames[0][1]) - 13
        assert _decode(out).get_srcSystem() == 9  # type: ignore[attr-defined]


def test_crc_delta_equals_a_full_recomputation() -> None:
    rng = random.Random(1)
    for _ in range(200):
        body = bytearray(rng.randrange(256) for _ in range(rng.randrange(1, 60)))
        pos = rng.randrange(len(body))
        new = rng.randrange(256)
        changed = bytearray(body)
        changed[pos] = new
        want = x25_crc(changed)
        got = x25_crc(body) ^ crc_delta(body[pos] ^ new, len(body) - pos - 1)
        assert got == want


def test_a_file_without_frames_is_refused_with_its_name(tmp_path: Path) -> None:
    p = tmp_path / "empty.tlog"
    p.write_bytes(b"not a tlog at all" * 10)
    with pytest.raises(FleetError, match=r"empty\.tlog: no vehicle frames"):
        load_tlog(p)
    with pytest.raises(FleetError, match=r"missing\.tlog: cannot read"):
        load_tlog(tmp_path / "missing.tlog")


def _min_phase_gap(offsets_s: list[float], period_s: float) -> float:
    """The smallest distance between two vehicles' phases of ``period_s``, in periods."""
    ph = sorted((o % period_s) / period_s for o in offsets_s)
    return min(b - a for a, b in zip(ph, [*ph[1:], ph[0] + 1.0], strict=True))


@pytest.mark.parametrize("vehicles", [2, 5, 10, 25, 35, 50, 100])
def test_vehicles_send_at_their_own_phase_of_the_logs_periods(vehicles: int) -> None:
    """K vehicles with their own clocks do not send in lock-step: each vehicle's frames fall
    at its own phase of the design log's periods (the simulator's 2 ms tick, HIGHRES_IMU's
    4 ms, ATTITUDE's 10 ms), for the fleet benchmark's vehicle counts."""
    offsets = start_offsets_s(vehicles, 1.0)
    assert offsets[0] == 0.0 and all(b > a for a, b in itertools.pairwise(offsets))
    assert offsets[-1] < 1.0  # the starts stay within the stagger
    for period_s in (0.002, 0.004, 0.010):
        # perfectly even phases would be 1/K apart; {k/φ} keeps at least a sixth of that
        # (its worst over these K and periods is 0.197/K, at K = 2 and 10 ms)
        assert _min_phase_gap(offsets, period_s) >= 1.0 / (6 * vehicles)
        # the start alone, k/K s, is a whole number of 2 ms ticks for each of these K
        # but 35: every vehicle at one phase, each tick's frames sent in one burst
        lockstep = [k / vehicles for k in range(vehicles)]
        if vehicles != 35:
            assert _min_phase_gap(lockstep, period_s) < 1e-6
