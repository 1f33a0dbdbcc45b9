"""The stream rates that fit a link (ingest/link_budget.py), in bytes per second."""

from __future__ import annotations

import pytest

from glmav_observer.config import DEFAULT_MIN_RATES_HZ, DEFAULT_RATES_HZ
from glmav_observer.ingest.link_budget import (
    LinkCapacity,
    cost_bytes_per_s,
    fit_rates,
    frame_bytes,
    serial_capacity_bytes_per_s,
)


def test_frame_sizes_are_mavlink2_lengths() -> None:
    # header 10 + payload (common.xml, with extensions) + CRC 2; signed: + 13
    assert frame_bytes("HIGHRES_IMU") == 10 + 63 + 2
    assert frame_bytes("ATTITUDE") == 10 + 28 + 2
    assert frame_bytes("LOCAL_POSITION_NED") == 10 + 28 + 2
    assert frame_bytes("ATTITUDE", signed=True) == 40 + 13
    # the default rates: 250 x 75 + 100 x 40 + 30 x 40 + 50 x 104 + 2 x 38 + 5 x 64
    assert cost_bytes_per_s(DEFAULT_RATES_HZ) == 29_546.0


def test_serial_capacity_from_the_baud_rate() -> None:
    assert serial_capacity_bytes_per_s("/dev/ttyUSB0,57600") == 5760.0  # 8N1: 10 bits
    assert serial_capacity_bytes_per_s("/dev/ttyACM0") == 11520.0  # pymavlink's 115,200
    assert serial_capacity_bytes_per_s("udpin:127.0.0.1:14550") is None
    assert serial_capacity_bytes_per_s("tcp:127.0.0.1:5760") is None
    assert LinkCapacity("tcp:127.0.0.1:5760", 2000.0).bytes_per_s == 2000.0  # [rates] wins
    assert LinkCapacity("/dev/ttyUSB0,57600").bytes_per_s == 5760.0
    assert LinkCapacity("udpin:127.0.0.1:14550").bytes_per_s is None


def test_at_57600_baud_the_needs_are_scaled_into_half_the_link() -> None:
    budget = 0.5 * 5760.0
    got = fit_rates(DEFAULT_RATES_HZ, DEFAULT_MIN_RATES_HZ, budget)
    assert cost_bytes_per_s(got) == pytest.approx(budget, rel=1e-12)
    # the needs (HIGHRES_IMU 50, ATTITUDE 10, LOCAL_POSITION_NED 5 Hz; 1 Hz for the others)
    # cost 3750 + 400 + 200 + 104 + 38 + 64 = 4556 B/s: each at 2880/4556 of its need
    scale = budget / 4556.0
    assert got["HIGHRES_IMU"] == pytest.approx(50.0 * scale, rel=1e-12)  # 31.6 Hz
    assert got["ATTITUDE"] == pytest.approx(10.0 * scale, rel=1e-12)
    assert got["LOCAL_POSITION_NED"] == pytest.approx(5.0 * scale, rel=1e-12)
    assert got["GPS_RAW_INT"] == pytest.approx(1.0 * scale, rel=1e-12)
    # signed frames are 13 bytes longer: lower rates for the same budget
    signed = fit_rates(DEFAULT_RATES_HZ, DEFAULT_MIN_RATES_HZ, budget, signed=True)
    assert cost_bytes_per_s(signed, signed=True) == pytest.approx(budget, rel=1e-12)
    assert signed["HIGHRES_IMU"] < got["HIGHRES_IMU"]


def test_above_the_needs_the_rest_is_shared_in_proportion() -> None:
    budget = 0.5 * 11520.0  # 115,200 baud
    got = fit_rates(DEFAULT_RATES_HZ, DEFAULT_MIN_RATES_HZ, budget)
    assert cost_bytes_per_s(got) == pytest.approx(budget, rel=1e-12)
    # every stream gets its need plus one share of what is wanted beyond it
    share = (got["HIGHRES_IMU"] - 50.0) / (250.0 - 50.0)
    assert 0.0 < share < 1.0
    assert got["ATTITUDE"] == pytest.approx(10.0 + share * 90.0, rel=1e-12)
    assert got["SIM_STATE"] == pytest.approx(1.0 + share * 49.0, rel=1e-12)
    # a link that carries everything: the configured rates, untouched; -1 and 0 kept
    wanted = {**DEFAULT_RATES_HZ, "RAW_IMU": -1.0}
    assert fit_rates(wanted, DEFAULT_MIN_RATES_HZ, 1e6) == wanted
    assert fit_rates(wanted, DEFAULT_MIN_RATES_HZ, 100.0)["RAW_IMU"] == -1.0


def test_a_radio_is_measured_over_periods_it_was_full() -> None:
    cap = LinkCapacity("udpin:127.0.0.1:14550")
    cap.rx_bytes = 1000
    assert not cap.radio_status(30, 10.0)  # the first full status only starts a period
    cap.rx_bytes += 3000
    assert not cap.radio_status(95, 11.0)  # room: not a measure
    cap.rx_bytes += 3500
    assert not cap.radio_status(20, 12.0)  # full, but the period began with room
    cap.rx_bytes += 4000
    assert cap.radio_status(20, 13.0) and cap.bytes_per_s == 4000.0
    cap.rx_bytes += 3800
    assert not cap.radio_status(20, 14.0) and cap.bytes_per_s == 4000.0  # 5 %: stable
    cap.rx_bytes += 4200
    assert not cap.radio_status(20, 15.0) and cap.bytes_per_s == 4000.0  # so is 5 % more
    cap.rx_bytes += 3000
    assert cap.radio_status(20, 16.0) and cap.bytes_per_s == 3000.0  # a slower radio now
    fixed = LinkCapacity("/dev/ttyUSB0,57600")
    fixed.rx_bytes = 0
    fixed.radio_status(20, 1.0)
    fixed.rx_bytes = 100
    fixed.radio_status(20, 2.0)
    assert fixed.bytes_per_s == 5760.0  # the baud rate says it
