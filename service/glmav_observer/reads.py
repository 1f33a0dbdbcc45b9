"""What an output reads, so that the estimator builds only that (issue 28).

An estimator's state moves at the IMU rate (250 Hz at the design rates), and building a
record of every configuration at every IMU sample costs more than the estimate itself;
most consumers read far less (a plot at 10 Hz, a ground station at 30 Hz). Each sink
declares a :class:`Reads`: per record *stream* (``full``, ``c1``, ``c2``, ``c3``,
``active``, ``aided``, ``health``, ``measurement``, ``truth``) the rate it reads, in Hz of
vehicle time. The service builds the union of its sinks' reads
(:meth:`Reads.union`) and hands each sink only what it declared
(:class:`ReadsGate`). A sink without a ``reads`` attribute reads everything
(:data:`READS_ALL`): files and recordings keep every sample.

The rule that says whether a record is due (:func:`next_due_s`): a stream read at
``rate_hz`` gets a record at the first sample at or after each multiple of
``1/rate_hz`` s of vehicle time (the grid is absolute: no drift, no burst after a gap,
the same times whichever sample rate feeds it). A stream read at :data:`EVERY` gets every
record; at 0 none.

Decisions are published at once, whatever the rates: a fault isolated, an axis
recovered or a configuration switch makes the next ``active`` (and ``aided``) and
``health`` records due at the next IMU sample (:meth:`~glmav_observer.estimation.outputs.
RecordBuilder.decision`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from glmav_observer.configurations import AIDED, CONFIGS
from glmav_observer.records import HealthRecord, MeasurementRecord, TruthRecord, VelocityRecord

#: A rate that reads every record of a stream.
EVERY = math.inf
#: The record streams a sink can read, in the order of the velocity streams first
#: (the estimator's per-IMU-sample records), then the others.
VELOCITY_STREAMS: tuple[str, ...] = (*CONFIGS, "active", AIDED)
STREAMS: tuple[str, ...] = (*VELOCITY_STREAMS, "health", "measurement", "truth")


def next_due_s(t_s: float, rate_hz: float) -> float:
    """The vehicle time from which the next record of a stream read at ``rate_hz`` is due,
    after one was built at ``t_s``: the next multiple of ``1/rate_hz`` (``-inf`` for
    :data:`EVERY`: every record is due)."""
    if rate_hz == EVERY:
        return -math.inf
    return (math.floor(t_s * rate_hz) + 1) / rate_hz


def rate_reason(rate_hz: object) -> str | None:
    """None if ``rate_hz`` is a valid read rate, else the reason (for config errors)."""
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)):
        return 'must be a number of Hz (0: not read; inf or "every": every record)'
    if math.isnan(rate_hz) or rate_hz < 0.0:
        return "must be >= 0 Hz (0: not read; inf: every record)"
    if 0.0 < rate_hz < 0.01:
        return "must be 0 or at least 0.01 Hz"
    return None


@dataclass(frozen=True, slots=True)
class Reads:
    """Per stream (:data:`STREAMS`), the rate a consumer reads it at (Hz of vehicle time;
    :data:`EVERY` for every record; absent or 0: not read)."""

    rates_hz: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for stream, rate in self.rates_hz.items():
            if stream not in STREAMS:
                raise ValueError(f"unknown record stream {stream!r} (known: {', '.join(STREAMS)})")
            reason = rate_reason(rate)
            if reason is not None:
                raise ValueError(f"read rate of {stream}: {reason}, got {rate!r}")
        # every stream, in STREAMS order (a plain dict: a service's state is deep-copied)
        object.__setattr__(self, "rates_hz", {s: float(self.rates_hz.get(s, 0.0)) for s in STREAMS})

    def rate(self, stream: str) -> float:
        return self.rates_hz[stream]

    def union(self, other: Reads) -> Reads:
        """What either reads: per stream the higher rate."""
        return Reads({s: max(self.rates_hz[s], other.rates_hz[s]) for s in STREAMS})

    def covers(self, other: Reads) -> bool:
        """True if every record ``self`` gets is one ``other`` wants: the same rates
        (a sink whose reads equal the union needs no gate)."""
        return all(self.rates_hz[s] == other.rates_hz[s] for s in STREAMS)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly: ``"every"`` for :data:`EVERY`."""
        return {s: ("every" if r == EVERY else r) for s, r in self.rates_hz.items()}

    def describe(self) -> str:
        """One line for logs: ``full, c1, c2, c3 at 10 Hz; active at 50 Hz; ...``."""
        groups: dict[float, list[str]] = {}
        for s, r in self.rates_hz.items():
            if r > 0.0:
                groups.setdefault(r, []).append(s)
        if not groups:
            return "nothing"
        parts = []
        for r, streams in sorted(groups.items(), key=lambda kv: -kv[0]):
            at = "every record" if r == EVERY else f"{r:g} Hz"
            parts.append(f"{', '.join(streams)} at {at}")
        return "; ".join(parts)


#: Every record of every stream (files, recordings, ``--full-rate``, a sink that does not
#: say what it reads).
READS_ALL = Reads(dict.fromkeys(STREAMS, EVERY))
#: Nothing.
READS_NONE = Reads()
#: What a live service publishes on Zenoh by default (``[zenoh.rates]``), with the reason:
#: ``active`` (and ``aided`` while an axis is lost) at 50 Hz: what a consumer acts on,
#: faster than any ground station's display or control loop reads it (ODOMETRY at 30 Hz);
#: the paper's configurations at 10 Hz: for plots and comparison; ``health`` at 5 Hz: a
#: status, and every decision goes out at once anyway; ``measurement`` and ``truth`` at
#: every record: they come at the sensors' rate (30-50 Hz), not the IMU's.
LIVE_DEFAULT_RATES_HZ: dict[str, float] = {
    **dict.fromkeys(CONFIGS, 10.0),
    "active": 50.0,
    AIDED: 50.0,
    "health": 5.0,
    "measurement": EVERY,
    "truth": EVERY,
}
READS_LIVE_DEFAULT = Reads(LIVE_DEFAULT_RATES_HZ)


def reads_of(sink: object) -> Reads:
    """A sink's declared :class:`Reads` (``sink.reads``), or :data:`READS_ALL`."""
    reads = getattr(sink, "reads", None)
    return reads if isinstance(reads, Reads) else READS_ALL


def stream_of(record: object) -> str | None:
    """The stream a record belongs to (None: a kind no sink can decline, e.g. the
    autopilot's reference records of a flight-log replay)."""
    t = type(record)
    if t is VelocityRecord:
        return record.config  # type: ignore[attr-defined, no-any-return]
    if t is HealthRecord:
        return "health"
    if t is MeasurementRecord:
        return "measurement"
    if t is TruthRecord:
        return "truth"
    return None


class ReadsGate:
    """Passes a sink the records it reads out of those the service builds for the union
    of its sinks' reads (``built``): a stream the sink reads at the built rate passes
    whole, one it does not read is held back, and one it reads slower gets its records on
    its own grid, per (vehicle, stream), by the builder's rule (:func:`next_due_s`)."""

    def __init__(self, reads: Reads, built: Reads) -> None:
        self.reads = reads
        #: per stream: EVERY (pass whole), 0 (hold back) or the sink's slower rate
        self._rates = {s: EVERY if r == built.rate(s) else r for s, r in reads.rates_hz.items()}
        self._next: dict[tuple[int, str], float] = {}

    def admit(self, record: Any) -> bool:
        stream = stream_of(record)
        if stream is None:
            return True
        rate = self._rates[stream]
        if rate == EVERY:
            return True
        if rate == 0.0:
            return False
        key = (record.sysid, stream)
        t = record.t_boot_s
        if t < self._next.get(key, -math.inf):
            return False
        self._next[key] = next_due_s(t, rate)
        return True
