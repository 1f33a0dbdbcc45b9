"""Three ``serve --claim`` services see the same traffic (the generator fans it out to
three UDP ports, as mavlink-router would) and split the fleet through a Zenoh router
subprocess. The flight (a hover) has a 1 m/s bias on the measured east velocity from 6 s,
which every owner isolates. One service is SIGKILLed mid-flight, mid-fault: every vehicle
keeps being published, its vehicles are claimed again within 3 s, no vehicle is held by
two services for more than one claim period (plus delivery), and the new owner continues
from the last published state: the fault stays isolated, the estimate goes on from the
dead owner's (a cold start would take the biased measurement)."""

from __future__ import annotations

import itertools
import json
import logging
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

from glmav_observer.estimation.seed import SEED_MAX_AGE_S
from glmav_observer.fleet.claims import CLAIM_PERIOD_S
from glmav_testkit.fleet_helpers import OBS, SITL, record_fault_tlog, wait_bound_udp
from glmav_testkit.zenoh_helpers import RouterProcess, client_config, client_session, wait_until

#: failover timing with six processes in real time: alone among the suite's workers
pytestmark = [pytest.mark.timeout(240), pytest.mark.exclusive]

VEHICLES = 6
SERVICES = ("svc-a", "svc-b", "svc-c")
#: the recorded flight: the generator is stopped once every vehicle has been published
#: POST_KILL_S of vehicle time past the kill, so this only has to outlast that when the
#: services read their links seconds late (seen: 7 s behind the generator with the suite
#: on both cores) and the kill waits for the victim's isolation to show (≤ 20 + 20 s)
FLIGHT_S = 40.0
#: vehicle time every vehicle is published for after the kill before the flight ends:
#: the takeover (≤ 3 s) and the new owner's first seconds
POST_KILL_S = 6.0
#: the measured east velocity's bias (m/s) from T_FAULT_S (s of the flight) to its end
FAULT_MPS = 1.0
#: after the FDI has armed on every vehicle: the services claim ~1.5 s into the flight
#: and the FDI arms 1.5 s of vetted samples (+ 0.6 s vetting delay) later; a bias that
#: starts before is learnt as part of the reference
T_FAULT_S = 6.0
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
        #: per vehicle: (monotonic s, seq, t_boot_s, v_ned_mps, service_id, source_config)
        self.active: dict[int, list[tuple[float, int, float, list[float], str, str]]] = defaultdict(
            list
        )
        #: per vehicle: (monotonic s, service_id, health payload)
        self.health: dict[int, list[tuple[float, str, dict[str, Any]]]] = defaultdict(list)
        #: per vehicle: t_boot_s -> truth v_ned_mps (SIM_STATE, whoever published it)
        self.truth: dict[int, dict[float, list[float]]] = defaultdict(dict)
        self.claims: list[tuple[float, int, str, bool]] = []
        self.alive: dict[str, set[int]] = defaultdict(set)
        self._subs = [
            session.declare_subscriber("glmav/*/velocity/active", self._on_active),
            session.declare_subscriber("glmav/*/health", self._on_health),
            session.declare_subscriber("glmav/*/truth", self._on_truth),
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
            self.active[v["sysid"]].append(
                (time.monotonic(), v["seq"], v["t_boot_s"], v["v_ned_mps"], v["service_id"],
                 v["source_config"])
            )  # fmt: skip

    def _on_health(self, s: zenoh.Sample) -> None:
        h = json.loads(s.payload.to_bytes())
        with self.lock:
            self.health[h["sysid"]].append((time.monotonic(), h["service_id"], h))

    def _on_truth(self, s: zenoh.Sample) -> None:
        v = json.loads(s.payload.to_bytes())
        with self.lock:
            self.truth[v["sysid"]][v["t_boot_s"]] = v["v_ned_mps"]

    def published_past(self, sysids: range, t_boot_s: float) -> bool:
        """Every vehicle's active estimate has been published at or past ``t_boot_s``."""
        with self.lock:
            return all(self.active[s] and self.active[s][-1][2] >= t_boot_s for s in sysids)

    def faulty_e(self, sysid: int, service_id: str) -> bool:
        """The latest health of ``sysid`` from ``service_id`` has the east axis isolated."""
        with self.lock:
            mine = [h for _, sid, h in self.health[sysid] if sid == service_id]
        return bool(mine) and mine[-1]["axis_state"]["e"] == "faulty"

    def truth_at(self, sysid: int, t_boot_s: float) -> list[float]:
        """The truth at vehicle time ``t_boot_s``: the nearest SIM_STATE (50 Hz)."""
        with self.lock:
            t = min(self.truth[sysid], key=lambda tt: abs(tt - t_boot_s))
            assert abs(t - t_boot_s) <= 0.03, (sysid, t_boot_s, t)
            return self.truth[sysid][t]

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


def _wait_quiet(watch: Watch, quiet_s: float, timeout_s: float) -> None:
    """Wait until no health record has arrived for ``quiet_s`` (at most ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with watch.lock:
            last = max((h[-1][0] for h in watch.health.values() if h), default=0.0)
        if time.monotonic() - last >= quiet_s:
            return
        time.sleep(0.1)


def _state_isolates_e(session: Any, service_id: str, sysids: list[int]) -> bool:
    """``service_id``'s state queryable answers for every vehicle of ``sysids`` with the
    east axis isolated (the state a survivor would continue from)."""
    isolated: set[int] = set()
    for reply in session.get("glmav/*/state", consolidation=zenoh.ConsolidationMode.NONE,
                             timeout=2.0):  # fmt: skip
        if reply.ok is None:
            continue
        state = json.loads(reply.ok.payload.to_bytes())
        health = state.get("health") or {}
        if state.get("service_id") == service_id and any(
            f.get("axis") == "e" for f in health.get("isolated_faults") or ()
        ):
            isolated.add(int(state["sysid"]))
    return isolated >= set(sysids)


def _service_toml(tmp: Path, service_id: str) -> Path:
    path = tmp / f"{service_id}.toml"
    path.write_text(f'[service]\nid = "{service_id}"\n', encoding="utf-8")
    return path


def test_a_killed_service_hands_its_vehicles_over_within_3_s(
    tmp_path: Path, router: RouterProcess, free_udp_port: Callable[[], int]
) -> None:
    tlog = record_fault_tlog(
        tmp_path, FLIGHT_S, axis="e", kind="bias", t_start_s=T_FAULT_S, magnitude=FAULT_MPS
    )
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
                # --full-rate: the seed's check below compares the victim's record at the
                # state's time, so it wants one every IMU step (4 ms), not active's 50 Hz
                [OBS, "serve", "--claim", "--workers", "1", "--zenoh", str(zcfg), "--full-rate",
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
        # the kill comes mid-fault: every vehicle of the victim has its east axis isolated
        assert wait_until(lambda: all(watch.faulty_e(s, victim) for s in orphans), 20), {
            s: [(h["t_boot_s"], h["axis_state"]) for _, _, h in watch.health[s][-1:]]
            for s in orphans
        }
        # ... and the victim's state queryable already answers with it: the survivors
        # continue from the last state they got by their query (every claim period), so
        # the kill waits for that state plus two of their turns (a reply that is late
        # under load: one turn, CI saw a survivor's newest state 1.0 s old at the kill)
        assert wait_until(lambda: _state_isolates_e(viewer, victim, orphans), 20)
        time.sleep(2 * CLAIM_PERIOD_S + 0.5)
        t_kill = time.monotonic()
        t_boot_kill = [watch.health[s][-1][2]["t_boot_s"] for s in orphans]
        print(f"kill at t_boot {t_boot_kill} s")
        services[victim].send_signal(signal.SIGKILL)
        services[victim].wait(timeout=10)
        # the flight goes on until every vehicle is published POST_KILL_S past the kill
        # (vehicle time: the same however late the services read), then ends
        t_boot_end = max(t_boot_kill) + POST_KILL_S
        assert t_boot_end < FLIGHT_S - 1.0, t_boot_end  # the tlog outlasts it
        assert wait_until(lambda: watch.published_past(sysids, t_boot_end), 60), {
            s: watch.active[s][-1][2] for s in sysids
        }
        fleet.send_signal(signal.SIGINT)
        assert fleet.wait(timeout=30) == 0
        t_end = time.monotonic()
        # a loaded service reads its link seconds late: let it work off what the kernel
        # holds before it is stopped (its health stops arriving once it has)
        _wait_quiet(watch, quiet_s=1.0, timeout_s=20.0)
    finally:
        for proc in services.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for sid, proc in services.items():
            logs[sid] = proc.communicate(timeout=60)[1]
        if fleet is not None and fleet.poll() is None:
            fleet.kill()
            fleet.wait()
    # the flight went on long enough after the kill to judge (POST_KILL_S of vehicle time)
    assert t_end - t_kill > POST_KILL_S - 1.0
    gaps: dict[int, float] = {}
    with watch.lock:
        for sysid in sysids:
            times = [a[0] for a in watch.active[sysid]]
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
    _assert_continued(watch, victim, orphans, survivors)


def _assert_continued(watch: Watch, victim: str, orphans: list[int], survivors: str) -> None:
    """The new owner went on from the state the victim published last, not from scratch."""
    said = re.findall(
        r"vehicle \d+(?: taken over|: continuing| continued| started cold).*", survivors
    )
    print("\n".join(said))
    for sysid in orphans:
        m = re.search(
            rf"vehicle {sysid} continued from its last published state: ([\d.]+) s old", survivors
        )
        assert m is not None, survivors[-3000:]
        age_s = float(m.group(1))
        # the state is the last the survivors got by their 2 Hz state query, and the seed is
        # applied at the first sample after the claim: ≤ one query period before the kill
        # plus the takeover (≤ 3 s, measured above), within the estimator's bound
        assert age_s <= SEED_MAX_AGE_S
        with watch.lock:
            old = [a for a in watch.active[sysid] if a[4] == victim]
            new = [a for a in watch.active[sysid] if a[4] != victim and a[0] > old[-1][0]]
            t_last = old[-1][0]  # survivors' records from before (a settled double claim) left out
            new_health = [h for t, sid, h in watch.health[sysid] if sid != victim and t > t_last]
            old_health = [h for _, sid, h in watch.health[sysid] if sid == victim]
        first = new[0]
        # the seed: the victim's active estimate at t_boot(first) − age (records every 4 ms)
        t_state = first[2] - age_s
        seeded = min(old, key=lambda a: abs(a[2] - t_state))
        assert abs(seeded[2] - t_state) <= 0.05, (sysid, seeded[2], t_state)
        truth_0 = watch.truth_at(sysid, seeded[2])
        truth_1 = watch.truth_at(sysid, first[2])
        print(
            f"vehicle {sysid}: state {age_s:.3f} s old; first new record at t_boot "
            f"{first[2]:.3f} s: v_ned {[round(x, 3) for x in first[3]]}, truth "
            f"{[round(x, 3) for x in truth_1]}; the victim's at {seeded[2]:.3f} s: "
            f"{[round(x, 3) for x in seeded[3]]}, truth {[round(x, 3) for x in truth_0]}"
        )
        for j in range(3):
            err_0 = seeded[3][j] - truth_0[j]
            err_1 = first[3][j] - truth_1[j]
            dv = truth_1[j] - truth_0[j]
            # the new owner starts from the victim's estimate: its error is the victim's
            # then, plus the velocity change over the age (it has no IMU for it; a hover:
            # small), plus 0.02 m/s: the nearest record and truth are up to 2 ms and 10 ms
            # off the state's and the first record's times, and one IMU step (4 ms) of
            # dead reckoning, at |V̇| ≤ 1 m/s² in this hover
            assert abs(err_1) <= abs(err_0) + abs(dv) + 0.02, (sysid, j, err_1, err_0, dv)
        # the east axis is the faulty one: a cold start would take its measurement, 1 m/s off
        assert abs(first[3][1] - truth_1[1]) < FAULT_MPS / 2
        # the isolation goes on: the hand-over configuration (c3, east lost), the same fault
        assert first[5] == "c3", first
        fault_0 = [f for f in old_health[-1]["isolated_faults"] if f["axis"] == "e"]
        h1 = new_health[0]
        assert h1["axis_state"]["e"] in ("faulty", "recovering"), h1
        fault_1 = [f for f in h1["isolated_faults"] if f["axis"] == "e"]
        assert fault_1 and fault_0 and fault_1[0]["kind"] == fault_0[0]["kind"] == "bias"
        assert fault_1[0]["t_detect_s"] == fault_0[0]["t_detect_s"]
        # ... and stays isolated while the bias lasts (to the end of the flight), or until
        # a gap restarts the estimator cold: more than max_gap_s (1 s) of the vehicle's
        # stream lost, which is a restart by design (docs/reliability.md), not a takeover's
        # failure; seen once in ~5 runs here (the survivors, the router and the generator
        # share 2 cores: a service stalled > 1 s loses datagrams in the kernel)
        with watch.lock:
            later = [h for t, sid, h in watch.health[sysid] if sid != victim and t > t_last]
        gaps0 = h1["counters"].get("estimator_restart_gap", 0)
        before_gap = list(
            itertools.takewhile(
                lambda h, g0=gaps0: h["counters"].get("estimator_restart_gap", 0) == g0, later
            )
        )
        # at least 3 s of the continued isolation are judged (the fault lasts to the end,
        # ~10 s after the takeover): a restart right after the takeover fails here
        assert before_gap[-1]["t_boot_s"] - h1["t_boot_s"] >= 3.0, (
            h1["t_boot_s"],
            [(h["t_boot_s"], h["counters"]) for h in later[len(before_gap) :][:1]],
        )
        assert all(h["axis_state"]["e"] in ("faulty", "recovering") for h in before_gap), [
            h["axis_state"]
            for h in before_gap
            if h["axis_state"]["e"] not in ("faulty", "recovering")
        ]


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


def test_claims_of_a_non_member_flood_are_ignored_with_one_warning(
    router: RouterProcess, caplog: pytest.LogCaptureFixture
) -> None:
    """Issue 31 D2: liveliness tokens glmav/@claim/{1..255}/0 from a session that is not a
    member stopped every record (31,150 messages, 0 records, no warning)."""
    from glmav_observer.fleet.claims import ClaimManager, claim_key

    rogue, session = client_session(router.port), client_session(router.port)
    tokens = [rogue.liveliness().declare_token(claim_key("glmav", s, "0")) for s in range(1, 256)]
    manager = ClaimManager(session, "glmav", period_s=3600.0)  # turns run by hand
    try:
        assert wait_until(lambda: len(manager.claimants(255)) == 1, 10)  # the flood is in
        with caplog.at_level(logging.WARNING, logger="glmav_observer.fleet.claims"):
            for _ in range(3):  # the chosen one claims at once; anyone after 2 turns
                for s in (1, 2, 3):
                    manager.saw(s)
                manager.turn()
        assert manager.owned == {1, 2, 3}
        assert manager.ignored_claims > 0
        warned = [r.getMessage() for r in caplog.records if "not a member" in r.getMessage()]
        assert len(warned) == 1 and "claims by 0 ignored" in warned[0], warned
    finally:
        manager.close()
        for t in tokens:
            t.undeclare()
        rogue.close()
        session.close()


def test_a_member_that_publishes_nothing_loses_its_claim(
    router: RouterProcess, caplog: pytest.LogCaptureFixture
) -> None:
    """A member (it holds the members token) claims vehicles 5 and 6 and publishes health
    for 6 only: 5 is taken back after ``takeback_s`` with a warning, 6 stays its own."""
    from glmav_observer.fleet.claims import ClaimManager, claim_key, members_key
    from glmav_observer.publish.zenoh_keys import encode_json

    rogue, session = client_session(router.port), client_session(router.port)
    entities = [
        rogue.liveliness().declare_token(members_key("glmav", "quiet")),
        rogue.liveliness().declare_token(claim_key("glmav", 5, "quiet")),
        rogue.liveliness().declare_token(claim_key("glmav", 6, "quiet")),
    ]
    period_s = 0.1
    manager = ClaimManager(session, "glmav", period_s=3600.0)
    manager.period_s, manager.takeback_s = period_s, 4 * period_s  # turns run by hand
    try:
        assert wait_until(lambda: len(manager.claimants(6)) == 1, 10)
        assert wait_until(lambda: "quiet" in manager._members, 10)
        with caplog.at_level(logging.WARNING, logger="glmav_observer.fleet.claims"):
            t_end = time.monotonic() + 10 * manager.takeback_s
            while time.monotonic() < t_end and 5 not in manager.owned:
                rogue.put("glmav/6/health", encode_json({"sysid": 6, "t_boot_s": 1.0}))
                manager.saw(5)
                manager.saw(6)
                manager.turn()
                time.sleep(period_s)
        assert 5 in manager.owned and 6 not in manager.owned
        assert manager.taken_back == 1
        warned = [r.getMessage() for r in caplog.records if "taken back" in r.getMessage()]
        assert len(warned) == 1 and warned[0].startswith("vehicle 5 taken back"), warned
    finally:
        manager.close()
        for e in entities:
            e.undeclare()
        rogue.close()
        session.close()
