"""Flight logs (ingest/logfiles/): recognised by content, read into samples, GPS latency.

Data: the trimmed ArduCopter SITL dataflash log and PX4 SITL ULog of
tests/data/public-logs/ (the ``public_logs`` fixture), and synthetic signals whose delay is
known. No sockets.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from glmav_observer.frames import e_exact, euler_from_quaternion_wxyz
from glmav_observer.ingest.framing import new_dialect
from glmav_observer.ingest.logfiles import (
    LogError,
    UnsupportedLogError,
    detect_format,
    read_flight_log,
    read_streams,
)
from glmav_observer.ingest.logfiles.latency import estimate_gps_delay_s
from glmav_observer.ingest.samples import TruthSample, VelocitySample


def test_format_is_recognised_by_content_not_by_name(
    public_logs: dict[str, Path], tmp_path: Path
) -> None:
    # the names lie on purpose: the content decides
    bin_as_txt = tmp_path / "flight.txt"
    bin_as_txt.write_bytes(public_logs["dataflash"].read_bytes()[:4096])
    ulg_as_bin = tmp_path / "flight.bin"
    ulg_as_bin.write_bytes(public_logs["ulog"].read_bytes()[:4096])
    mav = new_dialect()
    frame = mav.heartbeat_encode(2, 3, 0, 0, 4).pack(mav)
    tlog = tmp_path / "flight.ulg"
    tlog.write_bytes(struct.pack(">Q", 1_700_000_000_000_000) + bytes(frame))
    text = tmp_path / "flight.tlog"
    text.write_text("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n")
    assert detect_format(bin_as_txt) == "dataflash"
    assert detect_format(ulg_as_bin) == "ulog"
    assert detect_format(tlog) == "tlog"
    assert detect_format(text) == "dataflash-text"
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert detect_format(empty) == "tlog"  # a telemetry log that recorded nothing
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"not a log at all\n")
    with pytest.raises(LogError, match=r"junk\.bin: not a log this reads"):
        detect_format(junk)


def test_dataflash_streams_rates_units_and_signs(public_logs: dict[str, Path]) -> None:
    fmt, s = read_streams(public_logs["dataflash"])
    assert fmt == "dataflash"
    assert s.vehicle == "ArduCopter V4.6.0-dev"
    rates = s.rates_hz()
    # ArduCopter logs ATT and XKF1 at 10 Hz, IMU at 25 Hz per instance, GPS at 5 Hz; the
    # fixture keeps SIM2 every 8th of 400 Hz = 50 Hz. Time stamps are µs: 1 % is generous.
    for name, hz in (("attitude", 10), ("imu", 25), ("gps", 5), ("ekf", 10), ("truth", 50)):
        assert rates[name] == pytest.approx(hz, rel=0.01), name
    assert s.sources["ekf"] == "XKF1 core 0"
    # at rest before take-off: specific force ≈ −g on the body z axis (FRD)
    assert s.f_body_mps2[0, 2] == pytest.approx(-9.81, abs=0.05)
    # GPS velocity (Spd, GCrs, VZ) against the simulator's truth at the GPS times, for the
    # whole flight: the climb reaches 1.78 m/s upwards (VZ positive down, like SIM2's VD)
    i = int(np.argmax(np.abs(s.v_gps_ned_mps[:, 2])))
    assert s.v_gps_ned_mps[i, 2] < -1.5
    truth = np.stack(
        [np.interp(s.t_gps_s, s.t_truth_s, s.v_truth_ned_mps[:, k]) for k in range(3)], axis=1
    )
    rms = np.sqrt(np.mean((s.v_gps_ned_mps - truth) ** 2, axis=0))
    # the receiver lags the truth by ~0.27 s (docs/logs.md); at ≤ 1.8 m/s and ~1 m/s²
    # that is ≤ 0.1 m/s RMS on down, and the horizontal speed is ≤ 0.03 m/s
    assert rms[2] < 0.1 and max(rms[0], rms[1]) < 0.05, rms


def test_ulog_streams_rates_params_and_dropped_samples(public_logs: dict[str, Path]) -> None:
    fmt, s = read_streams(public_logs["ulog"])
    assert fmt == "ulog"
    assert s.vehicle == "PX4 v1.15.0"  # ver_sw_release 0x010f0000
    rates = s.rates_hz()
    # README of the source data: sensor_combined 250 Hz, attitude 20 Hz, GPS 19 Hz, local
    # position 10 Hz
    assert rates["imu"] == pytest.approx(250, rel=0.01)
    assert rates["attitude"] == pytest.approx(20, rel=0.01)
    assert rates["gps"] == pytest.approx(19.2, rel=0.02)
    assert rates["ekf"] == pytest.approx(10, rel=0.01)
    assert "truth" not in rates
    assert s.params["EKF2_GPS_DELAY"] == 110.0
    # the first 9.5 s have no 3D fix (160 of 583 GPS messages); the EKF's velocity is not
    # valid for the first 10 s (98 of 313)
    assert s.dropped == {"gps_no_3d_fix": 160, "ekf_invalid": 98}


def test_euler_from_quat_gives_the_same_rotation_as_the_estimators_e() -> None:
    rng = np.random.default_rng(1)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    # the body-to-NED rotation matrix of each quaternion (Hamilton, scalar first)
    R = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )
    E = e_exact(euler_from_quaternion_wxyz(q))
    assert np.max(np.abs(E - R)) < 1e-12  # float64 round-off


def _synthetic(delay_s: float, seed: int, moving: bool = True) -> tuple[np.ndarray, ...]:
    """IMU at 100 Hz and GPS at 5 Hz of a known motion; the GPS reads v(t − delay)."""
    rng = np.random.default_rng(seed)
    t_imu = np.arange(0.0, 60.0, 0.01)
    w = 2 * math.pi * np.array([0.3, 0.5, 0.2])
    amp = np.array([1.0, 0.6, 0.4]) if moving else np.zeros(3)

    def v(t: np.ndarray) -> np.ndarray:
        return amp * np.sin(w * t[:, None])

    a = amp * w * np.cos(w * t_imu[:, None]) + np.array([0.05, -0.03, 0.02])  # + accel bias
    a += rng.normal(scale=0.05, size=a.shape)
    t_gps = np.arange(1.0, 60.0, 0.2)
    v_gps = v(t_gps - delay_s) + rng.normal(scale=0.02, size=(len(t_gps), 3))
    return t_imu, a, t_gps, v_gps


@pytest.mark.parametrize("delay_s", [0.0, 0.12, 0.25])
def test_gps_delay_estimate_finds_a_known_delay(delay_s: float) -> None:
    est = estimate_gps_delay_s(*_synthetic(delay_s, seed=int(delay_s * 100)))
    assert est is not None
    # 10 ms grid refined by a parabola; with 295 intervals of 0.02 m/s GPS noise and
    # 0.05 m/s² IMU noise the minimum is located to a few ms: 10 ms is one grid step
    assert est.delay_s == pytest.approx(delay_s, abs=0.01)


def test_gps_delay_is_not_estimated_without_motion() -> None:
    assert estimate_gps_delay_s(*_synthetic(0.2, seed=3, moving=False)) is None


def test_samples_are_sorted_by_validity_time_with_gps_shifted_by_its_delay(
    public_logs: dict[str, Path],
) -> None:
    log = read_flight_log(public_logs["ulog"], "gps")
    assert (log.gps_delay_s, log.gps_delay_source) == (0.110, "parameter EKF2_GPS_DELAY")
    times = [s.t_boot_s for s in log.samples]
    assert times == sorted(times)
    vel = [s for s in log.samples if isinstance(s, VelocitySample)]
    assert len(vel) == len(log.streams.t_gps_s) == 423
    shift = np.array([s.t_boot_s for s in vel]) - log.streams.t_gps_s
    assert np.max(np.abs(shift + 0.110)) < 1e-6  # µs time stamps in float64 seconds
    given = read_flight_log(public_logs["ulog"], "gps", gps_delay_s=0.2)
    assert (given.gps_delay_s, given.gps_delay_source) == (0.2, "given")


def test_dataflash_without_delay_parameter_estimates_it(public_logs: dict[str, Path]) -> None:
    log = read_flight_log(public_logs["dataflash"], "gps")
    # GPS1_DELAY_MS = 0 ("driver default") is not a value: the delay is estimated
    assert log.streams.params["GPS1_DELAY_MS"] == 0.0
    assert log.gps_delay_source == "estimated"
    # against the logged IMU the GPS lags by 0.03-0.07 s in this log (docs/logs.md: the
    # whole-log fit gives 0.029 s; the climb alone, 0.06 s)
    assert 0.0 <= log.gps_delay_s <= 0.08
    truth = [s for s in log.samples if isinstance(s, TruthSample)]
    # the fixture's SIM2 comes every 19.992 ms (2914 samples); the 20 ms bins of the 50 Hz
    # cap drop one where two fall in a bin (about 1 %), and never leave a gap over 2 bins
    assert 0.98 * 2914 <= len(truth) <= 2914
    assert max(np.diff([s.t_boot_s for s in truth])) <= 0.040 + 1e-6
    ekf = read_flight_log(public_logs["dataflash"], "ekf")
    assert ekf.gps_delay_source == "not used"
    assert sum(isinstance(s, VelocitySample) for s in ekf.samples) == 583


def test_a_log_without_the_needed_messages_is_a_log_error(
    public_logs: dict[str, Path], tmp_path: Path
) -> None:
    head = tmp_path / "head.BIN"
    head.write_bytes(public_logs["dataflash"].read_bytes()[:3000])  # formats only
    with pytest.raises(UnsupportedLogError, match=r"head\.BIN: unsupported: this log has no ATT"):
        read_flight_log(head)
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(public_logs["ulog"].read_bytes()[:200])
    with pytest.raises(LogError, match=r"cut\.ulg"):
        read_flight_log(cut)


def _dataflash_as_text(src: Path, dst: Path, t_end_us: float) -> None:
    """ArduPilot's text dump (``.log``: ``FMT, ...`` lines, then ``NAME, v1, v2, ...``) of
    the messages the reader uses, up to ``t_end_us``, written from the binary log."""
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(src), zero_time_base=False)
    lines: list[str] = []
    seen: set[str] = set()
    while (
        m := reader.recv_match(type=["ATT", "IMU", "GPS", "XKF1", "PARM", "MSG", "SIM2"])
    ) is not None:
        if m.TimeUS > t_end_us:
            break
        f = m.fmt
        if f.name not in seen:
            lines.append(f"FMT, {f.type}, {f.len}, {f.name}, {f.format}, {','.join(f.columns)}")
            seen.add(f.name)
        lines.append(f"{f.name}, " + ", ".join(str(getattr(m, c)) for c in f.columns))
    dst.write_text("\n".join(lines) + "\n")


def test_dataflash_text_log_gives_the_same_streams_as_the_binary(
    public_logs: dict[str, Path], tmp_path: Path
) -> None:
    text = tmp_path / "flight.log"
    _dataflash_as_text(public_logs["dataflash"], text, t_end_us=215e6)  # the first 17 s
    fmt, t = read_streams(text)
    assert fmt == "dataflash-text" and t.vehicle == "ArduCopter V4.6.0-dev"
    _, b = read_streams(public_logs["dataflash"])
    for name in ("t_imu_s", "f_body_mps2", "t_att_s", "euler_rad", "t_gps_s", "v_gps_ned_mps",
                 "t_ekf_s", "v_ekf_ned_mps"):  # fmt: skip
        a_text = getattr(t, name)
        a_bin = getattr(b, name)[: len(a_text)]
        assert len(a_text) > 80, name  # GPS at 5 Hz over 17 s: 86 samples
        # the text holds Python's shortest repr of each float32 value: exact round trip
        assert np.array_equal(a_text, a_bin), name


def test_the_ahrs_position_differentiated_gives_the_velocity_of_a_straight_track() -> None:
    """The POS fallback reference (no EKF logged): a track at 3 m/s north-east, 0.5 m/s up,
    at 10 Hz, rounded like the log (1e-7 deg, 1 cm): the centred 1 s difference recovers it
    to the rounding over the window (1e-7 deg = 1.1 cm, over 1 s: 0.011 m/s)."""
    from glmav_observer.ingest.logfiles.dataflash import velocity_from_positions

    t = np.arange(0.0, 20.0, 0.1)
    lat0, r = 47.0, 6_378_137.0
    lat = np.round((lat0 + np.degrees(3.0 * t / r)) * 1e7) / 1e7
    lng = np.round((8.0 + np.degrees(3.0 * t / (r * np.cos(np.radians(lat0))))) * 1e7) / 1e7
    alt = np.round((400.0 + 0.5 * t) * 100) / 100
    tv, v, p = velocity_from_positions(t, lat, lng, alt)
    assert tv[0] == pytest.approx(0.5) and tv[-1] == pytest.approx(19.4)  # the window inside
    assert np.abs(v - [3.0, 3.0, -0.5]).max() < 0.025
    assert p[-1, 2] == pytest.approx(-0.5 * tv[-1], abs=0.01)


def test_in_flight_is_moving_or_off_the_ground_with_a_margin() -> None:
    from glmav_observer.ingest.logfiles.streams import IN_FLIGHT_MARGIN_S, in_flight_mask

    t = np.arange(0.0, 60.0, 0.1)
    v = np.zeros((len(t), 3))
    p = np.zeros((len(t), 3))
    v[(t >= 10) & (t < 20), 0] = 2.0  # a run along the ground
    p[(t >= 30) & (t < 40), 2] = -5.0  # a hover 5 m up
    m = in_flight_mask(t, v, p)
    for lo, hi in ((10, 20), (30, 40)):
        assert m[(t >= lo - IN_FLIGHT_MARGIN_S + 0.05) & (t < hi + IN_FLIGHT_MARGIN_S - 0.15)].all()
    assert not m[t < 10 - IN_FLIGHT_MARGIN_S - 0.05].any()
    assert not m[(t > 40 + IN_FLIGHT_MARGIN_S)].any()


def test_without_att_and_an_ekf_the_ahrs_backup_and_its_position_are_used(
    tmp_path: Path,
) -> None:
    """The matrix's ArduCopter 4.6 log with ATT, XKF1 and XKF4 removed (byte for byte, by
    the trimming script): the attitude comes from AHR2, the reference from POS
    differentiated over 1 s. Against the full log's ATT and XKF1: the centred 1 s
    difference is the window's mean velocity, off the instantaneous one by the jerk's
    share (T²/24 × jerk); measured 0.015 / 0.017 / 0.027 m/s RMS, bound 0.05. AHR2 is the
    DCM backup, ATT the EKF: measured 0.06° roll and pitch, 0.7° yaw, bounds 0.2° and 2°."""
    import importlib.util
    import lzma

    root = Path(__file__).resolve().parents[4]
    spec = importlib.util.spec_from_file_location("trim", root / "scripts/trim_public_logs.py")
    assert spec is not None and spec.loader is not None
    trim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(trim)
    data = lzma.decompress(
        (root / "tests/data/public-logs/matrix/copter-4.6-sitl.BIN.xz").read_bytes()
    )
    full, bare = tmp_path / "full.BIN", tmp_path / "no_att_no_ekf.BIN"
    full.write_bytes(data)
    bare.write_bytes(
        trim.trim_dataflash(data, trim.MATRIX_DATAFLASH_KEEP - {"ATT", "XKF1", "XKF4"})
    )
    _, b = read_streams(full)
    _, a = read_streams(bare)
    assert a.sources["attitude"] == "AHR2" and a.sources["ekf"].startswith("POS (AHRS position")
    assert "ekf_innovations" not in a.sources and len(a.t_ekf_s) > 500
    for k, bound in enumerate((0.05, 0.05, 0.05)):
        ref = np.interp(a.t_ekf_s, b.t_ekf_s, b.v_ekf_ned_mps[:, k])
        assert np.sqrt(np.mean((a.v_ekf_ned_mps[:, k] - ref) ** 2)) < bound, k
    for k, bound_deg in enumerate((0.2, 0.2, 2.0)):
        ref = np.interp(a.t_att_s, b.t_att_s, np.unwrap(b.euler_rad[:, k]))
        d = np.angle(np.exp(1j * (a.euler_rad[:, k] - ref)))
        assert np.degrees(np.sqrt(np.mean(d**2))) < bound_deg, k
