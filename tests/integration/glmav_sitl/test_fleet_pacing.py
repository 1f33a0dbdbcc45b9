"""The fleet generator sends every frame, in each vehicle's recorded order and at its
recorded rate (a real UDP socket on loopback reads them)."""

from __future__ import annotations

import itertools
import socket
import statistics
import threading
import time
from collections import defaultdict
from pathlib import Path

from glmav_sitl.fleet import LogArrays, load_tlog, record_tlog, run_fleet, start_offsets_s


def test_every_frame_in_order_at_the_recorded_rate(tmp_path: Path) -> None:
    log = load_tlog(record_tlog(tmp_path / "d.tlog", 2.0, truth=False))
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    got: list[tuple[float, bytes]] = []

    def read() -> None:
        while True:
            try:
                got.append((time.perf_counter(), rx.recv(4096)))
            except TimeoutError:
                return

    reader = threading.Thread(target=read)
    reader.start()
    summary = run_fleet(
        [log], [f"udpout:127.0.0.1:{rx.getsockname()[1]}"], 3, stagger_s=0.6, sysid_base=11
    )
    reader.join()
    rx.close()
    assert summary.frames_sent == 3 * len(log.frames) and summary.frames_failed == 0
    assert len(got) == summary.frames_sent  # loopback, a 4 MB buffer: nothing dropped
    by_vehicle: dict[int, list[tuple[float, bytes]]] = defaultdict(list)
    for t, d in got:
        by_vehicle[d[5]].append((t, d))
    arrays = LogArrays(log)
    imu_msgid = 105  # HIGHRES_IMU, 250 Hz
    for sysid in (11, 12, 13):
        frames = by_vehicle[sysid]
        # each vehicle's frames in the log's order, rewritten for its system id
        assert [d for _, d in frames] == arrays.rewrite(0, len(log.frames), sysid)
        imu = [t for t, d in frames if d[7] | d[8] << 8 | d[9] << 16 == imu_msgid]
        gaps = [b - a for a, b in itertools.pairwise(imu)]
        # sent when due, not a window's worth at once: the median gap is the recorded
        # 4 ms (a stall of the loaded machine makes a burst of a few gaps ~0 and one long
        # gap, which the median ignores); ±25 % leaves room for the sleep's granularity
        assert 0.003 <= statistics.median(gaps) <= 0.005, statistics.median(gaps)
    # vehicle k starts (k + {k/φ}) · stagger / K after the first: 0.324 s and 0.124 s
    # apart here. A stall of the loaded machine delays a vehicle's first frame and so
    # changes a gap: the generator's own worst lateness (it sends late, never early) plus
    # 0.1 s for the reader thread's stamping is left for that above, half the gap below
    starts = [by_vehicle[s][0][0] for s in (11, 12, 13)]
    offsets = start_offsets_s(3, 0.6)
    for k in (1, 2):
        gap, expected = starts[k] - starts[k - 1], offsets[k] - offsets[k - 1]
        late = summary.late_max_s
        assert expected / 2 <= gap <= expected + late + 0.1, (k, gap, expected, late)
