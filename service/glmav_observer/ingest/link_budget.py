"""What a link can carry, and the stream rates that fit in it (``[rates]`` of service.toml).

The rates the service asks a vehicle for (``[rates.hz]``: HIGHRES_IMU 250 Hz, ATTITUDE
100 Hz, ...) cost about 29 kB/s of MAVLink 2 frames: a wired or network link carries that,
a 57,600-baud telemetry radio (5,760 B/s with 8N1 framing) does not. When a link's capacity
is known, the rates asked for are chosen to fit in a fraction of it:

- capacity: ``[rates] link_bytes_per_s`` when set; else a serial link's baud rate / 10 (8N1:
  a start bit, 8 data bits, a stop bit per byte; a serial device without ``,BAUD`` is opened
  at pymavlink's 115,200); else, on a link that carries ``RADIO_STATUS`` (SiK radios inject
  it, ArduPilot relays its radio's), the bytes per second received between two RADIO_STATUS
  that both say the radio's transmit buffer is full (``txbuf`` below ``TXBUF_FULL_PERCENT``
  % free: the radio sent all it could the whole period, so what arrived is what it carries;
  a later measure replaces the estimate only if 10 % lower, so that the plan is stable). Otherwise (UDP, TCP) the rates are not limited.
- budget: ``[rates] link_budget_fraction`` of the capacity (default 0.5), shared equally by
  the vehicles on the link. Half, because the same radio carries the vehicle's own telemetry
  to the ground station (ArduPilot's default SRx streams take ~1.5-2 kB/s), parameters and
  missions, and because a SiK radio is half duplex: the uplink (commands, the ground
  station's heartbeats) takes air time from the downlink.
- a frame's cost: its MAVLink 2 length, header 10 + payload (with extensions, untruncated:
  the worst case) + CRC 2 bytes, + 13 when signing is on. HIGHRES_IMU 75 B, ATTITUDE 40 B,
  LOCAL_POSITION_NED 40 B, SIM_STATE 104 B, GPS_RAW_INT 64 B, EKF_STATUS_REPORT 38 B.
- the rates (:func:`fit_rates`): first the estimator's needs (``[rates.min_hz]``; 1 Hz for
  a stream it reads without a needed rate: the autopilot's word on its aiding, the truth);
  the rest of the budget is shared in proportion to what is wanted beyond them. If the needs
  alone do not fit, they are all scaled down by one factor (and a warning says so).

The default rates cost 29,546 B/s. At 57,600 baud: budget 2,880 B/s; the needs (4,556 B/s;
HIGHRES_IMU at 50 Hz is 3,750 B/s alone) do not fit, so every stream is asked at 0.632 of
its need: HIGHRES_IMU 31.6 Hz (2,371 B/s), ATTITUDE 6.3 Hz (253 B/s), LOCAL_POSITION_NED
3.2 Hz (126 B/s), the 1 Hz streams at 0.63 Hz. At 115,200 baud (budget 5,760 B/s):
HIGHRES_IMU 59.6 Hz, ATTITUDE 14.3 Hz, LOCAL_POSITION_NED 6.2 Hz, SIM_STATE 3.4 Hz.
"""

from __future__ import annotations

from collections.abc import Mapping

from pymavlink.dialects.v20 import ardupilotmega as mavlink_dialect

#: MAVLink 2 frame: header (magic, len, flags x2, seq, sysid, compid, msgid x3) and CRC
FRAME_OVERHEAD_BYTES = 12
#: MAVLink 2 signature (link id, 6-byte timestamp, 6-byte signature)
SIGNATURE_BYTES = 13
#: 8N1 serial framing: a start bit, 8 data bits, a stop bit
SERIAL_BITS_PER_BYTE = 10
#: pymavlink's baud rate for a serial device named without one
DEFAULT_SERIAL_BAUD = 115_200
#: share of a link's capacity the requested streams may take (see the module docstring)
DEFAULT_BUDGET_FRACTION = 0.5
#: rate asked for a stream the estimator reads without needing a rate, in the needs
FLOOR_HZ = 1.0
#: RADIO_STATUS.txbuf (% of the radio's transmit buffer free) below which the radio is full
TXBUF_FULL_PERCENT = 50
#: a lower estimate of a radio's capacity replaces the last only below this fraction of it
#: (a stable plan: each change of the rates costs a request per stream)
RADIO_CAPACITY_STEP = 0.9


def frame_bytes(message: str, *, signed: bool = False) -> int:
    """Bytes one ``message`` frame takes on the link (MAVLink 2, untruncated payload)."""
    cls = getattr(mavlink_dialect, f"MAVLink_{message.lower()}_message")
    size: int = cls.unpacker.size + FRAME_OVERHEAD_BYTES
    return size + (SIGNATURE_BYTES if signed else 0)


def cost_bytes_per_s(rates_hz: Mapping[str, float], *, signed: bool = False) -> float:
    """Bytes per second the streams at ``rates_hz`` take (streams at or below 0 Hz: none)."""
    return sum(frame_bytes(m, signed=signed) * hz for m, hz in rates_hz.items() if hz > 0)


def serial_capacity_bytes_per_s(conn: str) -> float | None:
    """Bytes per second a serial connection string carries (``/dev/ttyUSB0,57600``,
    ``COM3``), None for a network link."""
    if not conn.startswith(("/", "COM")) or conn.endswith(".tlog"):
        return None
    _, sep, baud = conn.rpartition(",")
    rate = int(baud) if sep and baud.isdigit() and int(baud) > 0 else DEFAULT_SERIAL_BAUD
    return rate / SERIAL_BITS_PER_BYTE


def fit_rates(
    wanted_hz: Mapping[str, float],
    need_hz: Mapping[str, float],
    budget_bytes_per_s: float,
    *,
    signed: bool = False,
) -> dict[str, float]:
    """The rates to ask for within ``budget_bytes_per_s`` (see the module docstring).

    Streams not asked for a rate (0, or -1: asked to stop) are kept as they are."""
    asked = {m: hz for m, hz in wanted_hz.items() if hz > 0}
    out = {m: hz for m, hz in wanted_hz.items() if hz <= 0}
    if cost_bytes_per_s(asked, signed=signed) <= budget_bytes_per_s:
        return {**out, **asked}
    floor = {
        m: min(hz, need_hz.get(m, 0.0) if need_hz.get(m, 0.0) > 0 else FLOOR_HZ)
        for m, hz in asked.items()
    }
    floor_cost = cost_bytes_per_s(floor, signed=signed)
    if floor_cost >= budget_bytes_per_s:
        scale = budget_bytes_per_s / floor_cost
        return {**out, **{m: hz * scale for m, hz in floor.items()}}
    extra = {m: asked[m] - floor[m] for m in asked}
    share = (budget_bytes_per_s - floor_cost) / cost_bytes_per_s(extra, signed=signed)
    return {**out, **{m: floor[m] + share * extra[m] for m in asked}}


class LinkCapacity:
    """One link's capacity in bytes per second (None: not limited), from the configuration,
    the serial baud rate or the link's RADIO_STATUS (see the module docstring)."""

    def __init__(self, conn: str, configured_bytes_per_s: float | None = None) -> None:
        self.conn = conn
        self.fixed = configured_bytes_per_s or serial_capacity_bytes_per_s(conn)
        #: the radio's estimate (RADIO_STATUS), None before the radio's buffer ever filled
        self.radio_bytes_per_s: float | None = None
        self.rx_bytes = 0
        self._last_status: tuple[float, int, bool] | None = None  # (t, rx_bytes, full)

    @property
    def bytes_per_s(self) -> float | None:
        if self.fixed is not None:
            return self.fixed
        return self.radio_bytes_per_s

    def radio_status(self, txbuf_percent: int, t_host_s: float) -> bool:
        """A RADIO_STATUS arrived at ``t_host_s``; True if the capacity estimate changed.

        Measured over the period from the previous RADIO_STATUS when both said the radio
        was full: it sent all it could the whole period."""
        full = txbuf_percent < TXBUF_FULL_PERCENT
        last, self._last_status = self._last_status, (t_host_s, self.rx_bytes, full)
        if last is None or not (full and last[2]) or t_host_s - last[0] <= 0.0:
            return False
        received = (self.rx_bytes - last[1]) / (t_host_s - last[0])
        est = self.radio_bytes_per_s
        if est is None or received < RADIO_CAPACITY_STEP * est:  # first, or a slower radio
            self.radio_bytes_per_s = received
            return True
        return False
