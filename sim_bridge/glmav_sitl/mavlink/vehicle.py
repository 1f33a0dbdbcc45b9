"""The simulated vehicle's MAVLink 2 side: streams, commands, tlog.

Messages (``pymavlink.dialects.v20.common``; one encoder, so one sequence number
across links), all stamped with the vehicle's own clock (sim time since boot):

==================  ================================================================
HEARTBEAT           MAV_TYPE_COAXIAL, MAV_AUTOPILOT_PX4 (its custom_mode layout, so a
                    GCS names the modes); armed while rotors turn
RAW_IMU             accel in ``raw_accel_lsb_mps2`` units (default 1 mG = 9.80665e-3
                    m/s^2), gyro in ``raw_gyro_lsb_radps`` (default 1 mrad/s), int16
                    rounded and saturated; FRD; ``time_usec`` = sim time
SCALED_IMU          accel mG, gyro mrad/s (the message's fixed units), ``time_boot_ms``
HIGHRES_IMU         accel m/s^2, gyro rad/s (float), ``fields_updated`` = 0x3F
ATTITUDE            ZYX roll, pitch, yaw (rad) and body rates (rad/s) with noise
LOCAL_POSITION_NED  x, y, z (m) and vx, vy, vz (m/s, NED) with noise and faults
SERVO_OUTPUT_RAW    the commanded (Ω1, Ω2, δcx, δcy) on channels 1-4 as PWM µs
                    (:mod:`glmav_sitl.mavlink.servo`); ``time_usec`` = sim time
SIM_STATE           truth: q1..q4 = (w, x, y, z) body->NED; roll, pitch, yaw;
                    xacc.. = true specific force FRD (m/s^2); xgyro.. = true rates;
                    lat, lon (deg, float) / lat_int, lon_int (degE7) / alt (m AMSL)
                    from the home point (flat earth); vn, ve, vd = true NED velocity
                    (m/s); std_dev_horz / vert = the configured position noise
==================  ================================================================

Ground-station telemetry (GLOBAL_POSITION_INT, SYS_STATUS, HOME_POSITION,
EXTENDED_SYS_STATE, VFR_HUD; :mod:`glmav_sitl.gcs.telemetry`) and STATUSTEXT for events.

Commands (COMMAND_LONG and COMMAND_INT addressed to our system or broadcast):
SET_MESSAGE_INTERVAL (511), GET_MESSAGE_INTERVAL (510), REQUEST_MESSAGE (512, e.g.
AUTOPILOT_VERSION 148, HOME_POSITION 242), GET_HOME_POSITION (410),
REQUEST_AUTOPILOT_CAPABILITIES (520) are ACCEPTED (or DENIED for a bad argument); the
flight commands (arm, disarm, takeoff, land, RTL, hold, DO_SET_MODE) are the autopilot's
(:mod:`glmav_sitl.gcs.autopilot`); every other command gets MAV_RESULT_UNSUPPORTED.
PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET serve :mod:`glmav_sitl.gcs.params`;
SET_POSITION_TARGET_LOCAL_NED feeds OFFBOARD; ODOMETRY and VISION_SPEED_ESTIMATE from
another component (an onboard estimator) are compared with the truth at their
``time_usec`` and reported (:class:`ReceivedEstimates`).
Malformed bytes and unknown messages are counted and ignored. With a signing key, outgoing
packets are signed (MAVLink 2 signing, link id 0, timestamps from the sim clock) and
incoming packets must carry a valid signature with that key.

tlog: each message as an 8-byte big-endian microsecond timestamp followed by the
packet, timestamps ``start_unix_s + t_sim`` so that a seeded run is reproducible.

One class, the vehicle's MAVLink endpoint, over 500 lines: its streams and its answers share
one encoder (one sequence number), the parsers and the stream timers, and ``emit`` writes
each message's fields out one per line.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import IO, Any

from pymavlink.dialects.v20 import common as mavlink2

from glmav_sitl.gcs import telemetry
from glmav_sitl.gcs.autopilot import Autopilot, Mode
from glmav_sitl.gcs.params import ParamError, ParamTable, default_params
from glmav_sitl.mavlink.frame import StreamWriter
from glmav_sitl.mavlink.links import Link
from glmav_sitl.mavlink.servo import servo_pwm_us
from glmav_sitl.scenario import STREAM_IDS
from glmav_sitl.simulator import Simulator, TruthState

log = logging.getLogger(__name__)

MSG_AUTOPILOT_VERSION = 148
MSG_HOME_POSITION = 242
CMD_GET_HOME_POSITION = 410
CMD_GET_MESSAGE_INTERVAL = 510
CMD_SET_MESSAGE_INTERVAL = 511
CMD_REQUEST_MESSAGE = 512
CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
_MAVLINK_EPOCH_UNIX_S = 1420070400  # 2015-01-01, origin of signing timestamps
_EARTH_RADIUS_M = 6378137.0


@dataclass
class Stats:
    sent: dict[str, int] = field(default_factory=dict)
    received: int = 0
    bad_input: int = 0
    commands: int = 0


@dataclass
class ReceivedEstimates:
    """ODOMETRY / VISION_SPEED_ESTIMATE received, against the truth at their ``time_usec``."""

    count: dict[str, int] = field(default_factory=dict)
    sources: set[tuple[int, int]] = field(default_factory=set)
    compared: int = 0
    sq_err_ned: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    max_abs_err_mps: float = 0.0
    estimator_types: set[int] = field(default_factory=set)
    last_v_ned_mps: tuple[float, float, float] | None = None
    reset_counters: set[int] = field(default_factory=set)
    qualities: set[int] = field(default_factory=set)
    #: what other components said: STATUSTEXT texts, NAMED_VALUE_FLOAT (name -> values),
    #: HEARTBEAT (sysid, compid) -> (type, autopilot)
    texts: list[str] = field(default_factory=list)
    named_values: dict[str, list[float]] = field(default_factory=dict)
    heartbeats: dict[tuple[int, int], tuple[int, int]] = field(default_factory=dict)

    def rmse_ned_mps(self) -> tuple[float, float, float] | None:
        if self.compared == 0:
            return None
        n = self.compared
        e = self.sq_err_ned
        return (math.sqrt(e[0] / n), math.sqrt(e[1] / n), math.sqrt(e[2] / n))


#: truth history kept for comparing received estimates (s): an onboard estimator may lag
_TRUTH_HISTORY_S = 30.0


class _Fanout:
    """The file object of the encoder: every packet to each link and the tlog."""

    def __init__(self, links: Sequence[Link], tlog: IO[bytes] | None) -> None:
        self.links = list(links)
        self.tlog = tlog
        self.stamp_us = 0

    def write(self, buf: bytes) -> None:
        for link in self.links:
            link.write(buf)
        if self.tlog is not None:
            self.tlog.write(struct.pack(">Q", self.stamp_us) + bytes(buf))


class MavlinkVehicle:
    """Encodes the simulator's streams and answers commands on ``links``."""

    def __init__(
        self,
        sim: Simulator,
        links: Sequence[Link],
        *,
        rates_hz: dict[str, float],
        sysid: int,
        compid: int = 1,
        tlog: IO[bytes] | None = None,
        signing_key: bytes | None = None,
        ground_station_flight: bool = False,
    ) -> None:
        self.sim = sim
        self.sysid = sysid
        self.compid = compid
        self.start_unix_us = round(sim.sitl.start_unix_s * 1e6)
        self.out = _Fanout(links, tlog)
        self.mav = mavlink2.MAVLink(self.out, srcSystem=sysid, srcComponent=compid)
        #: the sensor streams' packets, packed and framed in C (one sequence with mav)
        self.streams = StreamWriter(self.mav, links, tlog)
        self.signing_key = signing_key
        if signing_key is not None:
            if len(signing_key) != 32:
                raise ValueError("the signing key must be 32 bytes")
            self.mav.signing.secret_key = signing_key
            self.mav.signing.link_id = 0
            self.mav.signing.sign_outgoing = True
        self.parsers = [self._new_parser() for _ in links]
        self.links = list(links)
        self.default_interval_us = {k: self._interval(v) for k, v in rates_hz.items()}
        for k, (_mid, hz) in telemetry.GCS_STREAMS.items():
            self.default_interval_us.setdefault(k, self._interval(hz))
        self.interval_us = dict(self.default_interval_us)
        self.next_due_us = {k: 0 for k in self.interval_us}
        self._next_any_us = 0
        self.stats = Stats(sent={k: 0 for k in (*STREAM_IDS, *telemetry.GCS_STREAMS)})
        home = sim.sitl
        self._lat0 = home.home_lat_deg
        self._lon0 = home.home_lon_deg
        self._alt0 = home.home_alt_m
        self._ids = dict(STREAM_IDS) | {k: v[0] for k, v in telemetry.GCS_STREAMS.items()}
        self._order = [k for k in self._ids if k in self.interval_us]
        self._by_id = {v: k for k, v in self._ids.items()}
        self.gcs_flight = ground_station_flight
        self.params: ParamTable | None = None
        self.autopilot: Autopilot | None = None
        if sim.controller is not None:
            self.params = default_params(
                sim.params,
                velocity_sigma_mps=sim.position_sensor.velocity_sigma_mps,
                max_speed_mps=sim.controller.k.max_speed_mps,
                on_change=self._param_changed,
            )
            self.autopilot = Autopilot(
                sim, self.params, ground_station_flight=ground_station_flight
            )
        elif ground_station_flight:
            raise ValueError("ground-station flight needs a closed-loop vehicle")
        self.received_estimates = ReceivedEstimates()
        self._truth_hist: list[tuple[int, tuple[float, float, float]]] = []
        self.statustexts_sent: list[str] = []

    def _new_parser(self) -> Any:
        p = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=self.compid)
        p.robust_parsing = True
        if self.signing_key is not None:
            # signed link: only packets signed with our key are accepted (bad or missing
            # signatures surface as BAD_DATA and are counted)
            p.signing.secret_key = self.signing_key
            p.signing.allow_unsigned_callback = None
        return p

    @staticmethod
    def _interval(rate_hz: float) -> int:
        return 0 if rate_hz <= 0.0 else max(1, round(1e6 / rate_hz))

    # ------------------------------------------------------------------ output
    def _stamp(self) -> int:
        """The tlog stamp of a packet sent now (us); with signing, the signing clock
        brought up to the sim clock."""
        t_us = self.sim.t_us
        stamp_us: int = self.start_unix_us + t_us
        self.out.stamp_us = stamp_us
        if self.signing_key is not None:
            ts = (self.start_unix_us // 1_000_000 - _MAVLINK_EPOCH_UNIX_S) * 100_000 + t_us // 10
            self.mav.signing.timestamp = max(self.mav.signing.timestamp, ts)
        return stamp_us

    def _send(self, msg: Any) -> None:
        self._stamp()
        self.mav.send(msg)

    def poll_streams(self) -> None:
        """Emit every stream that is due at the simulator's current time."""
        t_us = self.sim.t_us
        if t_us < self._next_any_us:
            return
        nxt = 1 << 62
        interval_us, next_due_us = self.interval_us, self.next_due_us
        for name in self._order:
            iv = interval_us[name]
            if iv <= 0:
                continue
            due = next_due_us[name]
            if t_us >= due:
                self.emit(name)
                due += iv
                if due <= t_us:  # fell behind (rate above the step rate): skip, do not burst
                    due = t_us + iv
                next_due_us[name] = due
            nxt = min(nxt, due)
        self._next_any_us = nxt

    @property
    def next_stream_us(self) -> int:
        """When :meth:`poll_streams` next has something to send (sim time, us; at or
        before now: at the next poll)."""
        return self._next_any_us

    def set_interval(self, name: str, interval_us: int) -> None:
        self.interval_us[name] = interval_us
        self.next_due_us[name] = self.sim.t_us
        self._next_any_us = 0

    def emit(self, name: str) -> None:
        """Sample the sensors for ``name`` and send the message now."""
        sim = self.sim
        tr = sim.truth()
        t_us = sim.t_us
        t_ms = t_us // 1000
        iv = self.interval_us.get(name, 0)
        if iv <= 0:  # a one-off (REQUEST_MESSAGE) of a disabled stream: its default rate's noise
            iv = self.default_interval_us.get(name, 0)
        rate = 1e6 / iv if iv > 0 else 0.0

        if name == "heartbeat":
            ap = self.autopilot
            if ap is not None and ap.gcs_flight:
                armed = ap.armed
            else:
                armed = tr.rotor_radps[0] > 1.0 or tr.rotor_radps[1] > 1.0
            custom = (ap.mode if ap is not None else Mode.MISSION).custom_mode
            msg = mavlink2.MAVLink_heartbeat_message(
                mavlink2.MAV_TYPE_COAXIAL,
                # custom_mode is in PX4's layout: a GCS reads (and sets) the modes by
                # name only when the autopilot says it is PX4
                mavlink2.MAV_AUTOPILOT_PX4,
                mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                | (mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0),
                custom,
                mavlink2.MAV_STATE_ACTIVE if armed else mavlink2.MAV_STATE_STANDBY,
                3,
            )
        elif name in ("raw_imu", "scaled_imu", "highres_imu"):
            gyro, acc = sim.imu.sample(tr.t_s, tr.omega_body_radps, self._specific_force(tr), rate)
            if name == "highres_imu":
                self.streams.highres_imu(self._stamp(), t_us, gyro, acc)
            elif name == "raw_imu":
                c = sim.sensor_config.imu
                ka, kg = 1.0 / c.raw_accel_lsb_mps2, 1.0 / c.raw_gyro_lsb_radps
                self.streams.raw_imu(self._stamp(), t_us, gyro, acc, ka, kg)
            else:
                self.streams.scaled_imu(self._stamp(), t_ms, gyro, acc)
            self.stats.sent[name] += 1
            return
        elif name == "attitude":
            eul, w = sim.attitude_sensor.sample(tr.euler_rad, tr.omega_body_radps, rate)
            self.streams.attitude(self._stamp(), t_ms, eul, w)
            self.stats.sent[name] += 1
            return
        elif name == "local_position_ned":
            pos, vel = sim.position_sensor.sample(tr.t_s, tr.p_ned_m, tr.v_ned_mps)
            self.streams.local_position_ned(self._stamp(), t_ms, pos, vel)
            self.stats.sent[name] += 1
            return
        elif name == "servo_output_raw":
            pwm = servo_pwm_us(sim.u, sim.params)  # the command: glmav_sitl.mavlink.servo
            msg = mavlink2.MAVLink_servo_output_raw_message(
                t_us & 0xFFFFFFFF, 0, pwm[0], pwm[1], pwm[2], pwm[3], 0, 0, 0, 0
            )
        elif name == "sim_state":
            lat = self._lat0 + math.degrees(tr.p_ned_m[0] / _EARTH_RADIUS_M)
            lon = self._lon0 + math.degrees(
                tr.p_ned_m[1] / (_EARTH_RADIUS_M * math.cos(math.radians(self._lat0)))
            )
            q = tr.q
            e = tr.euler_rad
            f = self._specific_force(tr)
            w = tr.omega_body_radps
            v = tr.v_ned_mps
            sc = sim.sensor_config
            k = sc.noise_scale if sc.noise else 0.0
            self.streams.sim_state(
                self._stamp(),
                (
                    *q,
                    *e,
                    *f,
                    *w,
                    lat,
                    lon,
                    self._alt0 - tr.p_ned_m[2],
                    sc.position_sigma_m * k,
                    sc.position_sigma_m * k,
                    *v,
                ),
                round(lat * 1e7),
                round(lon * 1e7),
            )
            self.stats.sent[name] += 1
            return
        elif name in telemetry.GCS_STREAMS and self.autopilot is not None:
            msg = telemetry.message(name, sim, tr, self.autopilot)
        else:
            return
        self._send(msg)
        self.stats.sent[name] = self.stats.sent.get(name, 0) + 1

    def _specific_force(self, tr: TruthState) -> tuple[float, float, float]:
        """What an accelerometer reads: the model's, or on the ground the ground's push."""
        ap = self.autopilot
        if ap is not None and ap.resting:
            return (0.0, 0.0, -self.sim.params.g)  # level on the ground: the normal force
        return tr.f_body_mps2

    def send_autopilot_version(self) -> None:
        self._send(
            mavlink2.MAVLink_autopilot_version_message(
                mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED,
                (0 << 24) | (1 << 16) | (0 << 8) | 255,  # 0.1.0 release
                0,
                0,
                0,
                [0] * 8,
                [0] * 8,
                [0] * 8,
                0,
                0,
                self.sysid,
                [0] * 18,
            )
        )

    # ------------------------------------------------------------------- input
    def poll_inputs(self) -> None:
        """Read every link, parse, and answer what is addressed to us."""
        for i, link in enumerate(self.links):
            for data in link.read():
                try:
                    msgs = self.parsers[i].parse_buffer(data) or []
                except Exception as e:  # pymavlink raises bare MAVError / struct errors
                    self.stats.bad_input += 1
                    log.debug("link %s: bad input (%s)", link.name, e)
                    self.parsers[i] = self._new_parser()
                    continue
                for m in msgs:
                    self.handle(m)

    def _for_us(self, m: Any) -> bool:
        return m.target_system in (0, self.sysid) and m.target_component in (0, self.compid)

    def handle(self, m: Any) -> None:
        t = m.get_type()
        if t == "BAD_DATA":
            self.stats.bad_input += 1
            return
        self.stats.received += 1
        if t in ("ODOMETRY", "VISION_SPEED_ESTIMATE"):
            self._received_estimate(t, m)
        elif t in ("STATUSTEXT", "NAMED_VALUE_FLOAT", "HEARTBEAT"):
            self._received_report(t, m)
        elif t.startswith("PARAM_"):
            self._param_message(t, m)
        elif t == "SET_POSITION_TARGET_LOCAL_NED":
            if self.autopilot is not None and self._for_us(m):
                self.autopilot.position_target(
                    int(m.coordinate_frame),
                    int(m.type_mask),
                    (m.x, m.y, m.z),
                    (m.vx, m.vy, m.vz),
                    m.yaw,
                )
        elif t == "SET_MODE":
            if self.autopilot is not None and m.target_system in (0, self.sysid):
                mode = Mode.from_main_sub(
                    (m.custom_mode >> 16) & 0xFF, (m.custom_mode >> 24) & 0xFF
                )
                if mode is not None:
                    self.autopilot.select_mode(mode)
        elif t in ("COMMAND_LONG", "COMMAND_INT"):
            if not self._for_us(m):
                return
            self.stats.commands += 1
            if t == "COMMAND_LONG":
                p7 = [m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7]
            else:
                p7 = [m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z]
            try:
                result = self.command(int(m.command), p7)
            except (ValueError, OverflowError) as err:
                # a NaN or infinite parameter where a number is needed (a message id, a
                # mode): refused and acknowledged, never the end of the command handling
                result = int(mavlink2.MAV_RESULT_DENIED)
                self.statustext(
                    mavlink2.MAV_SEVERITY_WARNING, f"command {int(m.command)} refused: {err}"[:50]
                )
            log.debug(
                "command %d %s from %d/%d: result %d",
                m.command,
                [round(x, 3) for x in p7],
                m.get_srcSystem(),
                m.get_srcComponent(),
                result,
            )
            self._send(
                mavlink2.MAVLink_command_ack_message(
                    m.command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()
                )
            )
        self.flush_events()

    # --------------------------------------------------------------- autopilot
    def tick(self) -> None:
        """At the control rate: the autopilot's transitions, events, the truth history."""
        if self.autopilot is None:
            return
        self.autopilot.tick()
        self.flush_events()
        hist = self._truth_hist
        hist.append((self.sim.t_us, self.autopilot.v_ned_mps()))
        if hist[-1][0] - hist[0][0] > _TRUTH_HISTORY_S * 1e6 * 1.2:
            t_min = hist[-1][0] - round(_TRUTH_HISTORY_S * 1e6)
            self._truth_hist = [h for h in hist if h[0] >= t_min]

    def flush_events(self) -> None:
        if self.autopilot is None or not self.autopilot.events:
            return
        events, self.autopilot.events = self.autopilot.events, []
        for ev in events:
            log.info("statustext: %s", ev.text)
            self.statustext(ev.severity, ev.text)

    def statustext(self, severity: int, text: str) -> None:
        self.statustexts_sent.append(text)
        self._send(telemetry.statustext(severity, text))

    def _param_changed(self, name: str, value: float) -> None:
        if self.autopilot is not None:
            self.autopilot.param_changed(name, value)

    def _param_value(self, index: int) -> None:
        assert self.params is not None
        p = self.params.at(index)
        self._send(
            mavlink2.MAVLink_param_value_message(
                p.name.encode(),
                p.value,
                mavlink2.MAV_PARAM_TYPE_REAL32,
                len(self.params),
                index,
            )
        )

    def _param_message(self, t: str, m: Any) -> None:
        if self.params is None or not self._for_us(m):
            return
        if t == "PARAM_REQUEST_LIST":
            for i in range(len(self.params)):
                self._param_value(i)
            return
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else ""
        if t == "PARAM_REQUEST_READ":
            if 0 <= m.param_index < len(self.params):
                self._param_value(int(m.param_index))
            elif self.params.find(name) is not None:
                self._param_value(self.params.index(name))
            return
        if t == "PARAM_SET":
            p = self.params.find(name)
            try:
                self.params.set(name, float(m.param_value))
            except ParamError as e:
                self.statustext(mavlink2.MAV_SEVERITY_WARNING, str(e))
            if p is not None:  # the value now in force, set or not (the protocol's answer)
                self._param_value(self.params.index(name))

    def _received_report(self, t: str, m: Any) -> None:
        """Another component's HEARTBEAT, STATUSTEXT or NAMED_VALUE_FLOAT, kept for the summary."""
        r = self.received_estimates
        if t == "HEARTBEAT":
            r.heartbeats[(m.get_srcSystem(), m.get_srcComponent())] = (
                int(m.type),
                int(m.autopilot),
            )
        elif t == "STATUSTEXT":
            r.texts.append(str(m.text))
        else:
            r.named_values.setdefault(str(m.name), []).append(float(m.value))

    def _received_estimate(self, t: str, m: Any) -> None:
        r = self.received_estimates
        src = (m.get_srcSystem(), m.get_srcComponent())
        if not r.count:
            self.statustext(mavlink2.MAV_SEVERITY_INFO, f"{t} received from {src[0]}/{src[1]}")
        r.count[t] = r.count.get(t, 0) + 1
        r.sources.add(src)
        if t == "ODOMETRY":
            if m.child_frame_id != mavlink2.MAV_FRAME_LOCAL_NED:
                return  # only NED velocities are compared
            r.estimator_types.add(int(m.estimator_type))
            r.reset_counters.add(int(m.reset_counter))
            r.qualities.add(int(m.quality))
            t_us, v = int(m.time_usec), (m.vx, m.vy, m.vz)
        else:
            t_us, v = int(m.usec), (m.x, m.y, m.z)
        if not all(math.isfinite(x) for x in v):
            return
        r.last_v_ned_mps = (float(v[0]), float(v[1]), float(v[2]))
        hist = self._truth_hist
        if not hist or not hist[0][0] <= t_us <= hist[-1][0] + 10_000:
            return
        # nearest truth sample (250 Hz history: within 2 ms of the estimate's time)
        lo, hi = 0, len(hist) - 1
        while lo < hi:
            mid = (lo + hi) // 2
            if hist[mid][0] < t_us:
                lo = mid + 1
            else:
                hi = mid
        tv = hist[lo][1]
        r.compared += 1
        for i in range(3):
            e = v[i] - tv[i]
            r.sq_err_ned[i] += e * e
            r.max_abs_err_mps = max(r.max_abs_err_mps, abs(e))

    def command(self, cmd: int, params: Sequence[float]) -> int:
        """Execute a command; returns a MAV_RESULT."""
        if self.autopilot is not None:
            result = self.autopilot.command(cmd, params)
            if result is not None:
                return result
        if cmd == CMD_GET_HOME_POSITION:
            self._send(telemetry.home_position(self.sim))
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        if cmd == CMD_SET_MESSAGE_INTERVAL:
            name = self._by_id.get(int(params[0]))
            if name is None or (name == "heartbeat" and params[1] < 0):
                return int(
                    mavlink2.MAV_RESULT_UNSUPPORTED if name is None else mavlink2.MAV_RESULT_DENIED
                )
            iv = params[1]
            if iv < -1 or not math.isfinite(iv):
                return int(mavlink2.MAV_RESULT_DENIED)
            self.set_interval(
                name,
                0
                if iv == -1
                else (self.default_interval_us.get(name, 0) if iv == 0 else round(iv)),
            )
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        if cmd == CMD_GET_MESSAGE_INTERVAL:
            name = self._by_id.get(int(params[0]))
            if name is None:
                return int(mavlink2.MAV_RESULT_UNSUPPORTED)
            iv = self.interval_us.get(name, 0)
            self._send(
                mavlink2.MAVLink_message_interval_message(self._ids[name], iv if iv > 0 else -1)
            )
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        if cmd == CMD_REQUEST_MESSAGE:
            mid = int(params[0])
            if mid == MSG_AUTOPILOT_VERSION:
                self.send_autopilot_version()
                return int(mavlink2.MAV_RESULT_ACCEPTED)
            if mid == MSG_HOME_POSITION:
                self._send(telemetry.home_position(self.sim))
                return int(mavlink2.MAV_RESULT_ACCEPTED)
            name = self._by_id.get(mid)
            if name is None:
                return int(mavlink2.MAV_RESULT_UNSUPPORTED)
            if name not in self.interval_us:
                self.interval_us[name] = 0
            self.emit(name)
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        if cmd == CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self.send_autopilot_version()
            return int(mavlink2.MAV_RESULT_ACCEPTED)
        return int(mavlink2.MAV_RESULT_UNSUPPORTED)
