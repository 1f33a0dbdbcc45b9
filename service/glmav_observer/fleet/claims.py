"""``serve --claim``: several services see the same traffic; each vehicle is estimated once.

Services that receive the same MAVLink (fanned out by mavlink-router, or one UDP
broadcast) split the fleet through Zenoh. A service estimates and publishes a vehicle
only while it holds that vehicle's claim, a liveliness token
``<prefix>/@claim/<sysid>/<zid>`` (``zid``: the Zenoh session id, unique per process,
so two services configured with the same service id still claim apart).

Each claiming service also holds a member token ``<prefix>/@members/<zid>``. Every
``period_s`` (the claim period, default 0.5 s) each service looks at the vehicles it has
heard in the last ``vehicle_timeout_s``:

- a vehicle nobody claims is claimed by the member with the fewest claims, ties broken
  by the smallest ``rank(sysid, zid)`` (a hash: vehicles spread evenly, and every
  service computes the same choice); a vehicle still unclaimed after two turns is
  claimed by any service that hears it (the chosen one may not hear it);
- when two services claimed the same vehicle at once, both see both tokens; the one
  with the larger rank withdraws at its next turn, so a vehicle is published twice for
  at most one claim period;
- a vehicle no longer heard for ``vehicle_timeout_s`` is released.

When a service dies its session ends, Zenoh withdraws its tokens (at once when the
process dies and its TCP connections close, after the session lease otherwise), and the
others claim its vehicles at their next turn. The new owner continues that vehicle's
estimation from the last state the previous owner published: at every turn each
claiming service queries ``<prefix>/*/state`` (the owners' state queryables, answered
from other processes only) and keeps, per vehicle it hears but does not own, the
claim holder's reply (:mod:`glmav_observer.fleet.handover`: the last estimate of every configuration,
the active configuration, isolated faults, the reference fit). On the claim, the
vehicle's :class:`~glmav_observer.estimation.vehicle.VehicleEstimator` is seeded with it
(:meth:`~glmav_observer.estimation.vehicle.VehicleEstimator.seed`: applied at the first
attitude/IMU sample if the state is at most ``SEED_MAX_AGE_S`` old in vehicle time, else
a cold start from the live stream), and the log says which, with the state's age. The
new owner also logs the gap since the last health record the previous owner published
(every claiming service keeps the latest ``<prefix>/<sysid>/health``, 10 Hz per vehicle,
from a subscription).

Messages of vehicles this service does not own are counted (``not_owned_messages``) and
not estimated; messages that start no claim (a ground station's heartbeats) pass.

Whom a service believes (issue 31 D1, D2). On an open Zenoh network anyone can declare
tokens and answer state queries; the network's own defence is Zenoh's authentication and
access control (``configs/zenoh/acl-router.json5``: only the service's user may declare
``@claim``/``@members`` tokens and answer ``*/state``; docs/zenoh.md). Whatever the
network, a service also honours a claim only

- from a **member** (a session that holds a ``@members`` token): a flood of claim tokens
  from a session that is not one (D2: 255 tokens of "zid" 0 stopped every record) is
  ignored, with one warning per claimant;
- that **delivers**: a vehicle this service hears, claimed by others for longer than
  ``takeback_s`` (4 claim periods, 2 s: a new owner's first health record comes within
  ~0.2 s of its claim: the next sample, then one health period) while nobody published
  a health record of it for ``takeback_s``, is taken back with a warning; that claim
  (vehicle, claimant) is not honoured again. A service therefore needs its health
  records published (``[zenoh.decimation] health`` not 0) to keep its claims.

The state a taken-over vehicle is continued from is only a hypothesis: it must agree
with the vehicle's own measurements in the first second
(:data:`~glmav_observer.estimation.seed.SEED_GATE_SIGMA`), else it is dropped with a
warning and the estimation starts afresh.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.seed import EstimatorSeed
from glmav_observer.fleet.handover import HandoverError, seed_from_state, state_time_s
from glmav_observer.ingest.pipeline import Admission
from glmav_observer.publish.sink import Sink
from glmav_observer.publish.zenoh_keys import decode_payload

if TYPE_CHECKING:
    import zenoh

logger = logging.getLogger(__name__)

#: How often a service checks its claims, s (the longest a vehicle is published twice).
CLAIM_PERIOD_S = 0.5
#: A vehicle not heard for this long is released, s.
VEHICLE_TIMEOUT_S = 5.0
#: A claim on a vehicle this service hears, with no health record of it for this many
#: claim periods, is not honoured (the vehicle is taken back; see the module doc).
TAKEBACK_PERIODS = 4
#: non-member claimants (and silent claims) named in a warning; past that, counted only
MAX_WARNED_CLAIMANTS = 16
#: The messages that make a service claim their sender (the estimator's inputs).
CLAIMING_MESSAGES = frozenset(
    {"ATTITUDE", "HIGHRES_IMU", "SCALED_IMU", "RAW_IMU", "LOCAL_POSITION_NED"}
)


class ClaimError(ValueError):
    """Claims cannot work with this configuration (the message says why)."""


def claim_key(prefix: str, sysid: int | str = "*", zid: str | None = None) -> str:
    base = f"{prefix}/@claim/{sysid}"
    return base if zid is None else f"{base}/{zid}"


def members_key(prefix: str, zid: str = "*") -> str:
    return f"{prefix}/@members/{zid}"


def rank(sysid: int, zid: str) -> int:
    """The order of claimants for one vehicle (smallest first), the same on every host."""
    return int.from_bytes(hashlib.blake2b(f"{sysid}/{zid}".encode(), digest_size=8).digest())


class ClaimManager:
    """Holds this service's claims and watches everyone's (thread-safe)."""

    def __init__(
        self,
        session: zenoh.Session,
        prefix: str,
        *,
        period_s: float = CLAIM_PERIOD_S,
        vehicle_timeout_s: float = VEHICLE_TIMEOUT_S,
    ) -> None:
        import zenoh as zenoh_mod

        self._zenoh = zenoh_mod
        self._session = session
        self.prefix = prefix
        self.zid = str(session.zid())
        self.period_s = period_s
        self.vehicle_timeout_s = vehicle_timeout_s
        #: a claim without health records of its vehicle for this long is not honoured, s
        self.takeback_s = TAKEBACK_PERIODS * period_s
        self._lock = threading.Lock()
        self._claimants: dict[int, set[str]] = {}
        #: when each claim (sysid, zid) was first seen (monotonic s)
        self._claim_since: dict[tuple[int, str], float] = {}
        #: claims not honoured: their claimant published nothing of the vehicle
        self._distrusted: set[tuple[int, str]] = set()
        self._warned: set[str] = set()
        #: claim turns that ignored a non-member's claim; vehicles taken back from silent
        #: claimants (both in the summary: ``claims_ignored_not_member``,
        #: ``vehicles_taken_back``)
        self.ignored_claims = 0
        self.taken_back = 0
        self._tokens: dict[int, Any] = {}
        #: the vehicles this service owns now (read without the lock by the estimation loop)
        self.owned: frozenset[int] = frozenset()
        self._seen: dict[int, float] = {}
        self._unclaimed_turns: dict[int, int] = {}
        self._members: set[str] = {self.zid}
        #: last health record published by anyone: sysid -> (monotonic s, payload bytes)
        self._last_health: dict[int, tuple[float, bytes, str]] = {}
        #: newest state queryable reply per vehicle not owned: sysid -> (monotonic s, payload)
        self._last_state: dict[int, tuple[float, dict[str, Any]]] = {}
        self.state_replies = 0
        self.stale_state_replies = 0
        self.events: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._member_token = session.liveliness().declare_token(members_key(prefix, self.zid))
        self._member_sub = session.liveliness().declare_subscriber(
            members_key(prefix), self._on_member, history=True
        )
        self._subscriber = session.liveliness().declare_subscriber(
            claim_key(prefix, "**"), self._on_token, history=True
        )
        self._health_sub = session.declare_subscriber(f"{prefix}/*/health", self._on_health)
        self._thread = threading.Thread(target=self._loop, name="glmav-claims", daemon=True)
        self._thread.start()

    # -- zenoh callbacks (Zenoh's threads) -------------------------------------------------
    def _on_token(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        try:
            sysid, zid = int(parts[-2]), parts[-1]
        except (ValueError, IndexError):
            return
        with self._lock:
            holders = self._claimants.setdefault(sysid, set())
            if sample.kind == self._zenoh.SampleKind.PUT:
                holders.add(zid)
                self._claim_since.setdefault((sysid, zid), time.monotonic())
            else:
                holders.discard(zid)
                self._claim_since.pop((sysid, zid), None)
                if zid != self.zid:
                    self.events.append(
                        {"event": "released", "sysid": sysid, "by": zid, "t": time.monotonic()}
                    )

    def _on_member(self, sample: zenoh.Sample) -> None:
        zid = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == self._zenoh.SampleKind.PUT:
                self._members.add(zid)
            elif zid != self.zid:
                self._members.discard(zid)

    def _on_health(self, sample: zenoh.Sample) -> None:
        try:
            sysid = int(str(sample.key_expr).split("/")[-2])
        except (ValueError, IndexError):
            return
        self._last_health[sysid] = (
            time.monotonic(),
            sample.payload.to_bytes(),
            str(sample.encoding),
        )

    def _on_state_reply(self, reply: zenoh.Reply) -> None:
        sample = reply.ok
        if sample is None:
            return
        try:
            state = json.loads(sample.payload.to_bytes())
            sysid = int(state["sysid"])
        except (ValueError, KeyError, TypeError):
            return
        if sysid in self.owned:
            return
        t = state_time_s(state)
        replier = getattr(reply, "replier_id", None)  # (unstable in zenoh 1.x: may be None)
        with self._lock:
            self.state_replies += 1
            # several services may answer for one vehicle: one that released it (a double
            # claim settled) keeps answering with its last records; only the claim
            # holder's reply counts, or without the replier's id the newest estimate
            if replier is not None and str(replier.zid) not in self._honoured(sysid):
                self.stale_state_replies += 1
                return
            old = self._last_state.get(sysid)
            if old is None or replier is not None or not t <= state_time_s(old[1]):
                self._last_state[sysid] = (time.monotonic(), state)

    def _query_states(self, owned: set[int]) -> None:
        """Ask the other services for the state of the vehicles heard and not owned."""
        if not set(self._seen) - owned:
            return
        zenoh = self._zenoh
        try:
            self._session.get(
                f"{self.prefix}/*/state",
                self._on_state_reply,
                consolidation=zenoh.ConsolidationMode.NONE,  # every owner's reply
                allowed_destination=zenoh.Locality.REMOTE,  # not this process's own
                # replies are kept as they arrive; a loaded owner may answer late
                timeout=max(2.0, self.period_s),
            )
        except zenoh.ZError as exc:
            logger.debug("state query failed: %s", exc)

    def take_seed(self, sysid: int) -> EstimatorSeed | None:
        """The newest state another service published of ``sysid`` as a seed (None:
        none heard, or one that cannot seed; logged)."""
        with self._lock:
            last = self._last_state.pop(sysid, None)
        if last is None:
            logger.info("vehicle %d: no published state to continue from (cold start)", sysid)
            return None
        t_rx, state = last
        try:
            seed = seed_from_state(state)
        except HandoverError as err:
            logger.warning("vehicle %d: its last published state cannot be used: %s", sysid, err)
            return None
        logger.info(
            "vehicle %d: continuing from the state service %s published (t_boot %.3f s, "
            "received %.3f s ago)",
            sysid,
            state.get("service_id"),
            seed.t_boot_s,
            time.monotonic() - t_rx,
        )
        return seed

    # -- the estimation loop's side --------------------------------------------------------
    def saw(self, sysid: int) -> None:
        """A claiming message of ``sysid`` was heard (cheap: one dict write)."""
        self._seen[sysid] = time.monotonic()

    def note(self, event: dict[str, Any]) -> None:
        """Add an event of the estimation side (a seed applied or refused) to ``events``."""
        with self._lock:
            self.events.append(event)

    def claimants(self, sysid: int) -> set[str]:
        with self._lock:
            return set(self._claimants.get(sysid, ()))

    # -- whom to believe --------------------------------------------------------------------
    def _warn_once(self, zid: str, message: str, *args: object) -> None:
        """Log ``message`` once per claimant (the first MAX_WARNED_CLAIMANTS)."""
        if zid in self._warned or len(self._warned) >= MAX_WARNED_CLAIMANTS:
            return
        self._warned.add(zid)
        logger.warning(message, *args)

    def _honoured(self, sysid: int) -> set[str]:
        """The other claimants of ``sysid`` whose claim counts (caller holds the lock):
        members, and not taken back from (see the module doc)."""
        out = set()
        for z in self._claimants.get(sysid, ()):
            if z == self.zid or (sysid, z) in self._distrusted:
                continue
            if z not in self._members:
                self.ignored_claims += 1
                self._warn_once(
                    z,
                    "claims by %s ignored (vehicle %d, ...): it is not a member of the "
                    "fleet (no %s token); see docs/zenoh.md for Zenoh access control",
                    z,
                    sysid,
                    members_key(self.prefix, z),
                )
                continue
            out.add(z)
        return out

    def _silent_claim(self, sysid: int, holders: set[str], now: float) -> bool:
        """Whether ``holders`` have claimed ``sysid`` for longer than ``takeback_s``
        with no health record of it published for as long."""
        since = [self._claim_since.get((sysid, z), now) for z in holders]
        if now - max(since) <= self.takeback_s:
            return False
        last = self._last_health.get(sysid)
        return last is None or now - last[0] > self.takeback_s

    def _take_back(self, sysid: int, holders: set[str]) -> None:
        with self._lock:
            for z in holders:
                self._distrusted.add((sysid, z))
            self.taken_back += 1
            self.events.append(
                {"event": "taken_back", "sysid": sysid, "from": sorted(holders),
                 "t": time.monotonic()}
            )  # fmt: skip
        for z in holders:
            self._warn_once(
                f"{z}/{sysid}",
                "vehicle %d taken back: %s claims it but has published no estimate of it "
                "for %.1f s (its claim is no longer honoured)",
                sysid,
                z,
                self.takeback_s,
            )

    # -- the claim turn --------------------------------------------------------------------
    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self.turn()
            except Exception:  # never let the claims thread die silently
                logger.exception("claims turn failed")

    def turn(self) -> None:
        """Claim unclaimed vehicles, settle double claims, release silent vehicles."""
        now = time.monotonic()
        owned = set(self.owned)
        with self._lock:
            load = {m: 0 for m in self._members}
            for holders in self._claimants.values():
                for z in holders:
                    if z in load:
                        load[z] += 1
        for sysid, seen in sorted(self._seen.items()):
            with self._lock:
                others = self._honoured(sysid)
            if others and sysid not in owned and self._silent_claim(sysid, others, now):
                self._take_back(sysid, others)
                others = set()
                self._unclaimed_turns[sysid] = 2  # claimed at this turn, by whoever hears it
            if now - seen > self.vehicle_timeout_s:
                if sysid in owned:
                    self._release(sysid, "silent")
                    owned.discard(sysid)
                del self._seen[sysid]
                self._unclaimed_turns.pop(sysid, None)
                continue
            mine = rank(sysid, self.zid)
            if sysid in owned:
                if others and min(rank(sysid, z) for z in others) < mine:
                    self._release(sysid, "double claim: the lower rank keeps it")
                    owned.discard(sysid)
                    load[self.zid] = load.get(self.zid, 1) - 1
                continue
            if others:
                self._unclaimed_turns.pop(sysid, None)
                continue
            turns = self._unclaimed_turns[sysid] = self._unclaimed_turns.get(sysid, 0) + 1
            least = min(load.values())
            chosen = min((z for z, n in load.items() if n == least), key=lambda z: rank(sysid, z))
            if (chosen == self.zid or turns > 2) and self._claim(sysid):
                owned.add(sysid)
                load[self.zid] = load.get(self.zid, 0) + 1
                self._unclaimed_turns.pop(sysid, None)
        self.owned = frozenset(owned)
        self._query_states(owned)

    def _claim(self, sysid: int) -> bool:
        try:
            token = self._session.liveliness().declare_token(
                claim_key(self.prefix, sysid, self.zid)
            )
        except self._zenoh.ZError as exc:
            logger.warning("claim of vehicle %d failed: %s", sysid, exc)
            return False
        self._tokens[sysid] = token
        last = self._last_health.get(sysid)
        event: dict[str, Any] = {"event": "claimed", "sysid": sysid, "t": time.monotonic()}
        if last is not None:
            t_seen, payload, encoding = last
            event["gap_s"] = event["t"] - t_seen
            try:  # JSON or MessagePack ([zenoh] encoding of the publishing service)
                event["last_published"] = decode_payload(payload, encoding)
            except ValueError:
                event["last_published"] = None
            logger.info(
                "vehicle %d taken over: %.3f s since its last published health (t_boot %s s)",
                sysid,
                event["gap_s"],
                (event["last_published"] or {}).get("t_boot_s"),
            )
        else:
            logger.info("vehicle %d claimed", sysid)
        with self._lock:
            self.events.append(event)
        return True

    def _release(self, sysid: int, why: str) -> None:
        token = self._tokens.pop(sysid, None)
        if token is not None:
            try:
                token.undeclare()
            except self._zenoh.ZError as exc:
                logger.debug("undeclare of the claim of %d failed: %s", sysid, exc)
        logger.info("vehicle %d released (%s)", sysid, why)
        with self._lock:
            self.events.append(
                {"event": "released_own", "sysid": sysid, "why": why, "t": time.monotonic()}
            )

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for sysid in list(self._tokens):
            self._release(sysid, "stopping")
        self.owned = frozenset()
        entities: list[Any] = [
            self._subscriber,
            self._health_sub,
            self._member_sub,
            self._member_token,
        ]
        for entity in entities:
            try:
                entity.undeclare()
            except self._zenoh.ZError as exc:
                logger.debug("undeclare failed: %s", exc)


class ClaimingService(Service):
    """A :class:`Service` that estimates only the vehicles it has claimed."""

    def __init__(
        self,
        config: ServiceConfig,
        sinks: Sequence[Sink] = (),
        *,
        period_s: float = CLAIM_PERIOD_S,
        admission: Admission | None = None,
    ) -> None:
        from glmav_observer.publish.zenoh_sink import ZenohSink

        zs = next((s for s in sinks if isinstance(s, ZenohSink)), None)
        if zs is None:
            for s in sinks:
                s.close()
            raise ClaimError("--claim needs Zenoh: drop --no-zenoh, or set [zenoh] enabled = true")
        if zs.decimation.get("health", 1) == 0:
            for s in sinks:
                s.close()
            raise ClaimError(
                "--claim needs the health records published ([zenoh.decimation] health "
                "not 0): the other services take back a vehicle whose owner publishes none"
            )
        super().__init__(config, sinks, admission=admission)
        self.claims = ClaimManager(
            zs.session, zs.prefix, period_s=period_s, vehicle_timeout_s=zs.vehicle_timeout_s
        )
        #: the owned vehicles this service has started estimating (since their claim)
        self._estimating: set[int] = set()
        #: seeds for vehicles whose estimator does not exist yet
        self._pending_seeds: dict[int, EstimatorSeed] = {}
        #: seeded vehicles whose seed has not been applied yet
        self._seeding: set[int] = set()

    def feed_message(self, msg: Any, t_arrival_s: float, link_id: str = "") -> int:
        sysid = msg.get_srcSystem()
        claims = self.claims
        if sysid not in claims.owned:
            self._estimating.discard(sysid)
            if msg.get_type() in CLAIMING_MESSAGES:
                claims.saw(sysid)
                self.messages += 1
                self.counters["not_owned_messages"] += 1
                return 0
            return super().feed_message(msg, t_arrival_s, link_id)
        claims.saw(sysid)
        if sysid not in self._estimating:
            self._estimating.add(sysid)
            self._begin(sysid)
        n = super().feed_message(msg, t_arrival_s, link_id)
        if sysid in self._seeding:
            self._check_seeded(sysid)
        return n

    def _begin(self, sysid: int) -> None:
        """A vehicle newly claimed: its estimator continues from the last published state
        (or, without one, starts afresh from the live stream)."""
        seed = self.claims.take_seed(sysid)
        est = self.estimators.get(sysid)
        if seed is None:
            self._pending_seeds.pop(sysid, None)
            if est is not None and est.t_bank_s is not None:
                est.restart("claimed")  # estimated before a release: that state is stale
            return
        self._seeding.add(sysid)
        if est is None:
            self._pending_seeds[sysid] = seed  # the ingest has not announced it yet
        else:
            est.seed(seed)

    def _new_estimator(self, sysid: int, link_id: str) -> None:
        super()._new_estimator(sysid, link_id)
        seed = self._pending_seeds.pop(sysid, None)
        if seed is not None:
            self.estimators[sysid].seed(seed)

    def _check_seeded(self, sysid: int) -> None:
        est = self.estimators.get(sysid)
        if est is None or est.seed_outcome is None:
            return
        self._seeding.discard(sysid)
        event: dict[str, Any] = {
            "event": "seeded",
            "sysid": sysid,
            "outcome": est.seed_outcome,
            "state_age_s": est.seed_age_s,
            "active_config": est.active_config,
            "t": time.monotonic(),
        }
        if est.seed_outcome == "continued":
            logger.info(
                "vehicle %d continued from its last published state: %.3f s old (vehicle "
                "time), active %s, isolated %s",
                sysid,
                est.seed_age_s,
                est.active_config,
                [f"{ax.fault.axis} ({ax.fault.kind})" for ax in est.fdi.axes if ax.fault],
            )
        else:
            logger.info(
                "vehicle %d started cold: its last published state is %s", sysid, est.seed_outcome
            )
        self.claims.note(event)

    def close(self) -> None:
        # release the claims first: the others take over without waiting for the session
        self.claims.close()
        if self.claims.ignored_claims:
            self.counters["claims_ignored_not_member"] = self.claims.ignored_claims
        if self.claims.taken_back:
            self.counters["vehicles_taken_back"] = self.claims.taken_back
        super().close()
