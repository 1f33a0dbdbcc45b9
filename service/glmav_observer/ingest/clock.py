"""The vehicle's clock: boot-relative time, ordering, duplicates, resets and gaps.

Design (latency vs ordering). Samples are processed **on arrival** when they are in
vehicle-time order, which is the normal case on every link we know (one autopilot
thread stamps and sends in order). No reorder buffer holds in-order samples back, so
ordering costs no latency (the daemon's p99 arrival-to-record goal is 2 ms, far below
any useful buffer). A sample older than the vehicle's current time by at most
``latency_window_s`` is still admitted (``REORDERED``): it becomes the held input from
now on, without rewinding the estimator. Older than that, or older than the last
sample of its own stream, it is dropped as ``late``; the same time stamp again on a
stream is a ``duplicate``.

A vehicle reboot sends time back to near zero. A single sample far in the past (or
far in the future) is much more likely a corrupt one, so a new timeline is adopted
only when ``confirm_samples`` consecutive samples agree on it (``RESET``: the caller
restarts that vehicle's bank); until then they are dropped and counted
(``time_backwards`` / ``time_jump``, or ``late`` when less than ``reset_backwards_s``
back: a vehicle rebooted soon after its previous boot is confirmed the same way).

Forward steps are confirmed the same way once they exceed ``confirm_forward_s`` (1 s,
the estimator's ``max_gap_s``: a step that long restarts the bank): one outlier frame
stamped +29 s is dropped (``time_jump``) and the genuine samples after it go on as
before; after a real outage the first ``confirm_samples - 1`` samples are dropped and
the rest accepted (a ``gap``; beyond ``jump_forward_s`` a ``clock_jump`` reset). Gaps
longer than ``gap_s`` are counted and reported.

Two sources with one system id (a spoofer, or two vehicles misconfigured alike) show
as a stream of samples off the timeline that advance together (each later than the
previous off-timeline one by at most ``reset_backwards_s``: a second running clock,
not scattered or repeated corrupt stamps): ``conflict_samples`` of them within ``conflict_window_s``
of host time (the vehicle's own time jumps between the two) make the clock ``conflicting`` (counted
``conflicting_sources``); it stays so until ``conflict_window_s`` passes without one.
A reboot gives ``confirm_samples`` of them (5), a jittery link none (``late`` samples
are on the timeline).

``time_usec`` larger than ``EPOCH_THRESHOLD_US`` (2001-09-09 as a UNIX time; 31 years
as an uptime) is UNIX-epoch time. It is mapped to boot time with SYSTEM_TIME's pair
(``time_unix_usec``, ``time_boot_ms``) when the vehicle sent one, else with the offset
to the vehicle's latest boot time fixed at the first such sample.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field
from enum import Enum

from glmav_observer.ingest.convert import TIME_NONE, TIME_USEC, TimeKind

EPOCH_THRESHOLD_US = 1_000_000_000_000_000


class Admission(Enum):
    """What to do with a sample, decided by the vehicle clock."""

    ACCEPT = "accept"  # in order: process now
    REORDERED = "reordered"  # slightly old (within the window): use as held input
    DUPLICATE = "duplicate"  # drop
    LATE = "late"  # drop
    PENDING = "pending"  # inconsistent with the timeline, held for confirmation: drop
    RESET = "reset"  # a new timeline is confirmed: restart the vehicle, then process


# The members as module globals for the per-message paths: in Python 3.11 reading a member
# through its class (``Admission.ACCEPT``) takes EnumType's slow attribute lookup, ~150 ns
# against ~10 for a global, and the clock decides about every message.
ACCEPT, REORDERED, DUPLICATE = Admission.ACCEPT, Admission.REORDERED, Admission.DUPLICATE
LATE, PENDING, RESET = Admission.LATE, Admission.PENDING, Admission.RESET


@dataclass(frozen=True, slots=True)
class ClockConfig:
    """Ordering policy (all in seconds of vehicle time)."""

    latency_window_s: float = 0.05
    reset_backwards_s: float = 2.0
    jump_forward_s: float = 30.0
    gap_s: float = 0.5
    confirm_samples: int = 5
    confirm_forward_s: float = 1.0
    conflict_samples: int = 20
    conflict_window_s: float = 5.0


@dataclass
class VehicleClock:
    """One vehicle's time base. ``counters`` is shared with the vehicle's counters."""

    config: ClockConfig
    counters: collections.Counter[str]
    t_now_s: float | None = None
    epoch_offset_us: int | None = None
    gaps: list[tuple[float, float]] = field(default_factory=list)
    _last_t_by_stream: dict[str, float] = field(default_factory=dict)
    _pending: list[float] = field(default_factory=list)
    #: host time of each recent off-timeline sample (for ``conflicting``)
    _off_timeline: collections.deque[float] = field(default_factory=collections.deque)
    _last_off_t_s: float | None = None
    #: host time of the sample that set ``t_now_s`` (None: not known, e.g. no host clock)
    _t_host_at_now_s: float | None = None
    #: two sources seem to share this system id (see the module docstring)
    conflicting: bool = False

    def note_system_time(self, time_unix_usec: int, time_boot_ms: int) -> None:
        """SYSTEM_TIME: the exact UNIX-to-boot offset, if the vehicle knows UNIX time."""
        if time_unix_usec > EPOCH_THRESHOLD_US:
            self.epoch_offset_us = int(time_unix_usec) - int(time_boot_ms) * 1000

    def to_boot_s(self, t_us: int, kind: TimeKind, t_host_s: float | None = None) -> float | None:
        """Vehicle boot time of a raw stamp; None if it cannot be mapped yet (counted).

        An untimed message (SIM_STATE) takes the vehicle's latest time, unless more than
        ``gap_s`` of host time (``t_host_s``, arrival) has passed since the sample that set
        it: after an outage the first untimed message arrives before the first stamped one,
        and the latest time is then the time before the outage (a truth sample of 5.5 s
        stamped 4.0 s, 1.6 m/s off the estimate it was compared with). It is dropped
        (``untimed_stale``): its vehicle time is not known."""
        if kind is TIME_NONE:
            if self.t_now_s is None:
                self.counters["untimed_before_clock"] += 1  # SIM_STATE before any stamp
            elif (
                t_host_s is not None
                and self._t_host_at_now_s is not None
                and t_host_s - self._t_host_at_now_s > self.config.gap_s
            ):
                self.counters["untimed_stale"] += 1
                return None
            return self.t_now_s
        if kind is TIME_USEC and t_us > EPOCH_THRESHOLD_US:
            self.counters["epoch_time_samples"] += 1
            if self.epoch_offset_us is None:
                if self.t_now_s is None:
                    self.counters["epoch_unmapped"] += 1
                    return None
                self.epoch_offset_us = t_us - round(self.t_now_s * 1e6)
            return (t_us - self.epoch_offset_us) * 1e-6
        return t_us * 1e-6

    def peek_boot_s(self, t_us: int, kind: TimeKind) -> float | None:
        """What :meth:`to_boot_s` would return for a stamped sample, without counting
        anything (None where it would count or learn something: an unmapped epoch time)."""
        if kind is TIME_USEC and t_us > EPOCH_THRESHOLD_US:
            if self.epoch_offset_us is None:
                return None
            return (t_us - self.epoch_offset_us) * 1e-6
        return t_us * 1e-6

    def admit(self, stream: str, t_s: float, t_host_s: float | None = None) -> Admission:
        """Decide about a sample of ``stream`` (message name) at vehicle time ``t_s``.

        ``t_host_s`` (arrival, host clock) times the detection of conflicting sources;
        without it there is none."""
        cfg = self.config
        now = self.t_now_s
        if now is None:
            self._adopt(stream, t_s, t_host_s)
            return ACCEPT
        if t_s < now - cfg.reset_backwards_s or t_s > now + cfg.confirm_forward_s:
            last_off, self._last_off_t_s = self._last_off_t_s, t_s
            if (
                t_host_s is not None
                and last_off is not None
                and 0.0 < t_s - last_off <= cfg.reset_backwards_s
            ):
                self._note_off_timeline(t_host_s)  # a second coherent timeline, not noise
            self._pending.append(t_s)
            p = self._pending
            if len(p) >= cfg.confirm_samples and max(p) - min(p) <= cfg.reset_backwards_s:
                self._pending = []
                if now < t_s <= now + cfg.jump_forward_s:  # an outage: same timeline, a gap
                    self.counters["gap"] += 1
                    self.gaps.append((now, t_s))
                    self._adopt(stream, t_s, t_host_s)
                    return ACCEPT
                self.counters["clock_reset" if t_s < now else "clock_jump"] += 1
                self._last_t_by_stream.clear()
                self.t_now_s = None
                self.epoch_offset_us = None
                self._adopt(stream, t_s, t_host_s)
                return RESET
            self.counters["time_backwards" if t_s < now else "time_jump"] += 1
            return PENDING
        if (
            self.conflicting
            and t_host_s is not None
            and t_host_s - self._off_timeline[-1] > cfg.conflict_window_s
        ):
            self.conflicting = False  # one source remains
        if t_s < now - cfg.latency_window_s:
            # older than the window: late, unless ``confirm_samples`` in a row agree on a
            # new timeline (a vehicle rebooted less than ``reset_backwards_s`` after boot)
            self._pending.append(t_s)
            p = self._pending
            if len(p) >= cfg.confirm_samples and max(p) - min(p) <= cfg.reset_backwards_s:
                self.counters["clock_reset"] += 1
                self._pending = []
                self._last_t_by_stream.clear()
                self.t_now_s = None
                self.epoch_offset_us = None
                self._adopt(stream, t_s, t_host_s)
                return RESET
            self.counters["late"] += 1
            return LATE
        self._pending.clear()  # a sample on the current timeline
        last = self._last_t_by_stream.get(stream)
        if last is not None and t_s == last:
            self.counters["duplicate"] += 1
            return DUPLICATE
        if last is not None and t_s < last:
            self.counters["late"] += 1
            return LATE
        if t_s >= now:
            if t_s - now > cfg.gap_s:
                self.counters["gap"] += 1
                self.gaps.append((now, t_s))
            self._adopt(stream, t_s, t_host_s)
            return ACCEPT
        self.counters["reordered"] += 1
        self._last_t_by_stream[stream] = t_s
        return REORDERED

    def _note_off_timeline(self, t_host_s: float) -> None:
        cfg = self.config
        dq = self._off_timeline
        dq.append(t_host_s)
        while dq and dq[0] < t_host_s - cfg.conflict_window_s:
            dq.popleft()
        if not self.conflicting and len(dq) >= cfg.conflict_samples:
            self.conflicting = True
            self.counters["conflicting_sources"] += 1

    def _adopt(self, stream: str, t_s: float, t_host_s: float | None = None) -> None:
        self.t_now_s = t_s
        self._t_host_at_now_s = t_host_s
        self._last_t_by_stream[stream] = t_s
