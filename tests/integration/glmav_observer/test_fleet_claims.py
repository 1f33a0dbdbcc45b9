"""Three ``serve --claim`` services see the same traffic (the generator fans it out to
three UDP ports, as mavlink-router would) and split the fleet through a Zenoh router
subprocess. One is SIGKILLed mid-flight: every vehicle keeps being published, its
vehicles are claimed again within 3 s, and no vehicle is held by two services for more
than one claim period (plus delivery)."""

from __future__ import annotations

import itertools
import json
import re
import signal
import subprocess
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from glmav_observer.fleet.claims import CLAIM_PERIOD_S
from glmav_testkit.fleet_helpers import OBS, SITL, record_tlog, wait_bound_udp
from glmav_testkit.zenoh_helpers import RouterProcess, client_config, client_session, wait_until

pytestmark = pytest.mark.timeout(240)

VEHICLES = 6
SERVICES = ("svc-a", "svc-b", "svc-c")
FLIGHT_S = 11.0
#: the failover goal of issue 16
TAKEOVER_S = 3.0


@pytest.fixture
def router(free_tcp_port: Callable[[], int]) -> Iterator[RouterProcess]:
    router = RouterProcess(free_tcp_port())
    router.start()
    yield router
    router.stop()


class Watch:
    """What a viewer sees: active estimates by vehicle, claim and alive tokens over time."""

    def __init__(self, session: Any) -> None:
        self.lock = threading.Lock()
        self.active: dict[int, list[tuple[float, int, float]]] = defaultdict(list)
        self.claims: list[tuple[float, int, str, bool]] = []
        self.alive: dict[str, set[int]] = defaultdict(set)
        self._subs = [
            session.declare_subscriber("glmav/*/velocity/active", self._on_active),
            session.liveliness().declare_subscriber(
                "glmav/@claim/**", self._on_claim, history=True
            ),
            session.liveliness().declare_subscriber(
                "glmav/@alive/**", self._on_alive, history=True
            ),
        ]

    def _on_active(self, s: zenoh.Sample) -> None:
        v = json.loads(s.payload.to_bytes())
        with self.lock:
            self.active[v["sysid"]].append((time.monotonic(), v["seq"], v["t_boot_s"]))

    def _on_claim(self, s: zenoh.Sample) -> None:
        _, _, sysid, zid = str(s.key_expr).split("/")
        put = s.kind == zenoh.SampleKind.PUT
        with self.lock:
            self.claims.append((time.monotonic(), int(sysid), zid, put))

    def _on_alive(self, s: zenoh.Sample) -> None:
        parts = str(s.key_expr).split("/")
        if len(parts) != 4:
            return
        with self.lock:
            if s.kind == zenoh.SampleKind.PUT:
                self.alive[parts[2]].add(int(parts[3]))
            else:
                self.alive[parts[2]].discard(int(parts[3]))

    def holders(self, sysid: int) -> set[str]:
        held: set[str] = set()
        with self.lock:
            for _, s, zid, put in self.claims:
                if s == sysid:
                    (held.add if put else held.discard)(zid)
        return held

    def double_claims(self) -> dict[int, list[float]]:
        """Per vehicle, the lengths of the intervals it had two or more claims."""
        out: dict[int, list[float]] = defaultdict(list)
        held: dict[int, set[str]] = defaultdict(set)
        since: dict[int, float] = {}
        with self.lock:
            events = sorted(self.claims)
        for t, sysid, zid, put in events:
            (held[sysid].add if put else held[sysid].discard)(zid)
            if len(held[sysid]) >= 2 and sysid not in since:
                since[sysid] = t
            elif len(held[sysid]) < 2 and sysid in since:
                out[sysid].append(t - since.pop(sysid))
        return out


def _service_toml(tmp: Path, service_id: str) -> Path:
    path = tmp / f"{service_id}.toml"
    path.write_text(f'[service]\nid = "{service_id}"\n', encoding="utf-8")
    return path


def test_a_killed_service_hands_its_vehicles_over_within_3_s(
    tmp_path: Path, router: RouterProcess, free_udp_port: Callable[[], int]
) -> None:
    tlog = record_tlog(tmp_path, FLIGHT_S)
    viewer = client_session(router.port)
    watch = Watch(viewer)
    zcfg = client_config(tmp_path / "client.json5", router.port)
    ports = [free_udp_port() for _ in SERVICES]
    services: dict[str, subprocess.Popen[str]] = {}
    logs: dict[str, str] = {}
    fleet: subprocess.Popen[str] | None = None
    try:
        for sid, port in zip(SERVICES, ports, strict=True):
            services[sid] = subprocess.Popen(
                [OBS, "serve", "--claim", "--workers", "1", "--zenoh", str(zcfg),
                 "--config", str(_service_toml(tmp_path, sid)),
                 "--link", f"udpin:127.0.0.1:{port}"],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            )  # fmt: skip
        for sid, port in zip(SERVICES, ports, strict=True):
            wait_bound_udp(port, services[sid])
        fleet = subprocess.Popen(
            [SITL, "fleet", "--tlog", str(tlog), "--vehicles", str(VEHICLES), "--stagger", "0.3",
             *(a for p in ports for a in ("--link", f"udpout:127.0.0.1:{p}"))],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        sysids = range(1, VEHICLES + 1)
        # settled: every vehicle published, held by exactly one service
        assert wait_until(
            lambda: all(watch.active.get(s) and len(watch.holders(s)) == 1 for s in sysids), 30
        ), {s: watch.holders(s) for s in sysids}
        # the fleet is split (the least-loaded member claims): more than one service works
        owners = {sid: set(v) for sid, v in watch.alive.items() if v}
        assert len(owners) >= 2, owners
        victim = max(owners, key=lambda sid: len(owners[sid]))
        orphans = sorted(owners[victim])
        time.sleep(1.0)  # a second of steady state before the kill (the flight goes on)
        t_kill = time.monotonic()
        services[victim].send_signal(signal.SIGKILL)
        services[victim].wait(timeout=10)
        assert fleet.wait(timeout=FLIGHT_S + 60) == 0
        t_end = time.monotonic()
    finally:
        for proc in services.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for sid, proc in services.items():
            logs[sid] = proc.communicate(timeout=60)[1]
        if fleet is not None and fleet.poll() is None:
            fleet.kill()
            fleet.wait()
    # the flight went on long enough after the kill to judge
    assert t_end - t_kill > 5.0
    gaps: dict[int, float] = {}
    with watch.lock:
        for sysid in sysids:
            times = [t for t, _, _ in watch.active[sysid]]
            # every vehicle kept being published to the end of its flight (staggered ≤ 0.3 s,
            # plus 0.5 s for the last samples' delivery on a loaded machine)
            assert times[-1] > t_end - 0.8 - 0.3, (sysid, t_end - times[-1])
            around = [b - a for a, b in itertools.pairwise(times) if b > t_kill]
            gaps[sysid] = max(around)
    print(f"victim {victim} held {orphans}; publication gaps after the kill (s): {gaps}")
    # the orphans are claimed at the survivors' next turn (≤ 0.5 s after the router drops the
    # dead session's tokens); the goal is 3 s. The other vehicles are not handed over: their
    # gaps are only the scheduling stalls of a loaded 2-core machine (0.45 s seen at load 9.6)
    for sysid in sysids:
        assert gaps[sysid] <= TAKEOVER_S, (sysid, gaps[sysid])
    # two claims at once only while the loser waits for its next turn (≤ one period) plus
    # the token's trip through the router and a thread wake-up on a loaded machine (0.25 s)
    doubles = watch.double_claims()
    print(f"double claims (s): {dict(doubles)}")
    for sysid, spans in doubles.items():
        assert max(spans) <= CLAIM_PERIOD_S + 0.25, (sysid, spans)
    # the new owner said so, with the time since the last health record it had seen
    survivors = "".join(text for sid, text in logs.items() if sid != victim)
    for sysid in orphans:
        m = re.search(rf"vehicle {sysid} taken over: ([\d.]+) s since", survivors)
        assert m is not None and float(m.group(1)) <= TAKEOVER_S, survivors[-2000:]
    # each orphan is held again by exactly one of the survivors
    for sysid in orphans:
        assert len(watch.holders(sysid)) <= 1  # released at the survivors' clean stop


def test_a_double_claim_is_settled_by_rank_at_the_next_turn(router: RouterProcess) -> None:
    from glmav_observer.fleet.claims import ClaimManager, rank

    sessions = [client_session(router.port) for _ in range(2)]
    # a period longer than the test: turns are run by hand below
    managers = [ClaimManager(s, "glmav", period_s=3600.0) for s in sessions]
    try:
        for m in managers:
            m.saw(7)
        # the race that the least-loaded choice makes rare: both claim before either has
        # seen the other's token (forced here through the claim step itself)
        for m in managers:
            assert m._claim(7)
            m.owned = frozenset({7})
        assert wait_until(lambda: all(len(m.claimants(7)) == 2 for m in managers), 10)
        for m in managers:
            m.turn()
        keeper = min(managers, key=lambda m: rank(7, m.zid))
        assert [7 in m.owned for m in managers] == [m is keeper for m in managers]
        # the withdrawal reaches the keeper: one claim left, the keeper's
        assert wait_until(lambda: keeper.claimants(7) == {keeper.zid}, 10)
    finally:
        for m in managers:
            m.close()
        for s in sessions:
            s.close()
