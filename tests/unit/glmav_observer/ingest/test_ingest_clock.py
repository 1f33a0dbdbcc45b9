"""Vehicle clock: order, duplicates, late samples, resets confirmed, epoch mapping, gaps."""

from __future__ import annotations

import collections

from glmav_observer.ingest.clock import Admission, ClockConfig, VehicleClock
from glmav_observer.ingest.convert import TimeKind


def _clock(**kw: float) -> VehicleClock:
    return VehicleClock(ClockConfig(**kw), collections.Counter())  # type: ignore[arg-type]


def test_in_order_samples_accepted_immediately() -> None:
    c = _clock()
    assert [c.admit("A", t) for t in (1.0, 1.01, 1.02)] == [Admission.ACCEPT] * 3
    assert c.t_now_s == 1.02


def test_duplicate_and_late_within_stream() -> None:
    c = _clock()
    c.admit("A", 1.0)
    c.admit("A", 1.04)
    assert c.admit("A", 1.04) is Admission.DUPLICATE
    assert c.admit("A", 1.03) is Admission.LATE  # older than its own stream's last
    assert c.counters["duplicate"] == 1
    assert c.counters["late"] == 1


def test_reordered_across_streams_within_window_then_late_beyond() -> None:
    c = _clock(latency_window_s=0.05)
    c.admit("A", 2.0)
    assert c.admit("B", 1.97) is Admission.REORDERED  # 30 ms old, window 50 ms
    assert c.admit("C", 1.90) is Admission.LATE  # 100 ms old
    assert c.t_now_s == 2.0


def test_single_backwards_sample_is_dropped_not_a_reset() -> None:
    c = _clock(confirm_samples=5)
    c.admit("A", 100.0)
    assert c.admit("A", 0.5) is Admission.PENDING
    assert c.admit("A", 100.01) is Admission.ACCEPT  # the timeline continues
    assert c.counters["time_backwards"] == 1
    assert c.counters["clock_reset"] == 0


def test_reboot_confirmed_after_consecutive_samples() -> None:
    c = _clock(confirm_samples=3)
    c.admit("A", 100.0)
    out = [c.admit("A", t) for t in (0.1, 0.11, 0.12)]
    assert out == [Admission.PENDING, Admission.PENDING, Admission.RESET]
    assert c.t_now_s == 0.12
    assert c.counters["clock_reset"] == 1
    assert c.admit("A", 0.13) is Admission.ACCEPT


def test_gap_counted() -> None:
    c = _clock(gap_s=0.5)
    c.admit("A", 1.0)
    c.admit("A", 2.0)
    assert c.counters["gap"] == 1
    assert c.gaps == [(1.0, 2.0)]


def test_epoch_time_usec_mapped_to_boot_time() -> None:
    c = _clock()
    unix_us = 1_700_000_000_000_000
    # nothing boot-relative seen yet: cannot map
    assert c.to_boot_s(unix_us, TimeKind.USEC) is None
    c.admit("ATTITUDE", c.to_boot_s(12_000_000, TimeKind.BOOT_MS) or 0.0)  # 12 s after boot
    assert c.to_boot_s(unix_us, TimeKind.USEC) == 12.0
    assert c.to_boot_s(unix_us + 4000, TimeKind.USEC) == 12.004
    # SYSTEM_TIME gives the exact offset
    c.note_system_time(unix_us + 1_000_000, 13_500)  # unix - boot = unix_us - 12.5 s
    assert abs((c.to_boot_s(unix_us, TimeKind.USEC) or 0.0) - 12.5) < 1e-9


def test_reboot_soon_after_boot_is_confirmed_too() -> None:
    """Back by less than reset_backwards_s (a reboot 1.5 s after boot): still a reset."""
    c = _clock(confirm_samples=3, reset_backwards_s=2.0, latency_window_s=0.05)
    for t in (1.0, 1.2, 1.5):
        c.admit("A", t)
    out = [c.admit(s, t) for s, t in (("A", 0.01), ("B", 0.02), ("A", 0.03))]
    assert out == [Admission.LATE, Admission.LATE, Admission.RESET]
    assert c.counters["clock_reset"] == 1
    # an isolated late sample among good ones is only late
    c2 = _clock(confirm_samples=3)
    for t in (1.0, 1.2, 1.5, 1.6):
        c2.admit("A", t)
    assert c2.admit("B", 0.5) is Admission.LATE
    assert c2.admit("A", 1.7) is Admission.ACCEPT
    assert c2.admit("B", 0.6) is Admission.LATE
    assert c2.counters["clock_reset"] == 0


def test_one_outlier_frame_29_s_ahead_is_dropped_and_the_stream_goes_on() -> None:
    """Issue 18.8: one frame stamped +29 s was accepted (under jump_forward_s = 30 s): the
    bank restarted on the 29 s "gap" and the genuine samples after it were late."""
    c = _clock()
    for k in range(100):
        assert c.admit("IMU", 10.0 + 0.004 * k) is Admission.ACCEPT
    assert c.admit("ATT", 10.4 + 29.0) is Admission.PENDING
    assert [c.admit("IMU", 10.4 + 0.004 * k) for k in range(50)] == [Admission.ACCEPT] * 50
    assert c.counters["time_jump"] == 1
    assert c.counters["gap"] == 0 and c.counters["late"] == 0 and c.counters["clock_jump"] == 0
    assert c.t_now_s is not None and c.t_now_s < 11.0


def test_a_real_outage_is_confirmed_then_a_gap() -> None:
    """After 1.5 s of silence the first ``confirm_samples - 1`` samples wait (16 ms at
    250 Hz), then the timeline goes on with one gap, no reset."""
    c = _clock(confirm_samples=5, confirm_forward_s=1.0)
    c.admit("IMU", 5.0)
    got = [c.admit("IMU", 6.5 + 0.004 * k) for k in range(8)]
    assert got == [Admission.PENDING] * 4 + [Admission.ACCEPT] * 4
    assert c.counters["gap"] == 1 and c.gaps == [(5.0, 6.516)]
    assert c.counters["clock_reset"] == 0 and c.counters["clock_jump"] == 0


def test_two_sources_with_one_system_id_are_flagged_until_one_remains() -> None:
    """Issue 18.9: two clocks 7 s apart, interleaved: samples off the current timeline
    that advance together are a second source; 20 within 5 s of host time flag it. A
    reboot (5 off-timeline samples) or scattered corrupt stamps do not."""
    c = _clock(conflict_samples=20, conflict_window_s=5.0)
    t_host = 0.0
    for k in range(250):  # 1 s of source A alone
        t_host = 0.004 * k
        c.admit("IMU", 3.0 + t_host, t_host)
    assert not c.conflicting
    for k in range(250, 500):  # B, 7 s ahead, interleaved with A
        t_host = 0.004 * k
        c.admit("IMU", 3.0 + t_host, t_host)
        c.admit("IMU", 10.0 + t_host, t_host)
    assert c.conflicting and c.counters["conflicting_sources"] == 1
    for k in range(500, 2000):  # A alone again: cleared once 5 s pass without B
        t_host = 0.004 * k
        c.admit("IMU", 3.0 + t_host + 0.0001, t_host)
        if k * 0.004 < 2.0 + 5.0 - 0.01:
            assert c.conflicting, k
    assert not c.conflicting
    # a reboot: 5 off-timeline samples, a reset, no conflict
    r = _clock()
    for k in range(100):
        r.admit("IMU", 100.0 + 0.004 * k, 0.004 * k)
    for k in range(10):
        r.admit("IMU", 0.1 + 0.004 * k, 0.4 + 0.004 * k)
    assert r.counters["clock_reset"] == 1 and not r.conflicting


def test_an_untimed_message_after_an_outage_is_not_stamped_with_the_time_before_it() -> None:
    """SIM_STATE has no time field: it takes the vehicle's latest time. After a 1.5 s outage
    the first SIM_STATE arrives before the first stamped message, when the latest time is
    still the one before the outage: it would be stamped 1.5 s early (the truth of 5.5 s
    compared with the estimate of 4.0 s, 1.6 m/s off in an accelerating cruise)."""
    c = _clock(gap_s=0.5, confirm_samples=2)
    t_host = 1000.0
    for k in range(5):  # 250 Hz stamped, arriving in real time
        c.admit("IMU", 3.98 + 0.004 * k, t_host + 0.004 * k)
    t_host += 0.016
    assert c.to_boot_s(0, TimeKind.NONE, t_host + 0.01) == 3.996  # 10 ms later: fine
    # 0.5 s of host time is the gap threshold: within it the latest time is used
    assert c.to_boot_s(0, TimeKind.NONE, t_host + 0.49) == 3.996
    # the outage: 1.5 s later the untimed message comes first and is dropped, counted
    assert c.to_boot_s(0, TimeKind.NONE, t_host + 1.5) is None
    assert c.counters["untimed_stale"] == 1
    # the stamped stream resumes (a gap, confirmed by 2 samples): untimed is stamped again
    c.admit("IMU", 5.52, t_host + 1.51)
    assert c.admit("IMU", 5.524, t_host + 1.514) is Admission.ACCEPT
    assert c.counters["gap"] == 1
    assert c.to_boot_s(0, TimeKind.NONE, t_host + 1.515) == 5.524
    # without a host clock (an offline source that has none) nothing changes
    assert c.to_boot_s(0, TimeKind.NONE) == 5.524
