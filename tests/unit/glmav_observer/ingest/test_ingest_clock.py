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
