"""Rerun sink: mode parsing, frame math, truth interpolation, and .rrd files read back.

These tests write real recordings (``save:`` mode, a file in tmp_path) and read them
back with rerun's own reader; no sockets.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from glmav_observer.frames import e_exact, quaternion_xyzw
from glmav_observer.publish.rerun import (
    TIMELINE,
    RerunMode,
    RerunModeError,
    RerunSink,
    build_blueprint,
    open_rerun_sink,
    parse_rerun_mode,
    read_recording,
)
from glmav_observer.publish.sink import Sink
from glmav_observer.records import (
    FaultEvent,
    HealthRecord,
    MeasurementRecord,
    TruthRecord,
    VelocityRecord,
)

# Times go through int64 nanoseconds: rounding error <= 0.5 ns.
T_TOL_S = 1e-9


ESTIMATES = ("full", "c1", "c2", "c3", "active")


def _vel(config: str, t: float, v_body: tuple[float, float, float], seq: int = 0) -> VelocityRecord:
    """u carries the configuration's index / 10 so that instances can be told apart."""
    u = v_body[0] + 0.1 * ESTIMATES.index(config)
    v_ned = (u + 10.0, v_body[1] + 20.0, v_body[2] + 30.0)
    return VelocityRecord(1, config, t, (u, v_body[1], v_body[2]), v_ned, None, "ok", seq)


def _health(t: float, active: str, faults: tuple[FaultEvent, ...]) -> HealthRecord:
    return HealthRecord(
        sysid=1,
        t_boot_s=t,
        seq=0,
        active_config=active,
        residual_ned_mps=(0.1, -0.2, 0.3),
        test_ratio=(2.5, 0.5, 0.25),
        axis_state={"n": "faulty" if faults else "ok", "e": "ok", "d": "suspect"},
        isolated_faults=faults,
        input_rates_hz={},
        counters={},
    )


@pytest.mark.parametrize(
    ("text", "kind", "target"),
    [
        ("off", "off", None),
        ("spawn", "spawn", None),
        ("serve", "serve", None),
        ("connect", "connect", "rerun+http://127.0.0.1:9876/proxy"),
        ("connect:rerun+http://10.0.0.2:9000/proxy", "connect", "rerun+http://10.0.0.2:9000/proxy"),
        ("save:out/x.rrd", "save", "out/x.rrd"),
        ("SAVE:a.rrd", "save", "a.rrd"),
    ],
)
def test_parse_modes(text: str, kind: str, target: str | None) -> None:
    assert parse_rerun_mode(text) == RerunMode(kind, target)
    assert RerunMode(kind, target).live == (kind in ("spawn", "connect", "serve"))


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("view", "expected off, spawn"),
        ("save", "save needs a path"),
        ("save:", "save needs a path"),
        ("connect:http://127.0.0.1:9876", "rerun\\+http://HOST:PORT/proxy"),
        ("connect:rerun+http://127.0.0.1:9876/", "path /proxy"),
        ("serve:0.0.0.0", "takes no argument"),
    ],
)
def test_bad_modes_raise(text: str, match: str) -> None:
    with pytest.raises(RerunModeError, match=match):
        parse_rerun_mode(text)
    with pytest.raises(ValueError, match=match):  # RerunModeError is a ValueError
        open_rerun_sink(text)


def test_rotation_is_e_of_13_and_matches_quaternion() -> None:
    # yaw 90 deg: the body's forward axis points east (NED y), right axis points south
    e = e_exact((0.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(e @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(e @ [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], atol=1e-15)
    # pitch up 90 deg: forward points up (NED -z)
    e = e_exact((0.0, math.pi / 2, 0.0))
    np.testing.assert_allclose(e @ [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], atol=1e-15)
    rng = np.random.default_rng(7)
    for euler in rng.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(200, 3)):
        m = e_exact(euler)
        # a rotation: orthonormal with det +1 (round-off of a few ulp)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-14)
        x, y, z, w = quaternion_xyzw(euler)
        assert x * x + y * y + z * z + w * w == pytest.approx(1.0, abs=1e-14)
        q = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(q, m, atol=1e-14)  # same rotation, float round-off only


def test_blueprint_has_one_tab_per_vehicle() -> None:
    import rerun.blueprint as rrb

    one = build_blueprint([1])
    two = build_blueprint([1, 2])
    assert isinstance(one, rrb.Blueprint)
    assert isinstance(one.root_container, rrb.Tabs)  # the vehicle's tabs directly
    assert [c.name for c in one.root_container.contents] == [  # type: ignore[union-attr]
        "overview",
        "NED velocity",
        "errors vs truth",
        "health",
    ]
    assert [c.name for c in two.root_container.contents] == ["vehicle 1", "vehicle 2"]  # type: ignore[union-attr]


def test_save_roundtrip(tmp_path: Path) -> None:
    path = tmp_path / "out" / "rec.rrd"
    sink = open_rerun_sink(f"save:{path}", recording_name="unit")
    assert isinstance(sink, Sink)
    assert sink.effective_mode == f"save:{path}"
    # truth at 0 and 0.02 s, linear in time; estimates in between
    sink.write(TruthRecord(1, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0, 0, 0), (0, 0, 0), 0))
    for k, t in enumerate((0.005, 0.01, 0.015)):
        for c in ("full", "c1", "c2", "c3", "active"):
            sink.write(_vel(c, t, (1.0 + k, 2.0, 3.0), seq=k))
    sink.write(_health(0.01, "full", ()))
    sink.write(TruthRecord(1, 0.02, (0.2, 0.4, 0.6), (2.0, 4.0, 6.0), (0, 0, 0), (0, 0, 0), 1))
    # measured north-east-down (0, 1, 0) at yaw 90 deg is (1, 0, 0) in body axes
    sink.write(
        MeasurementRecord(1, 0.02, (0.0, 1.0, 0.0), (5.0, 6.0, -7.0), 0, (0.0, 0.0, math.pi / 2))
    )
    fault = FaultEvent("n", "bias", t_detect_s=0.025, t_onset_s=0.02)
    sink.write(_health(0.03, "c2", (fault,)))
    sink.close()
    assert sink.stats.records == 20
    assert sink.stats.send_errors == 0

    rec = read_recording(path)
    # the bank: one entity per axis, one instance per configuration (full, c1, c2, c3)
    bank_u = rec["/vehicle/1/estimate/v_body/u"]
    np.testing.assert_allclose(bank_u[TIMELINE], [0.005, 0.01, 0.015], rtol=0, atol=T_TOL_S)
    expected_u = [[1.0 + k + 0.1 * i for i in range(5)] for k in range(3)]
    assert bank_u["Scalars:scalars"] == expected_u  # float64 stored as is
    # each c-configuration is named with the axis it has lost (configurations.LOST_AXIS_OF_CONFIG)
    assert bank_u["static:SeriesLines:names"] == [
        ["full", "c1 (d lost)", "c2 (n lost)", "c3 (e lost)", "active"]
    ]
    assert rec["/vehicle/1/estimate/v_body/w"]["Scalars:scalars"] == [[3.0] * 5] * 3
    # the active estimate is the last instance
    assert [v[-1] for v in rec["/vehicle/1/estimate/v_ned/d"]["Scalars:scalars"]] == [33.0] * 3
    assert [v[-1] for v in bank_u["Scalars:scalars"]] == [1.4, 2.4, 3.4]
    # est - truth with truth linearly interpolated: at t the truth u is 10 t, n is 100 t
    err_u = rec["/vehicle/1/error/v_body/u"]
    assert err_u["static:SeriesLines:names"] == [
        ["full", "c1 (d lost)", "c2 (n lost)", "c3 (e lost)", "active"]
    ]
    for k, (t, row) in enumerate(zip(err_u[TIMELINE], err_u["Scalars:scalars"], strict=True)):
        expected = [1.0 + k + 0.1 * i - 10 * t for i in range(5)]
        np.testing.assert_allclose(row, expected, rtol=0, atol=1e-12)
    err_n = rec["/vehicle/1/error/v_ned/n"]["Scalars:scalars"]
    np.testing.assert_allclose(
        [row[2] for row in err_n], [11.2 - 0.5, 12.2 - 1.0, 13.2 - 1.5], rtol=0, atol=1e-12
    )  # c2
    truth_w = rec["/vehicle/1/truth/v_body/w"]
    assert truth_w["Scalars:scalars"] == [[0.0], [0.6]]
    meas = [
        rec[f"/vehicle/1/ingest/measurement/v_body/{a}"]["Scalars:scalars"][0][0] for a in "uvw"
    ]
    np.testing.assert_allclose(meas, [1.0, 0.0, 0.0], atol=1e-15)  # E^T y, see above
    assert rec["/vehicle/1/ingest/measurement/v_ned/e"]["Scalars:scalars"] == [[1.0]]
    h = "/vehicle/1/health"
    assert rec[f"{h}/residual"]["Scalars:scalars"] == [[0.1, -0.2, 0.3]] * 2  # n, e, d
    assert rec[f"{h}/test_ratio"]["Scalars:scalars"] == [[2.5, 0.5, 0.25]] * 2
    # ok 0, suspect 1, recovering 2, faulty 3
    assert rec[f"{h}/axis_state"]["Scalars:scalars"] == [[0.0, 0.0, 1.0], [3.0, 0.0, 1.0]]
    # (active config, isolated axis): (full, none) then (c2, n)
    assert rec[f"{h}/state"]["Scalars:scalars"] == [[0.0, 0.0], [2.0, 1.0]]
    assert rec[f"{h}/events"]["TextLog:text"] == [
        ["fault isolated on axis n (bias) at 0.025 s"],
        ["active configuration full -> c2 (n lost)"],
    ]
    # the status document, logged when it changes: what the active configuration lost,
    # fault detection armed, each axis's state and the configuration without it
    status = rec[f"{h}/status"]
    np.testing.assert_allclose(status[TIMELINE], [0.01, 0.03], atol=T_TOL_S)
    first, second = (doc[0] for doc in status["TextDocument:text"])
    assert first.splitlines()[0] == "**active: full**"
    assert "fault detection: armed on n, e, d" in first
    assert second.splitlines()[0] == (
        "**active: c2 (n lost)**, axis n dead-reckoned; isolated: n (bias at 0.025 s)"
    )
    assert "| n | **faulty** | c2 |" in second.splitlines()
    assert "| e | ok | c3 |" in second.splitlines()
    assert "| d | **suspect** | c1 |" in second.splitlines()
    np.testing.assert_allclose(rec[f"{h}/events"][TIMELINE], [0.03, 0.03], atol=T_TOL_S)
    pose = rec["/world/vehicle/1"]
    np.testing.assert_allclose(pose["Transform3D:translation"][0][0], [5.0, 6.0, -7.0])
    # yaw 90 deg about z: (0, 0, sin 45, cos 45); stored as float32 (6e-8 relative)
    np.testing.assert_allclose(
        pose["Transform3D:quaternion"][0][0], [0, 0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-7
    )
    arrow = rec["/world/vehicle/1/velocity/active"]["Arrows3D:vectors"]
    np.testing.assert_allclose(arrow[0][0], [3.4, 2.0, 3.0], atol=1e-6)  # last active, float32
    # the vehicle's clock only: no host-time timelines in the recording
    reader = RrdReader(path)
    timelines = {name for chunk in reader.stream() for name in chunk.timeline_names}
    assert timelines == {TIMELINE}
    assert len(reader.blueprints()) == 1  # the layout travels with the file


def test_save_mode_batches_all_rows_and_drops_unbracketed_errors(tmp_path: Path) -> None:
    path = tmp_path / "batched.rrd"
    sink = open_rerun_sink(f"save:{path}", decimation=10, batch_rows=100)
    n = 2000  # 8 s at 250 Hz: 20 flushes of 100 rows
    for k in range(n):
        t = k / 250
        if k % 5 == 0 and t < 2.0:  # truth (50 Hz) only for the first 2 s
            sink.write(TruthRecord(1, t, (0.0, 0.0, 0.0), (0, 0, 0), (0, 0, 0), None, k))
        sink.write(_vel("full", t, (float(k), 0.0, 0.0), seq=k))
    sink.close()
    rec = read_recording(path)
    # decimation applies to live modes only: a saved log has every record
    bank_u = rec["/vehicle/1/estimate/v_body/u"]["Scalars:scalars"]
    assert [v[0] for v in bank_u] == list(map(float, range(n)))  # the full configuration
    assert all(math.isnan(x) for v in bank_u for x in v[1:])  # c1, c2, c3, active never sent
    assert sink.stats.batches_sent >= 20  # flushed as it went, not all at close
    err_t = rec["/vehicle/1/error/v_body/u"][TIMELINE]
    k_last_truth = 495  # the last k with k % 5 == 0 and k / 250 < 2
    # errors exist exactly where two truth samples bracket the estimate: k = 0 .. 495
    assert len(err_t) == k_last_truth + 1
    assert max(err_t) == pytest.approx(k_last_truth / 250, abs=T_TOL_S)
    # the rest waited for truth that never came, then were dropped and counted
    assert sink.stats.error_rows_without_truth == n - (k_last_truth + 1)


def test_off_mode_opens_nothing(tmp_path: Path) -> None:
    sink = open_rerun_sink("off")
    assert isinstance(sink, RerunSink)
    sink.write(_vel("full", 0.0, (1.0, 2.0, 3.0)))
    sink.close()
    assert sink.stats.records == 0
    assert sink.effective_mode == "off"
    assert list(tmp_path.iterdir()) == []


def test_spawn_without_display_falls_back_to_save(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "demo.rrd"
    sink = open_rerun_sink("spawn", fallback_save_path=str(path), environ={})
    assert sink.requested_mode == RerunMode("spawn")
    assert sink.effective_mode == f"save:{path}"
    assert f"Open it with: rerun {path}" in caplog.text
    sink.write(_vel("c1", 1.5, (4.0, 5.0, 6.0)))
    sink.close()
    w = read_recording(path)["/vehicle/1/estimate/v_body/w"]["Scalars:scalars"]
    assert w[0][1] == 6.0  # c1 is the second instance
    with pytest.raises(RerunModeError, match="no DISPLAY or WAYLAND_DISPLAY"):
        open_rerun_sink("spawn", fallback_save_path=None, environ={})


def _warming(t: float, unarmed: tuple[str, ...]) -> HealthRecord:
    states = {a: ("warmup" if a in unarmed else "ok") for a in "ned"}
    return HealthRecord(1, t, 0, "full", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), states, (), {}, {})


def test_fault_detection_arming_is_shown(tmp_path: Path) -> None:
    """Axes in ``warmup`` (fault detection not armed): a warning once they have stayed
    there ``arming_timeout_s``, an event when they arm, and the status document says which."""
    path = tmp_path / "arming.rrd"
    sink = open_rerun_sink(f"save:{path}", arming_timeout_s=2.0)
    for k in range(31):  # health at 10 Hz for 3 s: n, e, d warm up until 2.5 s, then d until 3 s
        t = k / 10
        unarmed = ("n", "e", "d") if t < 2.5 else ("d",) if t < 3.0 else ()
        sink.write(_warming(t, unarmed))
    sink.close()
    events = read_recording(path)["/vehicle/1/health/events"]
    texts = [e[0] for e in events["TextLog:text"]]
    assert texts == [
        "fault detection not armed after 2.0 s on axis n, e, d: no vetted reference "
        "(too slow an IMU or missing measurements?)",
        "fault detection armed on axis n, e",
        "fault detection armed on axis d",
    ]
    assert [lvl[0] for lvl in events["TextLog:level"]] == ["WARN", "INFO", "INFO"]
    # 2.0 s after the first record (t = 0); the health rows are 0.1 s apart (float sums)
    np.testing.assert_allclose(events[TIMELINE], [2.0, 2.5, 3.0], atol=1e-9)
    docs = read_recording(path)["/vehicle/1/health/status"]
    lines = [d[0].splitlines()[1] for d in docs["TextDocument:text"]]
    assert lines == [
        "**fault detection NOT ARMED** on n, e, d (warm-up, no vetted reference yet)",
        "**fault detection NOT ARMED** on n, e, d (not armed after 2.0 s: warm-up, no vetted "
        "reference yet (IMU rate? measurements?))",
        "**fault detection NOT ARMED** on d (not armed after 2.0 s: warm-up, no vetted "
        "reference yet (IMU rate? measurements?))",
        "fault detection: armed on n, e, d",
    ]
    # warm-up is -1 in the axis-state series
    states = read_recording(path)["/vehicle/1/health/axis_state"]["Scalars:scalars"]
    assert states[0] == [-1.0, -1.0, -1.0]
    assert states[25] == [0.0, 0.0, -1.0]
    assert states[30] == [0.0, 0.0, 0.0]


def test_arming_in_time_gives_no_warning(tmp_path: Path) -> None:
    path = tmp_path / "armed.rrd"
    sink = open_rerun_sink(f"save:{path}", arming_timeout_s=2.0)
    for k in range(30):  # armed at 1.5 s, within the 2 s allowed
        sink.write(_warming(k / 10, ("n", "e", "d") if k < 15 else ()))
    sink.close()
    texts = read_recording(path)["/vehicle/1/health/events"]["TextLog:text"]
    assert texts == [["fault detection armed on axis n, e, d"]]


def test_configurations_are_the_ones_given(tmp_path: Path) -> None:
    """The bank's instances follow the configuration names the sink is given (a fifth one
    here); records of a configuration it was not given are ignored."""
    path = tmp_path / "five.rrd"
    configs = ("full", "c1", "c2", "c3", "aided")
    sink = open_rerun_sink(f"save:{path}", configs=configs)
    assert sink.configs == configs
    for k, t in enumerate((0.0, 0.004)):
        for i, c in enumerate((*configs, "active", "unknown")):
            v = (float(i), float(k), 0.0)
            sink.write(VelocityRecord(1, c, t, v, v, None, "ok", k))
    sink.close()
    rec = read_recording(path)
    bank_u = rec["/vehicle/1/estimate/v_body/u"]
    assert bank_u["static:SeriesLines:names"] == [
        ["full", "c1 (d lost)", "c2 (n lost)", "c3 (e lost)", "aided", "active"]
    ]
    assert len(bank_u["static:SeriesLines:colors"][0]) == 6  # one colour each, all distinct
    assert len(set(bank_u["static:SeriesLines:colors"][0])) == 6
    assert bank_u["Scalars:scalars"] == [[0.0, 1.0, 2.0, 3.0, 4.0, 5.0]] * 2  # active last
    assert rec["/vehicle/1/estimate/v_body/v"]["Scalars:scalars"] == [[0.0] * 6, [1.0] * 6]
    for bad in ((), ("full", "full"), ("full", "active")):
        with pytest.raises(ValueError, match="distinct configuration names"):
            open_rerun_sink("off", configs=bad)


def test_active_line_is_the_widest_of_its_plots(tmp_path: Path) -> None:
    """The active estimate coincides with a configuration and with the truth: it is drawn
    wider than both, so a band of it shows whatever the viewer draws on top."""
    path = tmp_path / "widths.rrd"
    sink = open_rerun_sink(f"save:{path}")
    sink.write(_vel("full", 0.0, (1.0, 2.0, 3.0)))
    sink.close()
    rec = read_recording(path)
    for axis in ("v_body/u", "v_ned/d"):
        *configs, active = rec[f"/vehicle/1/estimate/{axis}"]["static:SeriesLines:widths"][0]
        names = rec[f"/vehicle/1/estimate/{axis}"]["static:SeriesLines:names"][0]
        assert names[-1] == "active"  # the last instance: drawn after the configurations
        others = [*configs, *rec[f"/vehicle/1/truth/{axis}"]["static:SeriesLines:widths"][0]]
        assert active >= 2 * max(others), (active, others)  # >= 1 px band each side
