"""ODOMETRY carries every dead-reckoned axis's σ and a lowered quality: a silent velocity
stream (all axes) and a GPS loss (n and e), not only a configuration's lost axis."""

from __future__ import annotations

import socket
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_observer.config import MavlinkOutSettings
from glmav_observer.publish.mavlink_out import MavlinkOutSink
from glmav_observer.records import VelocityRecord


def _odometry(port: int, records: list[VelocityRecord]) -> list[Any]:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.settimeout(2.0)
    sink = MavlinkOutSink(
        MavlinkOutSettings(
            enabled=True, link=f"udpout:127.0.0.1:{port}", system_id=42, component_id=197,
            rate_hz=10.0, odometry=True,
        )
    )  # fmt: skip
    try:
        for r in records:
            sink.write(r)
    finally:
        sink.close()
    parser = mavlink2.MAVLink(None)
    got: list[Any] = []
    try:
        while True:
            got.extend(parser.parse_buffer(rx.recv(65535)) or [])
    except TimeoutError:
        pass
    finally:
        rx.close()
    return [m for m in got if m.get_type() == "ODOMETRY"]


def test_every_dead_reckoned_axis_has_its_variance_and_quality(
    free_udp_port: Callable[[], int],
) -> None:
    records = []
    for k in range(100):  # 1 s at 100 Hz: healthy, then GPS lost (n, e), then silent (all)
        t = k * 0.01
        if k < 30:
            axes, sig, health = (), None, "ok"
        elif k < 60:
            axes, sig, health = ("n", "e"), (0.1, 0.12, 0.0), "dead_reckoning"
        else:
            axes, sig, health = ("n", "e", "d"), (0.2, 0.22, 0.3), "dead_reckoning"
        records.append(
            VelocityRecord(
                3, "active", t, (0.0, 0.0, 0.0), (1.0, -2.0, 0.5), None, health, k, "full",
                None, "glmav.velocity/1", axes, sig,  # type: ignore[arg-type]
            )
        )  # fmt: skip
    odo = _odometry(free_udp_port(), records)
    assert len(odo) == 10  # 10 Hz of vehicle time over 1 s
    by_t = {round(m.time_usec / 10_000): m for m in odo}
    healthy, gps, silent = by_t[0], by_t[40], by_t[90]
    # velocity covariance (ODOMETRY's upper triangle: vx 0, vy 6, vz 11), float32: the
    # measured axes at sigma_measured_mps² (0.05², MavlinkOutSettings), a dead-reckoned
    # axis at its σ² (the larger of the two)
    assert (healthy.velocity_covariance[0], healthy.velocity_covariance[11]) == pytest.approx(
        (0.0025, 0.0025)
    )
    assert gps.velocity_covariance[0] == pytest.approx(0.01)
    assert gps.velocity_covariance[6] == pytest.approx(0.0144)
    assert gps.velocity_covariance[11] == pytest.approx(0.0025)
    assert [silent.velocity_covariance[i] for i in (0, 6, 11)] == pytest.approx(
        [0.04, 0.0484, 0.09]
    )
    # quality: 100 healthy, 50 while any axis is dead-reckoned (mavlink_out.QUALITY)
    assert (healthy.quality, gps.quality, silent.quality) == (100, 50, 50)
