"""Service in process: rate requests and re-requests when a stream falls short; summary."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.app import Service
from glmav_observer.config import parse_config
from glmav_observer.ingest.framing import FrameDecoder


def _att(t_ms: int) -> bytes:
    mav = dialect.MAVLink(None, srcSystem=3, srcComponent=1)
    return bytes(dialect.MAVLink_attitude_message(t_ms, 0, 0, 0, 0, 0, 0).pack(mav))


def _commands(outbox: list) -> list:
    dec = FrameDecoder(datagram=True)
    return [m for _, frame, _ in outbox for m in dec.feed(frame)]


def test_rates_requested_on_first_sight_and_again_when_short() -> None:
    cfg = parse_config(
        {"rates": {"hz": {"ATTITUDE": 100.0, "RAW_IMU": -1.0}, "window_s": 2.0, "retry_s": 5.0}}
    )
    svc = Service(cfg, [])
    svc.feed_bytes("udp", _att(1000), 0.0)
    svc.rate_requests()
    first = _commands(svc.outbox)
    svc.outbox.clear()
    by_msg = {int(c.param1): c for c in first}
    assert all(c.command == dialect.MAV_CMD_SET_MESSAGE_INTERVAL for c in first)
    assert all(c.target_system == 3 and c.target_component == 1 for c in first)
    assert by_msg[dialect.MAVLINK_MSG_ID_ATTITUDE].param2 == 10_000.0  # µs: 100 Hz
    assert by_msg[dialect.MAVLINK_MSG_ID_RAW_IMU].param2 == -1.0  # stop the stream
    # a ground station overrides the rate: ATTITUDE arrives at 10 Hz only
    times = []
    for k in range(1, 121):  # 12 s of vehicle time
        svc.feed_bytes("udp", _att(1000 + 100 * k), 0.0)
        svc.rate_requests()
        for c in _commands(svc.outbox):
            assert int(c.param1) == dialect.MAVLINK_MSG_ID_ATTITUDE  # -1 streams are not chased
            times.append(1.0 + 0.1 * k)
        svc.outbox.clear()
    # asked again after the first full window past retry_s, then every retry_s
    assert len(times) == 2, times
    assert abs(times[1] - times[0] - 5.0) < 0.11
    assert svc.summary().service_counters["rate_rerequest"] == 2
    assert svc.summary().vehicles[3].counters["rx_ATTITUDE"] == 121


def test_summary_text_is_plain_lines_and_says_when_no_velocity_arrived() -> None:
    from glmav_observer.app import ServiceSummary, VehicleSummary

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
            2: vehicle(2, {"rx_LOCAL_POSITION_NED": 3}),
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
