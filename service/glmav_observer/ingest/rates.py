"""Message rates: what we ask the vehicle for, what arrives, and when to ask again.

Ground stations are known to override stream rates (a QGroundControl or MAVProxy on
the same vehicle sends its own ``SET_MESSAGE_INTERVAL`` / ``REQUEST_DATA_STREAM``), so
the service measures the rate it actually receives, in vehicle time, and asks again
(``MAV_CMD_SET_MESSAGE_INTERVAL``) when a stream falls below ``shortfall_ratio`` of
the configured rate, at most once per ``retry_s`` per message.
"""

from __future__ import annotations

import collections
from collections.abc import Mapping
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink_dialect

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
}


@dataclass(frozen=True, slots=True)
class RateRequest:
    """Ask ``sysid``/``compid`` to send ``message`` at ``rate_hz`` (one COMMAND_LONG 511)."""

    sysid: int
    compid: int
    message: str
    rate_hz: float


@dataclass
class RateMonitor:
    """Per-vehicle received rates over a sliding window of vehicle time."""

    wanted_hz: Mapping[str, float]
    window_s: float = 2.0
    shortfall_ratio: float = 0.8
    retry_s: float = 5.0
    _times: dict[str, collections.deque[float]] = field(default_factory=dict)
    _last_request_s: dict[str, float] = field(default_factory=dict)
    _t_first_s: float | None = None

    def note(self, message: str, t_s: float) -> None:
        """A sample of ``message`` arrived at vehicle time ``t_s``."""
        if self._t_first_s is None:
            self._t_first_s = t_s
        dq = self._times.get(message)
        if dq is None:
            dq = self._times[message] = collections.deque()
        dq.append(t_s)
        while dq and dq[0] < t_s - self.window_s:
            dq.popleft()

    def rate_hz(self, message: str, t_now_s: float) -> float:
        """Messages per second of vehicle time over the last ``window_s``."""
        dq = self._times.get(message)
        if not dq:
            return 0.0
        span = min(self.window_s, max(t_now_s - (self._t_first_s or t_now_s), 1e-9))
        n = sum(1 for t in dq if t >= t_now_s - span)
        return n / span

    def rates(self, t_now_s: float) -> dict[str, float]:
        return {m: round(self.rate_hz(m, t_now_s), 3) for m in sorted(self._times)}

    def initial_requests(self, sysid: int, compid: int, t_now_s: float) -> list[RateRequest]:
        """The configured rates, requested when the vehicle is first seen."""
        for m in self.wanted_hz:
            self._last_request_s[m] = t_now_s
        return [RateRequest(sysid, compid, m, hz) for m, hz in self.wanted_hz.items()]

    def shortfalls(self, sysid: int, compid: int, t_now_s: float) -> list[RateRequest]:
        """Requests to send again: streams below ``shortfall_ratio`` of what we asked for.

        Judged only after a full window since the vehicle (or the last request) appeared.
        """
        out: list[RateRequest] = []
        if self._t_first_s is None or t_now_s - self._t_first_s < self.window_s:
            return out
        for m, hz in self.wanted_hz.items():
            if hz <= 0:
                continue  # a stream we asked to stop
            last = self._last_request_s.get(m, -float("inf"))
            if t_now_s - last < max(self.retry_s, self.window_s):
                continue
            if self.rate_hz(m, t_now_s) < self.shortfall_ratio * hz:
                self._last_request_s[m] = t_now_s
                out.append(RateRequest(sysid, compid, m, hz))
        return out


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
