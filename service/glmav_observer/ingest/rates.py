"""Message rates: what arrives, and when (and whether) to ask the vehicle for more.

Measurement. Each stream's rate is measured in the vehicle's own time over its last
``window_s``: (samples - 1) / (newest - oldest stamp), the inverse of the mean sample
spacing, which is what a vehicle's scheduler sets and what MAVSDK reports. A stream
silent for ``window_s`` of host time is at 0 Hz.

Requests (``[rates] mode``). A ground station on the same link sets rates too (QGC,
MAVSDK's ``set_rate_*``), so the service is polite:

- ``"request"`` (default): one ``window_s`` after a vehicle is first heard (a HEARTBEAT
  is enough), every stream below 90 % of the rate the estimator **needs** (``min_hz``; for the
  IMU, any of HIGHRES_IMU/SCALED_IMU/RAW_IMU counts) is asked for at the configured
  rate (``MAV_CMD_SET_MESSAGE_INTERVAL``); a stream that is fast enough is never
  touched, whoever set it. A stream still short is asked again after ``retry_s``,
  then twice as long each time, up to ``retry_max_s``.
- ``"observe"``: nothing is ever sent; rates are only measured and published.

A request counts (``asked``, the back-off) only once it was written on a live link
(:meth:`RateMonitor.sent`): while a TCP link is down nothing is due and nothing grows.
Before its first request of a stream the service asks the vehicle for the stream's current
interval (``MAV_CMD_GET_MESSAGE_INTERVAL``, answered by MESSAGE_INTERVAL), and when it stops
it sets every stream it changed back to that interval (:meth:`RateMonitor.restore_requests`;
the vehicle's default rate, interval 0, when the vehicle did not say). A vehicle that
rebooted (its clock went back) or a TCP link that reconnected has lost the intervals set:
every stream the service had set is asked again at once (:meth:`RateMonitor.renew`), with
its back-off from the start. A needed stream that was at its rate and stops altogether (a
reboot no timed stream shows: HEARTBEAT only) is asked at the next check, its back-off
from the start too.

On a link of known capacity (:mod:`glmav_observer.ingest.link_budget`) the rates asked for
are those that fit in its budget (:meth:`RateMonitor.set_plan`); a stream the service set
at another rate is asked again at the new one (it is ours); a stream set by someone else
and fast enough is still never touched.
"""

from __future__ import annotations

import collections
from collections.abc import Mapping
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink_dialect

#: A stream is short below this fraction of its need: a ground station that sets a stream
#: exactly at the need (MAVSDK's set_rate_attitude_euler(10) for a 10 Hz need) is measured
#: a little under it whenever a sample comes late (ms stamps, a loaded scheduler), and
#: must not be overridden for that.
SHORT_FRACTION = 0.9

#: MAVLink message ids of the streams we may request.
MESSAGE_IDS: dict[str, int] = {
    "ATTITUDE": mavlink_dialect.MAVLINK_MSG_ID_ATTITUDE,
    "RAW_IMU": mavlink_dialect.MAVLINK_MSG_ID_RAW_IMU,
    "SCALED_IMU": mavlink_dialect.MAVLINK_MSG_ID_SCALED_IMU,
    "HIGHRES_IMU": mavlink_dialect.MAVLINK_MSG_ID_HIGHRES_IMU,
    "LOCAL_POSITION_NED": mavlink_dialect.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "SIM_STATE": mavlink_dialect.MAVLINK_MSG_ID_SIM_STATE,
    # what the autopilot's velocity rests on (estimation/vehicle.py, "The autopilot's word")
    "EKF_STATUS_REPORT": mavlink_dialect.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
    "GPS_RAW_INT": mavlink_dialect.MAVLINK_MSG_ID_GPS_RAW_INT,
    # the actuator outputs: the drag model's cyclic regressors ([estimation.aero_control])
    "SERVO_OUTPUT_RAW": mavlink_dialect.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
}

#: ... and their names by id (a MESSAGE_INTERVAL answer names the stream by id).
MESSAGE_NAMES: dict[int, str] = {i: m for m, i in MESSAGE_IDS.items()}

#: IMU messages: the estimator needs one of them.
IMU_MESSAGES = ("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU")


@dataclass(frozen=True, slots=True)
class RateRequest:
    """Ask ``sysid``/``compid`` to send ``message`` at ``rate_hz`` (one COMMAND_LONG 511):
    -1 to stop it, 0 for the vehicle's default rate."""

    sysid: int
    compid: int
    message: str
    rate_hz: float


#: A stream set by the service is asked again when its planned rate moves by more than this
#: fraction (a link's budget changed): smaller moves are not worth a request.
REPLAN_FRACTION = 0.1


@dataclass
class RateMonitor:
    """Per-vehicle received rates (vehicle time) and the request schedule (host time).

    ``wanted_hz``: the rate to ask for (-1: ask the vehicle to stop the stream);
    ``min_hz``: below this a stream is short (0: never asked for again)."""

    wanted_hz: Mapping[str, float]
    min_hz: Mapping[str, float] = field(default_factory=dict)
    window_s: float = 2.0
    retry_s: float = 5.0
    retry_max_s: float = 60.0
    #: host time the vehicle was first heard (the first check is ``window_s`` later)
    t_registered_s: float | None = None
    _times: dict[str, collections.deque[float]] = field(default_factory=dict)
    _last_host_s: dict[str, float] = field(default_factory=dict)
    _t_host_now_s: float = 0.0
    _next_check_s: dict[str, float] = field(default_factory=dict)
    #: requests sent, per stream (all of them)
    _asked: collections.Counter[str] = field(default_factory=collections.Counter)
    #: requests sent since the last renewal: the back-off
    _attempts: collections.Counter[str] = field(default_factory=collections.Counter)
    #: the rate the service set, per stream (what it restores at its stop)
    _set_hz: dict[str, float] = field(default_factory=dict)
    #: the vehicle's interval of a stream before the service set it (µs, MESSAGE_INTERVAL:
    #: -1 disabled, 0 not available)
    _before_us: dict[str, int] = field(default_factory=dict)
    _queried: set[str] = field(default_factory=set)
    #: streams to ask again at once (the vehicle lost what the service had set)
    _renew: set[str] = field(default_factory=set)
    _renewed_at_s: float | None = None
    #: streams at their rate at their last check
    _flowing: set[str] = field(default_factory=set)

    def note(self, message: str, t_s: float, t_host_s: float) -> None:
        """A sample of ``message`` stamped ``t_s`` (vehicle) arrived at host time ``t_host_s``."""
        dq = self._times.get(message)
        if dq is None:
            dq = self._times[message] = collections.deque()
        if dq and t_s < dq[-1]:
            dq.clear()  # the vehicle's clock went back (a reboot): measure afresh
        dq.append(t_s)
        while dq[0] < t_s - self.window_s:
            dq.popleft()
        self._last_host_s[message] = t_host_s
        self._t_host_now_s = max(self._t_host_now_s, t_host_s)

    def rate_hz(self, message: str, t_host_s: float | None = None) -> float:
        """Samples per second of vehicle time over the stream's last ``window_s``; 0 if
        it has been silent for ``window_s`` of host time (default: the latest arrival)."""
        dq = self._times.get(message)
        if not dq or len(dq) < 2:
            return 0.0
        now = self._t_host_now_s if t_host_s is None else t_host_s
        if now - self._last_host_s.get(message, now) > self.window_s:
            return 0.0
        span = dq[-1] - dq[0]
        return (len(dq) - 1) / span if span > 0 else 0.0

    def rates(self, _t_now_s: float | None = None) -> dict[str, float]:
        """Every measured stream's rate (Hz, 3 decimals); the argument is ignored (the
        estimator passes its vehicle time)."""
        return {m: round(self.rate_hz(m), 3) for m in sorted(self._times)}

    def _short(self, message: str, t_host_s: float) -> bool:
        need = min(self.min_hz.get(message, 0.0), self.wanted_hz.get(message, 0.0))
        if message in IMU_MESSAGES:
            have = max(self.rate_hz(m, t_host_s) for m in IMU_MESSAGES)
        else:
            have = self.rate_hz(message, t_host_s)
        return have < SHORT_FRACTION * need

    def due_requests(self, sysid: int, compid: int, t_host_s: float) -> list[RateRequest]:
        """The requests to send now (see the module docstring). Nothing is counted here:
        :meth:`sent` counts a request written on a live link and schedules its next check;
        one not sent is due again at the next call."""
        if self.t_registered_s is None:
            self.t_registered_s = t_host_s
        out = [
            RateRequest(sysid, compid, m, self.wanted_hz.get(m, self._set_hz[m]))
            for m in sorted(self._renew)
        ]
        if t_host_s - self.t_registered_s < self.window_s:
            return out  # measure a full window before judging
        for m, hz in self.wanted_hz.items():
            if m in self._renew or t_host_s < self._next_check_s.get(m, 0.0):
                continue
            if hz < 0:  # ask once to stop it
                if not self._asked[m]:
                    out.append(RateRequest(sysid, compid, m, hz))
                else:
                    self._next_check_s[m] = float("inf")
                continue
            if hz == 0:
                self._next_check_s[m] = float("inf")
                continue
            mine = self._set_hz.get(m)
            if mine is not None and abs(mine - hz) > REPLAN_FRACTION * hz:
                out.append(RateRequest(sysid, compid, m, hz))  # ours, re-planned
            elif self.min_hz.get(m, 0.0) <= 0.0:
                # not needed by the estimator (SIM_STATE): asked once if absent, never again
                if self.rate_hz(m, t_host_s) == 0.0 and not self._attempts[m]:
                    out.append(RateRequest(sysid, compid, m, hz))
                else:
                    self._next_check_s[m] = float("inf")
            elif self._short(m, t_host_s):
                if m in self._flowing and self.rate_hz(m, t_host_s) == 0.0:
                    # it stopped altogether: the vehicle lost it (a reboot the clock cannot
                    # see: no timed stream at boot); asked with its back-off from the start
                    self._attempts[m] = 0
                self._flowing.discard(m)
                out.append(RateRequest(sysid, compid, m, hz))
            else:
                self._flowing.add(m)
                self._next_check_s[m] = t_host_s + self.window_s
        return out

    def sent(self, req: RateRequest, t_host_s: float) -> None:
        """``req`` was written on a live link at ``t_host_s``: count it, schedule the check."""
        m = req.message
        self._renew.discard(m)
        backoff = min(self.retry_s * 2.0 ** self._attempts[m], self.retry_max_s)
        self._asked[m] += 1
        self._attempts[m] += 1
        self._set_hz[m] = req.rate_hz
        if req.rate_hz < 0 or self.min_hz.get(m, 0.0) <= 0.0:
            self._next_check_s[m] = t_host_s + self.window_s  # a re-plan may still come
        else:
            self._next_check_s[m] = t_host_s + max(backoff, self.window_s)

    def asked(self, message: str) -> int:
        """How many times ``message`` was requested."""
        return self._asked[message]

    def set_plan(self, wanted_hz: Mapping[str, float], min_hz: Mapping[str, float]) -> None:
        """New rates to ask for (a link's budget): a stream the service set at a rate more
        than ``REPLAN_FRACTION`` away is asked again at its next check."""
        self.wanted_hz = dict(wanted_hz)
        self.min_hz = dict(min_hz)

    def renew(self, t_host_s: float) -> bool:
        """The vehicle lost the intervals the service set (it rebooted, or a TCP link was
        reconnected): every such stream is due at once, its back-off from the start, and
        the others are judged a ``window_s`` later. Once per ``window_s`` (a reconnect and
        the reboot it reveals are one event). True if renewed."""
        last = self._renewed_at_s
        if last is not None and 0.0 <= t_host_s - last < self.window_s:
            return False
        self._renewed_at_s = t_host_s
        self._renew = {m for m, hz in self._set_hz.items() if hz != 0}
        self._attempts.clear()
        self._next_check_s.clear()
        self.t_registered_s = t_host_s
        return True

    # -- what the vehicle had before, and putting it back ---------------------------------
    def query_due(self, message: str) -> bool:
        """True once per stream, before its first request: ask the vehicle its interval."""
        if message in self._queried or message in self._set_hz:
            return False
        self._queried.add(message)
        return True

    def note_interval(self, message_id: int, interval_us: int) -> None:
        """MESSAGE_INTERVAL: the vehicle's interval of a stream; only the first answer to
        the service's query counts (the vehicle answers it before the request that follows)."""
        name = MESSAGE_NAMES.get(message_id)
        if name is not None and name in self._queried and name not in self._before_us:
            self._before_us[name] = int(interval_us)

    def interval_before_us(self, message: str) -> int | None:
        """The stream's interval before the service set it (None: the vehicle did not say)."""
        return self._before_us.get(message)

    def restore_requests(self, sysid: int, compid: int) -> list[RateRequest]:
        """The requests that put back every stream the service set: its interval before
        (MESSAGE_INTERVAL's; interval 0, the vehicle's default rate, when it was not
        streamed or the vehicle did not say)."""
        out = []
        for m in sorted(self._set_hz):
            before = self._before_us.get(m)
            out.append(
                RateRequest(sysid, compid, m, 1e6 / before if before and before > 0 else 0.0)
            )
        return out


def _command_long(mav: object, sysid: int, compid: int, command: int, *params: float) -> bytes:
    p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    msg = mavlink_dialect.MAVLink_command_long_message(sysid, compid, command, 0, *p)
    frame: bytes = bytes(msg.pack(mav))
    return frame


def encode_rate_request(mav: object, req: RateRequest) -> bytes:
    """The COMMAND_LONG (MAV_CMD_SET_MESSAGE_INTERVAL, 511) frame for ``req``.

    param1 = message id, param2 = interval in µs: -1 stops the stream, 0 is the vehicle's
    default rate (MAVLink common.xml).
    """
    hz = req.rate_hz
    interval_us = 1e6 / hz if hz > 0 else (0.0 if hz == 0 else -1.0)
    return _command_long(
        mav,
        req.sysid,
        req.compid,
        mavlink_dialect.MAV_CMD_SET_MESSAGE_INTERVAL,
        float(MESSAGE_IDS[req.message]),
        float(interval_us),
    )


def encode_interval_query(mav: object, sysid: int, compid: int, message: str) -> bytes:
    """The COMMAND_LONG (MAV_CMD_GET_MESSAGE_INTERVAL, 510) frame asking ``message``'s
    interval (the vehicle answers with MESSAGE_INTERVAL)."""
    return _command_long(
        mav,
        sysid,
        compid,
        mavlink_dialect.MAV_CMD_GET_MESSAGE_INTERVAL,
        float(MESSAGE_IDS[message]),
    )
