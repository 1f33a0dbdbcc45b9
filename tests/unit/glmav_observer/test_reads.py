"""What an output reads (glmav_observer.reads): the due rule, the union, the gate."""

from __future__ import annotations

import itertools
import math

import pytest

from glmav_observer.reads import (
    EVERY,
    READS_ALL,
    READS_NONE,
    STREAMS,
    Reads,
    ReadsGate,
    next_due_s,
    reads_of,
    stream_of,
)
from glmav_observer.records import HealthRecord, VelocityRecord


def _vel(config: str, t: float, sysid: int = 1) -> VelocityRecord:
    z = (0.0, 0.0, 0.0)
    return VelocityRecord(sysid, config, t, z, z, None, "ok", 1, None, None)


def test_next_due_is_the_next_multiple_of_the_period() -> None:
    assert next_due_s(0.0, 10.0) == pytest.approx(0.1, abs=0.0)
    assert next_due_s(0.1234, 10.0) == pytest.approx(0.2, abs=1e-15)
    assert next_due_s(12.0, 50.0) == pytest.approx(12.02, abs=1e-12)
    assert next_due_s(5.0, EVERY) == -math.inf


def test_a_stream_read_at_10_hz_from_250_hz_samples_gets_one_record_per_period() -> None:
    # 250 Hz IMU steps over 10 s: 10 Hz on the absolute grid is exactly 100 records, one
    # per 0.1 s interval (the first sample at or after each multiple of 0.1 s)
    gate = ReadsGate(Reads({"full": 10.0}), READS_ALL)
    times = [k * 0.004 for k in range(2500)]
    kept = [t for t in times if gate.admit(_vel("full", t))]
    assert len(kept) == 100
    assert all(math.floor(t * 10.0 + 1e-9) == k for k, t in enumerate(kept))
    assert max(b - a for a, b in itertools.pairwise(kept)) < 0.1 + 0.004 + 1e-9


def test_union_takes_the_higher_rate_and_covers_compares_every_stream() -> None:
    a = Reads({"active": 50.0, "health": 5.0})
    b = Reads({"active": 30.0, "full": 10.0})
    u = a.union(b)
    assert u.rate("active") == 50.0 and u.rate("full") == 10.0 and u.rate("health") == 5.0
    assert u.rate("c1") == 0.0
    assert READS_ALL.covers(READS_ALL) and not a.covers(u)
    assert READS_NONE.union(READS_ALL) == READS_ALL


def test_the_gate_passes_equal_rates_whole_and_holds_back_what_is_not_read() -> None:
    built = Reads({"full": 10.0, "active": EVERY, "health": 5.0})
    gate = ReadsGate(Reads({"full": 10.0, "health": 5.0}), built)
    # full at the built rate: passed whole, even two records 1 ms apart (the builder's due)
    assert gate.admit(_vel("full", 1.0)) and gate.admit(_vel("full", 1.001))
    assert not gate.admit(_vel("active", 1.0))  # not read by this sink
    h = HealthRecord(1, 1.0, 1, "full", (0, 0, 0), (0, 0, 0), {}, (), {}, {})
    assert gate.admit(h)
    assert stream_of(h) == "health" and stream_of(object()) is None
    # per vehicle: vehicle 2's grid is its own
    slow = ReadsGate(Reads({"active": 10.0}), built)
    assert slow.admit(_vel("active", 1.0)) and not slow.admit(_vel("active", 1.05))
    assert slow.admit(_vel("active", 1.05, sysid=2))
    assert slow.admit(_vel("active", 1.1))


@pytest.mark.parametrize(
    ("rates", "why"),
    [
        ({"velocity": 10.0}, "unknown record stream"),
        ({"full": -1.0}, ">= 0"),
        ({"full": math.nan}, ">= 0"),
        ({"full": "fast"}, "number of Hz"),
        ({"full": 0.001}, "at least 0.01"),
    ],
)
def test_bad_reads_are_refused_with_the_reason(rates: dict[str, object], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        Reads(rates)  # type: ignore[arg-type]


def test_a_sink_that_does_not_say_reads_everything() -> None:
    class Plain:
        def write(self, record: object) -> None: ...

    assert reads_of(Plain()) == READS_ALL
    assert set(READS_ALL.rates_hz) == set(STREAMS)
    assert "at every record" in READS_ALL.describe()
    assert READS_NONE.describe() == "nothing"
