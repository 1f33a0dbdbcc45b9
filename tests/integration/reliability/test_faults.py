"""Link faults between the vehicle and the service: loss, reordering, duplicates, delay,
outages and a vehicle reboot. The simulator sends through the loopback fault proxy
(``glmav_testkit.faultproxy``) to the service; accuracy is the service's RMSE of the
active estimate against the simulator's SIM_STATE truth (docs/reliability.md).
"""

from __future__ import annotations

import itertools
import socket
import time
from collections.abc import Callable

import pytest

from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.pipeline import IngestConfig
from glmav_sitl.runner import run
from glmav_testkit.faultproxy import FaultSpec, UdpFaultProxy, VehicleTimeDisorder
from glmav_testkit.faultrun import fly_through_proxy
from glmav_testkit.rel_helpers import live_service, wait_until


@pytest.mark.timeout(30)
def test_proxy_applies_each_fault_as_specified(free_udp_port: Callable[[], int]) -> None:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)  # hold all 2000
    rx.bind(("127.0.0.1", free_udp_port()))
    rx.settimeout(5.0)
    spec = FaultSpec(drop=0.2, duplicate=0.1, reorder=0.1, reorder_delay_s=0.01, seed=5)
    n = 2000
    with UdpFaultProxy(rx.getsockname(), spec) as proxy:
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for i in range(n):
            tx.sendto(i.to_bytes(4, "big"), ("127.0.0.1", proxy.port))
            if i % 100 == 99:
                time.sleep(0.002)  # let the proxy keep up (loopback buffers are finite)
        got: list[int] = []
        wait_until(lambda: proxy.stats().get("received", 0) == n, 10.0, "proxy received all")
        want = n - proxy.stats()["dropped"] + proxy.stats()["duplicated"]
        while len(got) < want:
            got.append(int.from_bytes(rx.recv(16), "big"))
        tx.close()
        st = proxy.stats()
    rx.close()
    # binomial counts: n p ± 4 sqrt(n p (1-p)) (drop: 400 ± 72; dup, reorder of the
    # ~1600 kept: 160 ± 48)
    assert abs(st["dropped"] - 400) < 72
    assert abs(st["duplicated"] - 0.1 * (n - st["dropped"])) < 48
    assert abs(st["reordered"] - 0.1 * (n - st["dropped"])) < 48
    assert st["forwarded"] == want
    assert len(set(got)) == n - st["dropped"]  # each kept datagram arrives (dups aside)
    late, top = 0, -1
    for x in got:
        late += x < top
        top = max(top, x)
    # a held-back datagram arrives after one sent later when the sender sent another
    # within the 10 ms hold: nearly always (2000 in bursts of 100); on a loaded machine a
    # stalled sender lets some through in order, hence half as the lower bound; late
    # duplicates add to the count
    assert st["reordered"] // 2 <= late <= st["reordered"] + st["duplicated"]


@pytest.mark.timeout(60)
def test_estimation_degrades_gracefully_under_loss_reorder_duplicates_and_delay() -> None:
    spec = FaultSpec(drop=0.2, reorder=0.05, duplicate=0.05, delay_s=0.02, jitter_s=0.01, seed=2)
    r = fly_through_proxy(spec, scenario="cruise", duration_s=10.0, speed=1.0, seed=1)
    # 20 % dropped by the proxy; the rest reaches the service (loopback, real time)
    assert abs(r.proxy["dropped"] / r.proxy["received"] - 0.2) < 0.02  # binomial, n ≈ 9300
    assert r.frames["frames_ok"] == r.proxy["forwarded"]
    # every duplicate and every sample arriving behind its stream is dropped and counted
    assert r.vehicle["duplicate"] > 0 and r.vehicle["late"] > 0 and r.vehicle["reordered"] > 0
    assert r.vehicle.get("gap", 0) == 0  # random loss leaves no gap > 0.5 s
    # graceful: the fault-free run measures ~0.02-0.03 m/s per axis, this one ~0.03
    # (docs/reliability.md); 0.1 m/s is the healthy-flight bound of the daemon's tests
    assert r.rmse_active_mps is not None and max(r.rmse_active_mps) <= 0.1, r.rmse_active_mps
    assert r.truth_samples > 200  # ~80 % of 7 s of 50 Hz truth after the 3 s settling


@pytest.mark.timeout(60)
def test_outage_is_reported_as_a_gap_and_estimation_resumes() -> None:
    r = fly_through_proxy(
        FaultSpec(seed=3), scenario="cruise", duration_s=10.0, speed=1.0, seed=1,
        blackout=(4.0, 1.5),
    )  # fmt: skip
    assert r.proxy["blackout"] > 1000  # 1.5 s of ~930 datagrams/s
    assert r.vehicle["gap"] == 1  # one gap reported (> gap_s = 0.5 s)
    # longer than max_gap_s (1 s): the bank restarts instead of integrating over the hole
    assert r.vehicle.get("estimator_restart_gap", 0) == 1
    t = r.t_records_s
    holes = [b - a for a, b in itertools.pairwise(t) if b - a > 0.5]
    # the outage, in vehicle time: 1.5 s of wall time; a simulator that fell behind wall
    # time under load catches up inside it, so the hole can be shorter, but it exceeds
    # max_gap_s (1 s) since the bank restarted
    assert len(holes) == 1 and 1.0 < holes[0] < 1.8
    assert t[-1] > 9.5  # estimates continue to the end of the flight
    assert r.rmse_active_mps is not None and max(r.rmse_active_mps) <= 0.1


@pytest.mark.timeout(60)
def test_vehicle_reboot_restarts_its_estimator_without_mixing_samples(
    free_udp_port: Callable[[], int],
) -> None:
    """Two flights of the same vehicle one after the other: the second starts its clock
    at zero again (a reboot). The service must detect the reset, restart the bank, and
    never emit a record of the second boot that uses samples of the first."""
    port = free_udp_port()
    conn = f"udpin:127.0.0.1:{port}"
    out = f"udpout:127.0.0.1:{port}"
    with live_service(conn) as live:
        run("cruise", [out], duration_s=6.0, speed=2.0, seed=1)
        wait_until(lambda: len(live.velocity()) > 500, 10.0, "first boot estimated")
        n_first = len(live.velocity())
        run("hover", [out], duration_s=6.0, speed=2.0, seed=2)
        wait_until(lambda: len(live.velocity()) > n_first + 500, 10.0, "second boot estimated")
        v = live.service.summary().vehicles[1]
        recs = live.velocity()
    assert v.counters["clock_reset"] == 1
    assert v.counters["estimator_restart_clock_reset"] == 1
    # records: boot 1 rising to ~6 s, then boot 2 from ~0 s again, each monotonic
    t = [r.t_boot_s for r in recs]
    drops = [i for i in range(1, len(t)) if t[i] < t[i - 1]]
    assert len(drops) == 1
    k = drops[0]
    assert t[k - 1] > 5.0 and t[k] < 1.5
    # the reset is confirmed after 5 consecutive samples (~20 ms at 250 Hz): the second
    # boot starts estimating as early as the first did (its first LOCAL_POSITION_NED),
    # and its first estimates are of the hovering vehicle (|v| ≈ 0), not carried over
    # from the cruise at 3-5 m/s
    assert t[k] < recs[0].t_boot_s + 0.1
    second = recs[k : k + 50]
    assert max(max(abs(x) for x in r.v_ned_mps) for r in second) < 0.5
    first_tail = recs[k - 50 : k]
    assert max(abs(r.v_ned_mps[0]) for r in first_tail) > 2.0  # cruising before the reboot


@pytest.mark.timeout(90)
def test_reorder_window_restores_a_jittery_link() -> None:
    """20 ms ± 10 ms of jitter reorders the 250 Hz IMU (4 ms apart) all the time: processed
    on arrival, most samples come behind their stream and are dropped as late (about 0.4
    m/s of error, docs/reliability.md). With ``[ingest] reorder_window_s`` = 0.06 s (2x the
    jitter's spread plus margin) every sample the window can reach is released in
    vehicle-time order.

    Judged against what the link really did in this run (:class:`VehicleTimeDisorder` on
    the proxy's output): on an idle machine a sample arrives at most the jitter (10 ms)
    behind the newest, so nothing may be late; on a busy one the simulator stalls and
    sends a burst, the jitter reorders the burst across the stall's span of vehicle time,
    and the samples beyond 60 ms behind are ones no 60 ms window can restore. Only those
    may be late (a busy-machine run of the README's command once had 19 here)."""
    window_s = 0.06
    config = ServiceConfig(request_rates=False, ingest=IngestConfig(reorder_window_s=window_s))
    spec = FaultSpec(delay_s=0.02, jitter_s=0.01, seed=1)
    link = VehicleTimeDisorder()
    r = fly_through_proxy(
        spec, scenario="cruise", duration_s=10.0, speed=1.0, seed=1, config=config, tap=link.feed
    )
    assert r.frames["frames_ok"] == r.proxy["forwarded"]
    # the jitter did reorder the link: ~2.5 IMU samples per 10 ms of spread come behind
    # a newer one (measured 30-50 % of the timed samples)
    assert link.samples > 3000 and link.behind > link.samples // 10, (link.samples, link.behind)
    # the buffer spans what a 60 ms window can reach: only samples beyond it may be late
    beyond = link.beyond(window_s)
    assert r.vehicle.get("late", 0) <= beyond, (r.vehicle, beyond, max(link.disorder_s))
    # and the window did the work: of the samples the link put behind a newer one, at most
    # a tenth were out of its reach (idle: none of ~4,600; load 11 with 4 busy processes:
    # 206, max disorder 92 ms), so most were restored
    assert beyond <= link.behind // 10, (beyond, link.behind, max(link.disorder_s))
    # healthy-flight bound of the daemon's tests; this cruise measures 0.097-0.099 m/s north
    # (the same on main before this test changed: the flight's, not the link's) and 0.03 on
    # e/d; 1 % of samples lost changes nothing the estimate needs
    assert r.rmse_active_mps is not None and max(r.rmse_active_mps) <= 0.1, r.rmse_active_mps
    assert r.truth_samples > 200  # ~7 s of 50 Hz truth after the settling time
