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

#: IMU messages: the estimator needs one of them.
IMU_MESSAGES = ("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU")


@dataclass(frozen=True, slots=True)
class RateRequest:
    """Ask ``sysid``/``compid`` to send ``message`` at ``rate_hz`` (one COMMAND_LONG 511)."""

    sysid: int
    compid: int
    message: str
    rate_hz: float


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
    _asked: collections.Counter[str] = field(default_factory=collections.Counter)

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
        need = self.min_hz.get(message, 0.0)
        if message in IMU_MESSAGES:
            have = max(self.rate_hz(m, t_host_s) for m in IMU_MESSAGES)
        else:
            have = self.rate_hz(message, t_host_s)
        return have < SHORT_FRACTION * need

    def due_requests(self, sysid: int, compid: int, t_host_s: float) -> list[RateRequest]:
        """The requests to send now (see the module docstring); schedules the next check."""
        if self.t_registered_s is None:
            self.t_registered_s = t_host_s
        if t_host_s - self.t_registered_s < self.window_s:
            return []  # measure a full window before judging
        out: list[RateRequest] = []
        for m, hz in self.wanted_hz.items():
            if t_host_s < self._next_check_s.get(m, 0.0):
                continue
            if hz < 0:  # ask once to stop it
                if not self._asked[m]:
                    out.append(RateRequest(sysid, compid, m, hz))
                    self._asked[m] += 1
                self._next_check_s[m] = float("inf")
                continue
            if hz == 0:
                self._next_check_s[m] = float("inf")
                continue
            if self.min_hz.get(m, 0.0) <= 0.0:
                # not needed by the estimator (SIM_STATE): asked once if absent, never again
                if self.rate_hz(m, t_host_s) == 0.0:
                    out.append(RateRequest(sysid, compid, m, hz))
                    self._asked[m] += 1
                self._next_check_s[m] = float("inf")
                continue
            if self._short(m, t_host_s):
                out.append(RateRequest(sysid, compid, m, hz))
                backoff = min(self.retry_s * 2.0 ** self._asked[m], self.retry_max_s)
                self._asked[m] += 1
                self._next_check_s[m] = t_host_s + max(backoff, self.window_s)
            else:
                self._next_check_s[m] = t_host_s + self.window_s
        return out

    def asked(self, message: str) -> int:
        """How many times ``message`` was requested."""
        return self._asked[message]


def encode_rate_request(mav: object, req: RateRequest) -> bytes:
    """The COMMAND_LONG (MAV_CMD_SET_MESSAGE_INTERVAL, 511) frame for ``req``.

    param1 = message id, param2 = interval in µs (MAVLink common.xml).
    """
    interval_us = 1e6 / req.rate_hz if req.rate_hz > 0 else -1.0
    msg = mavlink_dialect.MAVLink_command_long_message(
        req.sysid,
        req.compid,
        mavlink_dialect.MAV_CMD_SET_MESSAGE_INTERVAL,
        0,
        float(MESSAGE_IDS[req.message]),
        float(interval_us),
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
    )
    frame: bytes = bytes(msg.pack(mav))
    return frame
