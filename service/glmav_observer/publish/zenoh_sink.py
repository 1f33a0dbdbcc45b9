"""Republishing the service's records on Zenoh (design.md, "Zenoh"; docs/zenoh.md).

One Zenoh session per service, opened by :func:`open_zenoh_sink` and owned (closed) by
the returned :class:`ZenohSink`. Keys, with ``<prefix>`` (default ``glmav``):

- ``<prefix>/<sysid>/velocity/<config>`` (full, c1, c2, c3) and ``.../velocity/active``;
- ``<prefix>/<sysid>/health``; ``<prefix>/<sysid>/measurement``; ``<prefix>/<sysid>/truth``;
- queryable ``<prefix>/<sysid>/state`` (a query on ``<prefix>/*/state`` gets one reply
  per vehicle) and queryable ``<prefix>/@config/<service-id>``;
- liveliness ``<prefix>/@alive/<service-id>`` while the sink is open, and
  ``<prefix>/@alive/<service-id>/<sysid>`` while that vehicle's records keep coming.

Payloads are ``record.to_dict()`` plus ``service_id`` as compact JSON (encoding
``application/json``), or as MessagePack (``application/msgpack``) with ``encoding=
"msgpack"`` (``[zenoh] encoding``); the ``schema`` field names the layout, see
:mod:`glmav_observer.publish.schema`. Query replies are always JSON. Two services on one Zenoh network publish on the
same ``<prefix>/<sysid>/...`` keys when they estimate the same vehicle; ``service_id``
tells their samples apart. A service refuses to start (:class:`DuplicateServiceError`)
when another one already holds the liveliness token of its id.

``write`` never waits on the network: publishers use congestion control DROP, so a slow
or absent subscriber makes Zenoh drop samples instead of blocking the estimator; without
any connected node a put is a local no-op. A lost router is reconnected by Zenoh itself
(the ``connect`` endpoints are retried), and publishing resumes without a restart.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import threading
import time
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Any

from glmav_observer._version import __version__
from glmav_observer.configurations import AIDED
from glmav_observer.publish.schema import (
    CONFIG_SCHEMA,
    DEFAULT_ENCODING,
    DEFAULT_PREFIX,
    KINDS,
    STATE_SCHEMA,
    encoding_reason,
)
from glmav_observer.publish.zenoh_config import (
    EMBEDDED_DEFAULT_NAME,
    ZenohConfigError,
    check_decimation,
    load_zenoh_config,
    open_session,
)
from glmav_observer.publish.zenoh_keys import (
    alive_key,
    check_prefix,
    check_service_id,
    config_key,
    encode_json,
    payload_encoder,
    route,
    state_key,
    zenoh_encoding_name,
)
from glmav_observer.reads import READS_LIVE_DEFAULT, Reads
from glmav_observer.records import (
    CONFIGS,
    Record,
    VelocityRecord,
)

if TYPE_CHECKING:
    import zenoh


log = logging.getLogger(__name__)

#: How long a starting service waits for the liveliness token of a namesake (s): a query
#: to a connected router is answered within milliseconds on a LAN; with no router or
#: peer reachable it ends at once.
DUPLICATE_CHECK_TIMEOUT_S = 2.0


class DuplicateServiceError(ZenohConfigError):
    """Another service with the same id is already on the Zenoh network."""


def check_encoding(encoding: str) -> str:
    """``encoding`` if it is one of ``ENCODINGS`` (publish/schema.py), else a config error."""
    reason = encoding_reason(encoding)
    if reason is not None:
        raise ZenohConfigError(f"zenoh encoding {encoding!r}: {reason}")
    return encoding


_monotonic = time.monotonic


def _count_of(counter: Iterator[int]) -> int:
    """The next value of an ``itertools.count`` without taking it (its repr: ``count(N)``)."""
    return int(repr(counter)[6:-1])


class _Vehicle:
    """One vehicle's shared state: its latest record per slot (read by the state
    queryable), when it was last heard, whether its liveliness token is declared."""

    __slots__ = ("alive", "last_seen", "slots", "sysid")

    def __init__(self, sysid: int) -> None:
        self.sysid = sysid
        self.slots: dict[str, Record] = {}
        self.last_seen = 0.0
        self.alive = False


class _Route:
    """Everything ``write`` needs for one key, computed at its first record: the kind,
    the key string, the state slot, the decimation, the encoder and (at its first
    published record) the publisher. ``count`` numbers the records written (an
    ``itertools.count``: taking a number is atomic, so writers on several threads need no
    lock); ``failed`` the selected records that did not reach Zenoh."""

    __slots__ = (
        "count",
        "encode",
        "every",
        "failed",
        "key",
        "kind",
        "publisher",
        "slot",
        "vehicle",
    )

    def __init__(self, kind: str, key: str, slot: str, every: int, vehicle: _Vehicle) -> None:
        self.kind = kind
        self.key = key
        self.slot = slot
        self.every = every
        self.vehicle = vehicle
        self.count = itertools.count()
        self.failed = 0
        self.publisher: zenoh.Publisher | None = None
        self.encode: Any = None

    def selected(self) -> tuple[int, int]:
        """(records written, of which selected by the decimation) so far."""
        n = _count_of(self.count)
        every = self.every
        return n, (0 if every == 0 else -(-n // every))


# ---------------------------------------------------------------------------------------
# The sink
# ---------------------------------------------------------------------------------------


class ZenohSink:
    """Publishes records, answers state and config queries, holds liveliness tokens.

    Construct with :func:`open_zenoh_sink`. ``write`` is called from the estimation
    thread (one per link); queries are answered from Zenoh's threads. Each key's route
    (key string, decimation, encoder, publisher) is built at its first record, under the
    lock, and then only read: ``write`` takes no lock on its path (the latest records
    are one dict store per record, the counters an ``itertools.count`` per key).
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        config_name: str | None,
        prefix: str = DEFAULT_PREFIX,
        decimation: Mapping[str, int] | None = None,
        encoding: str = DEFAULT_ENCODING,
        service_id: str,
        effective_config: Mapping[str, Any],
        vehicle_timeout_s: float = 5.0,
        check_unique: bool = True,
        reads: Reads = READS_LIVE_DEFAULT,
    ) -> None:
        import zenoh

        #: the record streams and rates this sink publishes; the service builds no more
        #: for it (glmav_observer.reads)
        self.reads = reads

        self._zenoh = zenoh
        self._session = session
        self.prefix = check_prefix(prefix)
        self.service_id = check_service_id(service_id)
        self.decimation = check_decimation(decimation)
        self.encoding = check_encoding(encoding)
        self._zenoh_encoding = zenoh.Encoding(zenoh_encoding_name(encoding))
        self._encode = payload_encoder(encoding, self.service_id)
        self.config_name = config_name
        self.vehicle_timeout_s = vehicle_timeout_s
        self._effective_config = dict(effective_config)
        self._lock = threading.Lock()
        self._closed = False
        self._publishers: dict[str, zenoh.Publisher] = {}
        #: sysid -> (config name for velocity records, else the record class) -> route
        self._routes: dict[int, dict[object, _Route]] = {}
        self._vehicles: dict[int, _Vehicle] = {}
        self._vehicle_tokens: dict[int, zenoh.LivelinessToken] = {}
        self.errors = 0
        self.after_close = 0
        self.queries_answered = 0
        self._config_payload = encode_json(self.config_payload())
        if check_unique:  # off for the 2nd..Nth worker of one service (fleet.workers)
            self._check_unique()
        self._queryables = [
            session.declare_queryable(state_key(self.prefix), self._on_state_query),
            session.declare_queryable(
                config_key(self.prefix, self.service_id), self._on_config_query
            ),
        ]
        self._service_token = session.liveliness().declare_token(
            alive_key(self.prefix, self.service_id)
        )
        self._stop = threading.Event()
        self._watchdog = threading.Thread(
            target=self._watch_vehicles, name="zenoh-sink-liveliness", daemon=True
        )
        self._watchdog.start()
        log.info(
            "zenoh sink open: prefix %s, service %s, config %s, zid %s; publishing %s",
            self.prefix,
            self.service_id,
            config_name or EMBEDDED_DEFAULT_NAME,
            session.zid(),
            reads.describe(),
        )

    def _check_unique(self) -> None:
        """Raise :class:`DuplicateServiceError` if ``@alive/<service-id>`` is already held."""
        key = alive_key(self.prefix, self.service_id)
        replies = self._session.liveliness().get(key, timeout=DUPLICATE_CHECK_TIMEOUT_S)
        for reply in replies:
            if reply.ok is not None:
                raise DuplicateServiceError(
                    f"another service with id {self.service_id!r} is already on this Zenoh "
                    f"network (liveliness token {key}); give this one its own id: "
                    "--service-id NAME or [service] id in the service TOML"
                )

    @property
    def session(self) -> zenoh.Session:
        """The sink's session (for in-process subscribers; do not close it yourself)."""
        return self._session

    # -- publishing -----------------------------------------------------------------------

    def write(self, record: Record) -> None:
        if self._closed:
            self.after_close += 1
            return
        routes = self._routes.get(record.sysid)
        route = None
        if routes is not None:
            route = routes.get(record.config if type(record) is VelocityRecord else type(record))
        if route is None:
            route = self._add_route(record)
        vehicle = route.vehicle
        vehicle.slots[route.slot] = record  # one dict store: atomic for the state queryable
        vehicle.last_seen = _monotonic()
        if not vehicle.alive:
            self._revive(vehicle)
        n = next(route.count)
        every = route.every
        if every != 1 and (every == 0 or n % every):
            return  # decimated (route.count counts it)
        publisher = route.publisher
        if publisher is None:
            publisher = self._declare_publisher(route)
            if publisher is None:
                return
        # the hand-over to Zenoh: non-blocking (congestion control DROP)
        try:
            publisher.put(route.encode(record))
        except self._zenoh.ZError as exc:
            with self._lock:
                route.failed += 1
                self.errors += 1
            if self.errors == 1 or self.errors % 1000 == 0:
                log.warning("zenoh put on %s failed (%d so far): %s", route.key, self.errors, exc)

    def _add_route(self, record: Record) -> _Route:
        """The route of ``record``'s key, made at its first record (raises ``TypeError``
        for anything that is not a record, as :func:`route` does)."""
        kind, key, slot = route(self.prefix, record)
        sysid = record.sysid
        sub = record.config if type(record) is VelocityRecord else type(record)
        with self._lock:
            routes = self._routes.get(sysid)
            if routes is None:
                routes = self._routes[sysid] = {}
            existing = routes.get(sub)
            if existing is not None:  # another writer thread made it meanwhile
                return existing
            vehicle = self._vehicles.get(sysid)
            if vehicle is None:
                vehicle = self._vehicles[sysid] = _Vehicle(sysid)
            new = _Route(kind, key, slot, self.decimation[kind], vehicle)
            new.encode = self._encode
            routes[sub] = new
            return new

    def _revive(self, vehicle: _Vehicle) -> None:
        """Declare the liveliness token of a vehicle heard (again)."""
        with self._lock:
            if not vehicle.alive and not self._closed:
                self._declare_vehicle_token(vehicle.sysid)
                vehicle.alive = vehicle.sysid in self._vehicle_tokens  # else: the next record

    def _declare_publisher(self, route: _Route) -> zenoh.Publisher | None:
        zenoh = self._zenoh
        with self._lock:
            if route.publisher is not None:
                return route.publisher
            try:
                publisher = self._session.declare_publisher(
                    route.key,
                    encoding=self._zenoh_encoding,
                    # estimates are superseded 4 ms later: drop rather than block the estimator
                    congestion_control=zenoh.CongestionControl.DROP,
                    priority=(
                        zenoh.Priority.DATA_HIGH if route.kind == "health" else zenoh.Priority.DATA
                    ),
                )
            except zenoh.ZError as exc:
                self.errors += 1
                route.failed += 1
                log.warning("zenoh: cannot declare a publisher on %s: %s", route.key, exc)
                return None
            self._publishers[route.key] = publisher
            route.publisher = publisher
            return publisher

    @property
    def published(self) -> dict[str, int]:
        """Records handed to Zenoh, per kind."""
        out = dict.fromkeys(KINDS, 0)
        for r in self._all_routes():
            out[r.kind] += r.selected()[1] - r.failed
        return out

    @property
    def decimated(self) -> dict[str, int]:
        """Records left out by the decimation, per kind."""
        out = dict.fromkeys(KINDS, 0)
        for r in self._all_routes():
            n, selected = r.selected()
            out[r.kind] += n - selected
        return out

    def _all_routes(self) -> list[_Route]:
        with self._lock:
            return [r for routes in self._routes.values() for r in routes.values()]

    # -- liveliness -----------------------------------------------------------------------

    def _declare_vehicle_token(self, sysid: int) -> None:
        """Declare ``<prefix>/@alive/<service-id>/<sysid>`` (caller holds the lock; on
        failure the next record tries again)."""
        try:
            token = self._session.liveliness().declare_token(
                alive_key(self.prefix, self.service_id, sysid)
            )
        except self._zenoh.ZError as exc:
            self.errors += 1
            log.warning("zenoh: cannot declare the liveliness token of vehicle %d: %s", sysid, exc)
            return
        self._vehicle_tokens[sysid] = token
        log.info(
            "zenoh: vehicle %d alive (%s)", sysid, alive_key(self.prefix, self.service_id, sysid)
        )

    def _watch_vehicles(self) -> None:
        """Withdraw a vehicle's token when its records stop for ``vehicle_timeout_s``."""
        period_s = max(0.05, min(1.0, self.vehicle_timeout_s / 4.0))
        while not self._stop.wait(period_s):
            now = time.monotonic()
            with self._lock:
                stale = [
                    v
                    for v in self._vehicles.values()
                    if v.alive and now - v.last_seen > self.vehicle_timeout_s
                ]
                for vehicle in stale:
                    sysid = vehicle.sysid
                    vehicle.alive = False
                    token = self._vehicle_tokens.pop(sysid, None)
                    if token is not None:
                        self._undeclare(token)
                    log.info("zenoh: vehicle %d silent for %.1f s", sysid, self.vehicle_timeout_s)

    def alive_vehicles(self) -> list[int]:
        """The sysids whose liveliness token is currently declared."""
        with self._lock:
            return sorted(self._vehicle_tokens)

    # -- queryables -----------------------------------------------------------------------

    def state_payload(self, sysid: int) -> dict[str, Any] | None:
        """The latest record of each kind for one vehicle (None if never seen)."""
        with self._lock:
            vehicle = self._vehicles.get(sysid)
            slots = {} if vehicle is None else dict(vehicle.slots)
        if not slots:
            return None

        def latest(slot: str) -> dict[str, Any] | None:
            record = slots.get(slot)
            return None if record is None else record.to_dict()

        return {
            "schema": STATE_SCHEMA,
            "service_id": self.service_id,
            "sysid": sysid,
            "velocity": {
                name: slots[name].to_dict() for name in (*CONFIGS, AIDED, "active") if name in slots
            },
            "health": latest("health"),
            "measurement": latest("measurement"),
            "truth": latest("truth"),
        }

    def config_payload(self) -> dict[str, Any]:
        """What the ``@config`` queryable answers: the service's effective configuration."""
        return {
            "schema": CONFIG_SCHEMA,
            "service_id": self.service_id,
            "prefix": self.prefix,
            "zenoh_config": self.config_name,
            "decimation": dict(self.decimation),
            "rates_hz": self.reads.to_dict(),
            "config": json.loads(encode_json(self._effective_config)),
            "version": __version__,
        }

    def _on_state_query(self, query: zenoh.Query) -> None:
        zenoh = self._zenoh
        try:
            with self._lock:
                sysids = sorted(self._vehicles)
            for sysid in sysids:
                key = state_key(self.prefix, sysid)
                if not query.key_expr.intersects(key):
                    continue
                payload = self.state_payload(sysid)
                if payload is not None:
                    query.reply(key, encode_json(payload), encoding=zenoh.Encoding.APPLICATION_JSON)
                    self.queries_answered += 1
        except Exception:  # a callback must never raise into Zenoh's thread
            self.errors += 1
            log.exception("zenoh: answering %s failed", query.selector)

    def _on_config_query(self, query: zenoh.Query) -> None:
        zenoh = self._zenoh
        try:
            query.reply(
                config_key(self.prefix, self.service_id),
                self._config_payload,
                encoding=zenoh.Encoding.APPLICATION_JSON,
            )
            self.queries_answered += 1
        except Exception:  # a callback must never raise into Zenoh's thread
            self.errors += 1
            log.exception("zenoh: answering %s failed", query.selector)

    # -- lifecycle ------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        return {
            "published": dict(self.published),
            "decimated": dict(self.decimated),
            "errors": self.errors,
            "after_close": self.after_close,
            "queries_answered": self.queries_answered,
            "publishers": len(self._publishers),
            "vehicles_alive": self.alive_vehicles(),
        }

    def _undeclare(self, entity: Any) -> None:
        try:
            entity.undeclare()
        except self._zenoh.ZError as exc:
            log.debug("zenoh: undeclare failed: %s", exc)

    def close(self) -> None:
        """Withdraw the tokens, undeclare everything and close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._watchdog.join(timeout=5.0)
        with self._lock:
            tokens = list(self._vehicle_tokens.values())
            self._vehicle_tokens.clear()
            for vehicle in self._vehicles.values():
                vehicle.alive = False
        for entity in [*tokens, self._service_token, *self._queryables]:
            self._undeclare(entity)
        for publisher in self._publishers.values():
            self._undeclare(publisher)
        self._publishers.clear()
        try:
            self._session.close()  # type: ignore[no-untyped-call]
        except self._zenoh.ZError as exc:
            log.warning("zenoh: closing the session failed: %s", exc)
        log.info("zenoh sink closed: %s", self.stats())

    def __enter__(self) -> ZenohSink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def open_zenoh_sink(
    zenoh_config_path: str | os.PathLike[str] | None,
    *,
    prefix: str = DEFAULT_PREFIX,
    decimation: Mapping[str, int] | None = None,
    encoding: str = DEFAULT_ENCODING,
    service_id: str,
    effective_config: Mapping[str, Any],
    vehicle_timeout_s: float = 5.0,
    check_unique: bool = True,
    reads: Reads = READS_LIVE_DEFAULT,
) -> ZenohSink:
    """Open the service's Zenoh session and sink (docs/zenoh.md).

    ``zenoh_config_path``: a Zenoh JSON5 file, or None for the embedded loopback peer.
    ``decimation``: per key kind (``KINDS``), publish every Nth record (0 = off).
    ``encoding``: the payloads' wire encoding, ``"json"`` or ``"msgpack"`` (``ENCODINGS``).
    ``check_unique``: refuse to start when a namesake holds ``@alive/<service-id>``
    (False for the workers after the first of one ``serve --workers N``: they share the id).
    ``reads``: the record streams and rates published (``[zenoh.rates]``; default: the
    live defaults of :mod:`glmav_observer.reads`).
    Raises :class:`ZenohConfigError` (a ``ValueError``) with a self-contained message.
    """
    check_prefix(prefix)
    check_service_id(service_id)
    check_decimation(decimation)
    check_encoding(encoding)
    config, name = load_zenoh_config(zenoh_config_path)
    session = open_session(config, name)
    try:
        return ZenohSink(
            session,
            config_name=None if zenoh_config_path is None else name,
            prefix=prefix,
            decimation=decimation,
            encoding=encoding,
            service_id=service_id,
            effective_config=effective_config,
            vehicle_timeout_s=vehicle_timeout_s,
            check_unique=check_unique,
            reads=reads,
        )
    except BaseException:
        session.close()  # type: ignore[no-untyped-call]
        raise
