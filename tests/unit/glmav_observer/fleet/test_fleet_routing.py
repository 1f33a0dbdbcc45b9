"""Routing by the header's system id, stream splitting, output merging (no sockets)."""

from __future__ import annotations

import collections
import pickle

import pytest
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav2

from glmav_observer.app_summary import ServiceSummary
from glmav_observer.fleet.latency import LatencyHistogram
from glmav_observer.fleet.routing import StreamSplitter, sysid_of
from glmav_observer.fleet.worker_process import WorkerError, worker_rerun_mode
from glmav_observer.fleet.workers import merge_summaries
from glmav_observer.ingest.framing import FrameDecoder


def _att(sysid: int, i: int, *, v1: bool = False) -> bytes:
    m = (mav1 if v1 else mav2).MAVLink(None, srcSystem=sysid, srcComponent=1)
    return bytes(m.attitude_encode(10 * i, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(m))


def test_sysid_is_read_from_both_header_versions() -> None:
    assert sysid_of(_att(17, 1)) == 17
    assert sysid_of(_att(201, 1, v1=True)) == 201
    assert sysid_of(b"\x00\x01") is None
    assert sysid_of(b"\xfd\x01\x00") is None  # header cut short


def test_stream_splitter_gives_whole_frames_and_garbage_whatever_the_cuts() -> None:
    frames = [_att(s, i, v1=(i % 3 == 0)) for i in range(30) for s in (3, 9)]
    garbage = b"\x00garbage\x11"
    stream = garbage + b"".join(frames[:10]) + garbage + b"".join(frames[10:])
    for cut in (1, 7, 64, 1000):
        sp = StreamSplitter()
        pieces: list[tuple[int | None, bytes]] = []
        for k in range(0, len(stream), cut):
            pieces += sp.feed(stream[k : k + cut])
        whole = [(s, p) for s, p in pieces if s is not None]
        assert [p for _, p in whole] == frames
        assert [s for s, _ in whole] == [3, 9] * 30
        assert b"".join(p for s, p in pieces if s is None) == garbage * 2
        # every frame decodes in the worker's datagram mode; the garbage is counted there
        dec = FrameDecoder(datagram=True)
        n = sum(len(dec.feed(p)) for _, p in pieces)
        assert n == 60 and dec.counters.counts["garbage_bytes"] == 2 * len(garbage)


def test_a_corrupt_length_does_not_swallow_the_next_frames() -> None:
    a, b, c = _att(1, 1), _att(1, 2), _att(1, 3)
    bad = bytearray(a)
    bad[1] = 200  # the length byte now claims 200 bytes of payload
    sp = StreamSplitter()
    pieces = sp.feed(bytes(bad) + b + c)
    assert pieces == []  # the claimed 212 bytes have not all arrived: wait, as the decoder does
    for i in range(4, 12):
        pieces += sp.feed(_att(1, i))
    frames = [p for s, p in pieces if s is not None]
    # no magic byte after the claimed span: resync one byte past the bad magic, lose nothing
    assert frames == [b, c] + [_att(1, i) for i in range(4, 12)]
    assert b"".join(p for s, p in pieces if s is None) == bytes(bad)


def test_rerun_modes_with_workers() -> None:
    assert worker_rerun_mode("save:/tmp/x.rrd", 2) == "save:/tmp/x.w2.rrd"
    assert worker_rerun_mode("connect:rerun+http://127.0.0.1:9876/proxy", 1).startswith("connect")
    assert worker_rerun_mode("off", 0) == "off"
    with pytest.raises(WorkerError, match="use --workers 1 for spawn or serve"):
        worker_rerun_mode("serve", 0)


def test_summaries_merge_disjoint_vehicles_and_add_counters() -> None:
    a = ServiceSummary({}, {"udp": {"frames_ok": 5}}, {"x": 1}, records=10, messages=5)
    b = ServiceSummary({}, {"udp": {"frames_ok": 7, "bad_crc": 1}}, {"x": 2}, 3, 8)
    b.failed_sinks.append(("FileSink", "o.jsonl: write failed (No space left on device)"))
    m = merge_summaries([a, b], collections.Counter({"routed": 4}))
    assert m.link_counters == {"udp": {"bad_crc": 1, "frames_ok": 12}}
    assert m.service_counters == {"routed": 4, "x": 3}
    assert (m.records, m.messages) == (13, 13)
    # a worker's failed output reaches the service's summary (serve then exits 1, as
    # with one process; it used to be dropped here and serve said 0)
    assert m.failed_sinks == b.failed_sinks


def test_latency_histogram_quantiles_within_one_bin() -> None:
    h = LatencyHistogram()
    for k in range(1, 1001):
        h.add(k * 1e-6)  # 1 µs .. 1 ms, uniform
    # bins are 10^(1/50) wide (4.7 %): a quantile is its bin's upper edge
    assert h.quantile(0.5) == pytest.approx(500e-6, rel=0.047)
    assert h.quantile(0.99) == pytest.approx(990e-6, rel=0.047)
    g = LatencyHistogram()
    g.merge(h)
    assert g.n == 1000


def test_latency_blocks_leave_one_stall_out() -> None:
    """A 60 ms stall (40 datagrams late) among 5,000 at 1 ms: the run's p99 is the stall's,
    the median block's p99 is not (it spoils one block of 1,000 of the 5)."""
    h = LatencyHistogram()
    for k in range(5000):
        h.add(0.060 if 2500 <= k < 2540 else 0.001)
    # 40 of 5,000 late = 0.8 % < 1 %: the run's p99 is still the 1 ms bin; 60 of 5,000 is not
    assert h.quantile(0.99) == pytest.approx(1e-3, rel=0.047)
    g = LatencyHistogram()
    for k in range(5000):
        g.add(0.060 if 2500 <= k < 2560 else 0.001)
    assert g.quantile(0.99) == pytest.approx(0.060, rel=0.047)  # 60 > 50 = 1 % of 5,000
    # one block of the five holds the 60 late ones (60 > its 10 = 1 %): its p99 is 60 ms,
    # the four others' 1 ms, and the median block's 1 ms (bins 4.7 % wide)
    assert sum(g.block_p99) == 5
    assert g.block_quantile(0.5) == pytest.approx(1e-3, rel=0.047)
    assert g.block_quantile(1.0) == pytest.approx(0.060, rel=0.047)
    # merged (two workers): the finished blocks add, and so does the statistic
    m = LatencyHistogram()
    m.merge(g)
    m.merge(h)
    assert sum(m.block_p99) == 10
    assert m.block_quantile(0.5) == pytest.approx(1e-3, rel=0.047)
    # pickled between processes with its partial block (the workers' results are)
    g.add(0.002)
    r = pickle.loads(pickle.dumps(g))
    assert (r.counts, r.block_p99, r.summary_ms()) == (g.counts, g.block_p99, g.summary_ms())
