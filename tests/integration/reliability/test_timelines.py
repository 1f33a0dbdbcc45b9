"""Issue 18.8 and 18.9 through the whole service: one outlier time stamp changes
nothing; two sources with one system id are flagged and not estimated."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.framing import FrameDecoder
from glmav_observer.records import HealthRecord, Record, VelocityRecord, flatten
from glmav_testkit.fuzzgen import sitl_stream
from glmav_testkit.sinks import MemorySink


def _t_s(msg: Any) -> float | None:
    if hasattr(msg, "time_usec"):
        return float(msg.time_usec) * 1e-6
    if hasattr(msg, "time_boot_ms"):
        return float(msg.time_boot_ms) * 1e-3
    return None


def _timed(frames: list[bytes]) -> list[tuple[float, bytes]]:
    """(vehicle time, frame): untimed frames (SIM_STATE, HEARTBEAT) take the last time."""
    dec = FrameDecoder(datagram=True)
    out: list[tuple[float, bytes]] = []
    t = 0.0
    for f in frames:
        (msg,) = dec.feed(f)
        t = _t_s(msg) or t
        out.append((t, f))
    return out


def _velocity(records: list[Record]) -> list[dict[str, Any]]:
    return [flatten(r) for r in records if isinstance(r, VelocityRecord)]


def test_one_frame_29_s_ahead_changes_no_record() -> None:
    """It used to restart the bank (a 29 s "gap") and drop 46 records."""
    frames = sitl_stream("cruise", 6.0, seed=5).frames
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    outlier = bytes(dialect.MAVLink_attitude_message(3000 + 29_000, 0, 0, 0, 0, 0, 0).pack(mav))
    runs = []
    for stream in (frames, [*frames[: len(frames) // 2], outlier, *frames[len(frames) // 2 :]]):
        sink = MemorySink()
        svc = Service(ServiceConfig(request_rates=False), [sink])
        for i, f in enumerate(stream):
            svc.feed_bytes("udp", f, 0.0004 * i)
        svc.close()
        runs.append((svc.summary(), _velocity(sink.records)))
    (_, clean), (summary, got) = runs
    counters = summary.vehicles[1].counters
    assert counters["time_jump"] == 1
    assert not any(k.startswith("estimator_restart") for k in counters), counters
    assert len(got) == len(clean) > 5000 and got == clean


def test_two_sources_with_one_sysid_raise_conflicting_sources_and_stop_estimation() -> None:
    """Source A flies a cruise from boot; source B, another vehicle configured with the
    same system id, booted 7 s earlier, is heard from A's 3 s to 5 s. Before: 3 m/s of
    error published as healthy. Now: flagged in health, no estimate while both talk,
    estimation again once B has been silent for conflict_window_s (5 s)."""
    a = _timed(sitl_stream("cruise", 12.0, seed=6).frames)
    b = [(t - 7.0, f) for t, f in _timed(sitl_stream("hover", 12.0, seed=7).frames) if t >= 10.0]
    b = [(t, f) for t, f in b if t < 5.0]  # B heard from A's 3 s to 5 s
    merged = sorted(a + b, key=lambda tf: tf[0])
    sink = MemorySink()
    svc = Service(ServiceConfig(request_rates=False), [sink])
    conflict_at: list[tuple[float, bool]] = []
    state = False
    during: list[Record] = []  # velocity records published while the flag is up

    def on_records(recs: list[Record]) -> None:
        v = svc.ingest.vehicles[1]
        if v.conflict:
            during.extend(r for r in recs if isinstance(r, VelocityRecord))

    svc.on_records = on_records
    for t, f in merged:
        svc.feed_bytes("udp", f, t)  # host time = A's vehicle time
        v = svc.ingest.vehicles.get(1)
        if v is not None and v.conflict != state:
            state = v.conflict
            conflict_at.append((t, state))
    svc.close()
    # flagged within 0.5 s of B's first frame (20 coherent samples at ~400/s: 50 ms);
    # cleared 5 s after B's last (10 s)
    assert [s for _, s in conflict_at] == [True, False], conflict_at
    assert 3.0 <= conflict_at[0][0] < 3.5 and 10.0 <= conflict_at[1][0] < 10.5
    assert svc.summary().service_counters["conflicting_sources"] == 1
    health = [r for r in sink.records if isinstance(r, HealthRecord)]
    flagged = [h for h in health if h.counters.get("conflicting_sources_active") == 1]
    assert flagged and all(
        h.axis_state == {"n": "suspect", "e": "suspect", "d": "suspect"} for h in flagged
    )
    assert any(h.counters.get("conflicting_sources_active") == 0 for h in health)
    # no estimate while both talk; estimation resumes afterwards (A's 10 s to 12 s)
    assert during == []
    vel = [r for r in sink.records if isinstance(r, VelocityRecord) and r.config == "active"]
    assert len([r for r in vel if r.t_boot_s > conflict_at[1][0]]) > 250  # ~1.9 s of 250 Hz
