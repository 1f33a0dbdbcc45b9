"""Service in process: the rate request policy (ingest/rates.py) on a silent vehicle, a
vehicle whose rates a ground station set, and one that stays short; summary."""

from __future__ import annotations

import itertools
import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.app import Service
from glmav_observer.config import parse_config
from glmav_observer.ingest.framing import FrameDecoder
from glmav_observer.ingest.links import Link

_MAV = dialect.MAVLink(None, srcSystem=3, srcComponent=1)


def _att(t_ms: int) -> bytes:
    return bytes(dialect.MAVLink_attitude_message(t_ms, 0, 0, 0, 0, 0, 0).pack(_MAV))


def _heartbeat(autopilot: int = dialect.MAV_AUTOPILOT_ARDUPILOTMEGA, kind: int = 2) -> bytes:
    return bytes(dialect.MAVLink_heartbeat_message(kind, autopilot, 0, 0, 0, 3).pack(_MAV))


def _commands(svc: Service) -> list:
    dec = FrameDecoder(datagram=True)
    out = [m for _, frame, _ in svc.outbox for m in dec.feed(frame)]
    svc.outbox.clear()
    return out


def _service(mode: str = "request") -> Service:
    return Service(
        parse_config(
            {
                "rates": {
                    "mode": mode,
                    "hz": {"ATTITUDE": 100.0, "RAW_IMU": -1.0},
                    "min_hz": {"ATTITUDE": 10.0},
                    "window_s": 2.0,
                    "retry_s": 5.0,
                    "retry_max_s": 20.0,
                }
            }
        )
    )


def test_a_silent_vehicle_is_registered_on_its_heartbeat_and_asked_once_a_window_later() -> None:
    svc = _service()
    svc.feed_bytes(
        "udp", _heartbeat(autopilot=dialect.MAV_AUTOPILOT_INVALID), 0.0
    )  # a GCS/companion
    svc.feed_bytes("udp", _heartbeat(kind=dialect.MAV_TYPE_GCS), 0.0)
    assert svc.ingest.vehicles == {}
    svc.feed_bytes("udp", _heartbeat(), 0.0)  # ArduCopter with every stream rate at 0
    assert list(svc.ingest.vehicles) == [3]
    svc.rate_requests(1.9)
    assert _commands(svc) == []  # a full window is measured first (window_s = 2 s)
    svc.rate_requests(2.0)
    by_msg = {int(c.param1): c for c in _commands(svc)}
    assert set(by_msg) == {dialect.MAVLINK_MSG_ID_ATTITUDE, dialect.MAVLINK_MSG_ID_RAW_IMU}
    assert all(c.command == dialect.MAV_CMD_SET_MESSAGE_INTERVAL for c in by_msg.values())
    assert all(c.target_system == 3 and c.target_component == 1 for c in by_msg.values())
    assert by_msg[dialect.MAVLINK_MSG_ID_ATTITUDE].param2 == 10_000.0  # µs: 100 Hz
    assert by_msg[dialect.MAVLINK_MSG_ID_RAW_IMU].param2 == -1.0  # stop the stream


def test_a_rate_set_by_a_ground_station_above_the_need_is_left_alone() -> None:
    svc = _service()
    svc.feed_bytes("udp", _heartbeat(), 0.0)
    asked: list[float] = []
    # MAVSDK's set_rate_attitude_euler(20): 20 Hz, above the 10 Hz the estimator needs
    for k in range(60 * 20):  # 60 s, host time = vehicle time
        t = 0.05 * k
        svc.feed_bytes("udp", _att(round(1000 * t)), t)
        if k % 20 == 0:
            svc.rate_requests(t)
            asked += [t for c in _commands(svc) if int(c.param1) == dialect.MAVLINK_MSG_ID_ATTITUDE]
    assert asked == []  # never overridden (was: re-requested every 5 s, 11 times in 60 s)
    assert svc.summary().vehicles[3].counters["rx_ATTITUDE"] == 1200
    health_rates = svc.ingest.vehicles[3].rates.rates()
    assert abs(health_rates["ATTITUDE"] - 20.0) < 1e-6  # 40 intervals of exactly 50 ms


def test_a_short_stream_is_asked_again_with_backoff_and_observe_mode_sends_nothing() -> None:
    for mode, expected in (("request", [2.0, 7.0, 17.0, 37.0, 57.0]), ("observe", [])):
        svc = _service(mode)
        svc.feed_bytes("udp", _heartbeat(), 0.0)
        asked: list[float] = []
        for k in range(60 * 5):  # 5 Hz, below the 10 Hz needed, for 60 s
            t = 0.2 * k
            svc.feed_bytes("udp", _att(round(1000 * t)), t)
            if k % 5 == 0:
                svc.rate_requests(t)
                asked += [
                    round(t, 3)
                    for c in _commands(svc)
                    if int(c.param1) == dialect.MAVLINK_MSG_ID_ATTITUDE
                    and c.command == dialect.MAV_CMD_SET_MESSAGE_INTERVAL  # not its query
                ]
        # after the first window, then 5, 10, 20 (retry_max_s), 20 s later
        assert asked == expected, mode
        counters = svc.summary().service_counters
        assert counters.get("rate_requests_sent", 0) == len(expected) + (mode == "request")


def test_summary_text_is_plain_lines_and_says_when_no_velocity_arrived() -> None:
    from glmav_observer.app_summary import ServiceSummary, VehicleSummary

    def vehicle(sysid: int, counters: dict[str, int]) -> VehicleSummary:
        return VehicleSummary(
            sysid=sysid,
            rmse_ned_mps={},
            max_abs_error_ned_mps={},
            truth_samples=0,
            faults=[{"axis": "e", "kind": "bias", "t_detect_s": 12.1624, "t_onset_s": None}],
            switches=[
                {
                    "from": "full",
                    "to": "c3",
                    "t_boot_s": 12.1624,
                    "reason": "bias_e",
                    "jump_mps": 0.004,
                },
                {
                    "from": "c3",
                    "to": "full",
                    "t_boot_s": 18.1,
                    "reason": "recovered",
                    "jump_mps": None,
                },
            ],
            counters=counters,
            active_config="full",
        )

    summary = ServiceSummary(
        vehicles={
            1: vehicle(1, {"rx_ATTITUDE": 10, "rx_HIGHRES_IMU": 25, "late": 2}),
            2: vehicle(2, {"rx_LOCAL_POSITION_NED": 3, "fdi_off_imu_too_slow": 3}),
        },
        link_counters={},
        service_counters={},
        records=0,
        messages=38,
    )
    text = summary.to_text()
    assert "{" not in text and "}" not in text  # no Python dicts
    assert "  fault isolated: axis e (bias) at t = 12.162 s" in text
    assert "  switch: full -> c3 at t = 12.162 s (bias_e), jump 0.004 m/s" in text
    assert "  switch: c3 -> full at t = 18.100 s (recovered), jump n/a" in text
    assert "  samples dropped/flagged: late=2" in text
    # vehicle 1 never sent LOCAL_POSITION_NED, vehicle 2 did
    v1, v2 = text.split("vehicle 2:")
    assert "no velocity measurement received (LOCAL_POSITION_NED)" in v1
    assert "no velocity measurement" not in v2
    assert "fault detection off for 3 velocity samples" in v2
    assert "fault detection off" not in v1


def test_superseded_imu_frames_and_bad_frames_are_counted_by_reason() -> None:
    """A vehicle sends three IMU messages at 250 Hz; the service uses the best one and
    counts the other two as superseded. Mixed in: CRC errors in superseded frames, MAVLink
    1 frames, a frame from another component, an all-zero payload (MAVLink 2 truncates it
    to one byte: ``imu_absent``), two frames in one datagram. Every count is the one the
    stream was built with, and every message decoded is one the service counts."""
    from glmav_testkit.fuzzgen import pack, sitl_stream

    stream = sitl_stream("cruise", duration_s=4.0, seed=2)
    frames: list[bytes] = []
    injected = {"bad_crc": 0, "v1": 0, "double": 0, "zero": 0}
    for k, f in enumerate(stream.frames):
        msgid = f[7] | f[8] << 8 | f[9] << 16 if f[0] == 0xFD else f[5]
        if msgid == dialect.MAVLINK_MSG_ID_RAW_IMU and k % 50 == 0:
            frames.append(f[:-1] + bytes([f[-1] ^ 0xFF]))  # CRC error
            injected["bad_crc"] += 1
        elif msgid == dialect.MAVLINK_MSG_ID_SCALED_IMU and k % 70 == 0:
            msg = dialect.MAVLink(None).decode(bytearray(f))
            frames.append(pack(msg, f[5], f[6], v1=True))
            injected["v1"] += 1
        elif k % 400 == 0:
            frames.append(f + f)  # two frames in one datagram
            injected["double"] += 1
        else:
            frames.append(f)
        if k % 500 == 0:
            zero = dialect.MAVLink_raw_imu_message(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
            frames.append(pack(zero, f[5], f[6]))
            frames.append(pack(zero, f[5], 77))  # another component of the vehicle
            injected["zero"] += 1

    svc = Service(parse_config({"rates": {"mode": "observe"}}))
    recs: list[object] = []
    svc.on_records = recs.extend
    for i, f in enumerate(frames):
        svc.feed_bytes("udp", f, 1000.0 + i * 1e-3)
    summary = svc.summary()
    counters = summary.vehicles[1].counters
    link = summary.link_counters["udp"]
    assert injected["bad_crc"] > 10 and injected["v1"] > 10 and injected["zero"] > 1
    assert link["bad_crc"] == injected["bad_crc"]
    # every frame but the bad ones decoded once (a double datagram holds two)
    assert link["frames_ok"] == len(frames) - injected["bad_crc"] + injected["double"]
    assert summary.messages == link["frames_ok"]
    assert counters["imu_superseded"] > 1500  # 2 of 3 IMU streams: ~2,000 in 4 s
    assert counters["other_component"] == injected["zero"]
    # the zero RAW_IMU frames arrive while HIGHRES_IMU streams: superseded, not converted
    assert counters["rx_SCALED_IMU"] > 0 and counters["rx_RAW_IMU"] > 0
    assert summary.records == len(recs) > 0


def _wait_for_kernel_stamps(link: Link, tx: socket.socket, port: int) -> None:
    """Return once the kernel stamps datagrams as they arrive. A machine where no socket
    had receive stamps on turns them on (a global switch) a moment after the first one
    asks; a datagram queued before that is stamped when it is read (Linux's
    ``__sock_recv_timestamp``: "race occurred between timestamp enabling and packet
    receiving"). So: send one, wait 20 ms, read it; stamped on arrival, it is >= 15 ms
    older than its read (5 ms of slack for a loaded machine's scheduling)."""
    for _ in range(50):
        tx.sendto(b"prime", ("127.0.0.1", port))
        time.sleep(0.02)
        got = link.read_datagrams(4)
        if got and time.monotonic() - got[-1][1] >= 0.015:
            return
    raise AssertionError("the kernel never stamped a datagram on arrival")


def test_the_live_loop_gives_each_drained_datagram_its_own_arrival() -> None:
    """Service.run drains a UDP link many datagrams a system call (recvmmsg); the
    arrival it exposes while feeding each one (``current_arrival_s``, what bench_fleet's
    latency reads) is that datagram's own kernel stamp, not the batch's last."""
    svc = Service(parse_config({"rates": {"mode": "observe"}}), [])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a free port
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    link = Link(f"udpin:127.0.0.1:{port}")
    seen: list[float] = []
    orig = svc.feed_bytes

    def feed(link_id: str, data: bytes, t: float, *, datagram: bool = True) -> int:
        seen.append(svc.current_arrival_s)
        return orig(link_id, data, t, datagram=datagram)

    svc.feed_bytes = feed  # type: ignore[method-assign]
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    _wait_for_kernel_stamps(link, tx, port)
    frames = [_MAV.heartbeat_encode(2, 3, 0, 0, 4).pack(_MAV) for _ in range(3)]
    stamps = []
    for f in frames:  # sent 20 ms apart, queued before the loop reads: one drain reads all
        stamps.append(time.monotonic())
        tx.sendto(f, ("127.0.0.1", port))
        time.sleep(0.02)
    stop = threading.Event()
    th = threading.Thread(target=svc.run, args=({"udp": link}, stop))
    th.start()
    deadline = time.monotonic() + 10.0
    while len(seen) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    th.join(10.0)
    link.close()
    tx.close()
    assert len(seen) == 3
    # each one its own: 20 ms apart as sent (the loop read them together, later); the
    # sleeps are at least 20 ms, and a stamp is the kernel's, taken after the send began
    gaps = [b - a for a, b in itertools.pairwise(seen)]
    assert all(g >= 0.019 for g in gaps), gaps
    assert all(s >= t0 for s, t0 in zip(seen, stamps, strict=True))
