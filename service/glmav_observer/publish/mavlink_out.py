"""The estimate back on MAVLink: a sink for the vehicle, a router or a ground station.

Opt-in (``[mavlink_out]`` in the service TOML, or ``serve --mavlink-out CONN``). On one
output link (a pymavlink connection string, opened with the ingest's
:class:`~glmav_observer.ingest.links.Link`) the service is a MAVLink component of each
vehicle it estimates: system id the vehicle's (or ``system_id``), component id
``component_id`` (default 191, MAV_COMP_ID_ONBOARD_COMPUTER; never a ground station's
255/190). It sends:

- HEARTBEAT at 1 Hz (host clock), MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID;
- the active estimate at ``rate_hz`` per vehicle (vehicle time) as ODOMETRY (frame and
  child frame MAV_FRAME_LOCAL_NED, position and attitude unknown: NaN, velocity
  covariance diagonal: ``sigma_measured_mps``\\ ^2 on measured axes, ``sigma_lost_mps``\\ ^2
  on a dead-reckoned one; ``estimator_type`` MAV_ESTIMATOR_TYPE_GPS_INS: IMU and attitude
  fused with a velocity measurement; ``reset_counter`` + 1 at each configuration switch;
  ``quality`` 100 ok, 75 aided by the drag model, 50 dead reckoning, 1 degraded) and/or VISION_SPEED_ESTIMATE (NED,
  the same covariance); ``time_usec`` is the vehicle's boot time of the estimate;
- STATUSTEXT for each newly isolated fault and each configuration switch;
- NAMED_VALUE_FLOAT at ``health_rate_hz``: ``GLV_N``, ``GLV_E``, ``GLV_D`` (axis state:
  0 warmup, 1 ok, 2 suspect, 3 faulty, 4 recovering) and ``GLV_CFG`` (0 full, 1 c1,
  2 c2, 3 c3).

Signed (MAVLink 2 signing, link id 1) when the service has a signing key. Bytes arriving on
the output link are read and dropped (the vehicle's own streams come in on ``--link``).

A ``udpin:``/``udp:`` output has no destination until a peer sends something: it answers
the **first** peer only (address and port), for the service's lifetime. Datagrams from any
other address are dropped, counted (``foreign_peer_datagrams``) and warned about once per
address, so a local process that sends one byte to the port cannot take the stream over
(issue 31 D7; before, the last sender got it). To change the peer, restart the service; a
fixed destination is ``udpout:``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from glmav_observer.ingest.links import Link
from glmav_observer.publish.mavlink_out_settings import GCS_COMPONENT_IDS, MavlinkOutSettings
from glmav_observer.reads import EVERY, Reads, next_due_s
from glmav_observer.records import CONFIGS, HealthRecord, Record, VelocityRecord

log = logging.getLogger(__name__)

AXIS_STATE_CODES = {"warmup": 0, "ok": 1, "suspect": 2, "faulty": 3, "recovering": 4}
CONFIG_CODES = {c: i for i, c in enumerate(CONFIGS)}
#: ODOMETRY.quality (%) by the active record's health: an axis aided by the learnt drag
#: model sits between measured (100) and dead-reckoned (50)
QUALITY = {"ok": 100, "aided": 75, "dead_reckoning": 50, "degraded": 1}
HEARTBEAT_PERIOD_S = 1.0
_SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01
_AXIS_INDEX = {"n": 0, "e": 1, "d": 2}


@dataclass
class _Vehicle:
    next_estimate_s: float = -math.inf
    next_health_s: float = -math.inf
    reset_counter: int = 0
    source: str | None = None
    seen: bool = False  # a first estimate has been sent (sets ``source`` without a reset)
    active_config: str | None = None
    faults: frozenset[tuple[str, str, float]] = frozenset()
    switch_t_s: float | None = None  # the last switch's own time (switch_at)


@dataclass
class MavlinkOutStats:
    sent: dict[str, int] = field(default_factory=dict)
    errors: int = 0
    dropped_input_bytes: int = 0
    #: datagrams on a udpin output from an address that is not the first peer
    foreign_peer_datagrams: int = 0


class MavlinkOutSink:
    """Writes the active estimate, events and health as MAVLink (see the module docstring)."""

    def __init__(self, settings: MavlinkOutSettings, *, signing_key: bytes | None = None) -> None:
        if settings.component_id in GCS_COMPONENT_IDS or not 1 <= settings.component_id <= 254:
            raise ValueError(f"mavlink_out.component_id {settings.component_id}: not allowed")
        self.settings = settings
        self.link = Link(settings.link)
        # udpout: send to the destination ourselves (pymavlink's write swallows errors)
        self._dest: Any = (
            getattr(self.link._m, "destination_addr", None)
            if settings.link.startswith("udpout:")
            else None
        )
        #: udpin: the first peer heard is the destination, for good (see the module doc)
        self._pin_peer = settings.link.startswith(("udpin:", "udp:"))
        self._warned_peers: set[Any] = set()
        self.signing_key = signing_key
        self._mavs: dict[int, Any] = {}
        self._vehicles: dict[int, _Vehicle] = {}
        self.stats = MavlinkOutStats()
        self._lock = threading.Lock()
        self._closed = False
        self._stop = threading.Event()
        self._beat = threading.Thread(target=self._heartbeats, name="mavlink-out-hb", daemon=True)
        self._beat.start()
        log.info(
            "mavlink out open: %s as component %d (%s)",
            settings.link,
            settings.component_id,
            "signed" if signing_key is not None else "unsigned",
        )

    # ----------------------------------------------------------------- encoding
    def _mav(self, sysid: int) -> Any:
        src = self.settings.system_id or sysid
        mav = self._mavs.get(src)
        if mav is None:
            mav = mavlink2.MAVLink(None, srcSystem=src, srcComponent=self.settings.component_id)
            if self.signing_key is not None:
                mav.signing.secret_key = self.signing_key
                mav.signing.link_id = 1
                mav.signing.sign_outgoing = True
                mav.signing.timestamp = int((time.time() - _SIGNING_EPOCH_UNIX_S) * 1e5)
            self._mavs[src] = mav
        return mav

    def _read_input(self) -> None:
        """Read and drop what arrived on the output link; on a udpin output, pin the
        first peer as the destination and refuse the others (caller holds the lock)."""
        while data := self.link.read():  # replies on the output link: not ours
            self.stats.dropped_input_bytes += len(data)
            if not self._pin_peer:
                continue
            peer = self.link.peer
            if self._dest is None:
                self._dest = peer
                log.info("mavlink out: answering %s only (the first peer heard)", peer)
            elif peer != self._dest:
                self.stats.foreign_peer_datagrams += 1
                if peer not in self._warned_peers and len(self._warned_peers) < 64:
                    self._warned_peers.add(peer)
                    log.warning(
                        "mavlink out: datagram from %s refused: this udpin output answers "
                        "%s only (the first peer); restart to change it, or use udpout:",
                        peer,
                        self._dest,
                    )

    def _send(self, sysid: int, msg: Any) -> None:
        """Encode and send (caller holds the lock)."""
        if self._pin_peer and self._dest is None:
            return  # a udpin output before its peer: nowhere to send
        try:
            self.link.write(bytes(msg.pack(self._mav(sysid))), self._dest)
        except Exception as exc:  # an encoding error must not stop the estimator
            self.stats.errors += 1
            log.warning("mavlink out: %s not sent: %s", msg.get_type(), exc)
            return
        name = msg.get_type()
        self.stats.sent[name] = self.stats.sent.get(name, 0) + 1

    def _heartbeats(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if self._closed:
                    return
                self._read_input()
                sysids = sorted(self._vehicles) or [self.settings.system_id or 1]
                for sysid in sysids:
                    self._send(
                        sysid,
                        mavlink2.MAVLink_heartbeat_message(
                            mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
                            mavlink2.MAV_AUTOPILOT_INVALID,
                            0,
                            0,
                            mavlink2.MAV_STATE_ACTIVE,
                            3,
                        ),
                    )
            self._stop.wait(HEARTBEAT_PERIOD_S)

    # ------------------------------------------------------------------- sink
    @property
    def reads(self) -> Reads:
        """The active estimate at the output's rate (ODOMETRY, VISION_SPEED_ESTIMATE) and
        every health record (its events become STATUSTEXT at once)."""
        s = self.settings
        return Reads(
            {"active": s.rate_hz if s.odometry or s.vision_speed_estimate else 0.0, "health": EVERY}
        )

    def write(self, record: Record) -> None:
        if isinstance(record, VelocityRecord):
            if record.config == "active":
                self._estimate(record)
        elif isinstance(record, HealthRecord):
            self._health(record)

    def _vehicle(self, sysid: int) -> _Vehicle:
        v = self._vehicles.get(sysid)
        if v is None:
            v = self._vehicles[sysid] = _Vehicle()
        return v

    def switch_at(self, sysid: int, t_boot_s: float) -> None:
        """``sysid``'s active configuration switched at ``t_boot_s`` (told by the service
        as it happens): its STATUSTEXT gives this time, not the next health record's."""
        with self._lock:
            self._vehicle(sysid).switch_t_s = t_boot_s

    def _estimate(self, r: VelocityRecord) -> None:
        s = self.settings
        with self._lock:
            if self._closed:
                return
            v = self._vehicle(r.sysid)
            if r.source_config != v.source:
                if v.seen:  # a configuration switch: the estimate may jump
                    v.reset_counter = (v.reset_counter + 1) % 256
                v.source = r.source_config
            v.seen = True
            if r.t_boot_s < v.next_estimate_s - 1e-6:  # 1 us: the grid's rounding
                return
            # the next slot on the rate's grid (no drift, no burst after a gap): the rule
            # the estimator builds the records by, so that it builds only these
            v.next_estimate_s = next_due_s(r.t_boot_s, s.rate_hz)
            var = [s.sigma_measured_mps**2] * 3
            if r.sigma_ned_mps is not None:  # every dead-reckoned axis (lost, unaided, silent)
                var = [max(v, x * x) for v, x in zip(var, r.sigma_ned_mps, strict=True)]
            elif r.lost_axis is not None:
                sig = r.sigma_lost_mps
                var[_AXIS_INDEX[r.lost_axis]] = sig * sig if sig is not None else math.nan
            vn, ve, vd = r.v_ned_mps
            t_us = max(0, round(r.t_boot_s * 1e6))
            if s.odometry:
                cov = [0.0] * 21  # upper triangle of the 6x6 (vx vy vz p q r), row by row
                cov[0], cov[6], cov[11] = var
                cov[15] = cov[18] = cov[20] = math.nan  # body rates: not estimated
                self._send(
                    r.sysid,
                    mavlink2.MAVLink_odometry_message(
                        t_us,
                        mavlink2.MAV_FRAME_LOCAL_NED,
                        mavlink2.MAV_FRAME_LOCAL_NED,
                        math.nan,
                        math.nan,
                        math.nan,
                        [math.nan, 0.0, 0.0, 0.0],
                        vn,
                        ve,
                        vd,
                        math.nan,
                        math.nan,
                        math.nan,
                        [math.nan] + [0.0] * 20,  # pose: unknown
                        cov,
                        v.reset_counter,
                        mavlink2.MAV_ESTIMATOR_TYPE_GPS_INS,
                        QUALITY.get(r.health, 0),
                    ),
                )
            if s.vision_speed_estimate:
                cov9 = [var[0], 0.0, 0.0, 0.0, var[1], 0.0, 0.0, 0.0, var[2]]
                self._send(
                    r.sysid,
                    mavlink2.MAVLink_vision_speed_estimate_message(
                        t_us, vn, ve, vd, cov9, v.reset_counter
                    ),
                )

    def _health(self, h: HealthRecord) -> None:
        s = self.settings
        with self._lock:
            if self._closed:
                return
            v = self._vehicle(h.sysid)
            # isolated_faults holds the faults isolated now (one per axis at most)
            faults = frozenset((str(f.axis), f.kind, f.t_detect_s) for f in h.isolated_faults)
            if s.statustext:
                for axis, kind, t_detect in sorted(faults - v.faults, key=lambda f: f[2]):
                    self._text(
                        h.sysid,
                        mavlink2.MAV_SEVERITY_WARNING,
                        f"glmav {h.sysid}: fault {kind} v{axis} at {t_detect:.2f}s",
                    )
                if v.active_config is not None and h.active_config != v.active_config:
                    t_switch = h.t_boot_s if v.switch_t_s is None else v.switch_t_s
                    self._text(
                        h.sysid,
                        mavlink2.MAV_SEVERITY_NOTICE,
                        f"glmav {h.sysid}: {v.active_config} -> {h.active_config} "
                        f"at {t_switch:.2f}s",
                    )
                    v.switch_t_s = None
            v.faults = faults
            v.active_config = h.active_config
            if s.named_value_float and h.t_boot_s >= v.next_health_s:
                v.next_health_s = h.t_boot_s + 1.0 / s.health_rate_hz
                t_ms = max(0, round(h.t_boot_s * 1000)) & 0xFFFFFFFF
                values = [
                    (f"GLV_{a.upper()}", float(AXIS_STATE_CODES.get(h.axis_state.get(a, ""), -1)))
                    for a in ("n", "e", "d")
                ]
                values.append(("GLV_CFG", float(CONFIG_CODES.get(h.active_config, -1))))
                for name, value in values:
                    self._send(
                        h.sysid,
                        mavlink2.MAVLink_named_value_float_message(t_ms, name.encode(), value),
                    )

    def _text(self, sysid: int, severity: int, text: str) -> None:
        self._send(
            sysid,
            mavlink2.MAVLink_statustext_message(severity, text[:50].encode("ascii", "replace")),
        )

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        self._beat.join(timeout=5.0)
        self.link.close()
        log.info(
            "mavlink out closed: sent %s, errors %d, datagrams from other peers refused %d",
            self.stats.sent,
            self.stats.errors,
            self.stats.foreign_peer_datagrams,
        )
