"""``[mavlink_out]``'s settings, read by the configuration and used by the MAVLink output
(publish/mavlink_out.py): defined here so that the output imports nothing above it."""

from __future__ import annotations

from dataclasses import dataclass

#: Component ids a ground station uses (MAVLink's MAV_COMP_ID_MISSIONPLANNER, QGroundControl):
#: the service never claims them.
GCS_COMPONENT_IDS = frozenset({190})


@dataclass(frozen=True, slots=True)
class MavlinkOutSettings:
    """``[mavlink_out]``: the active estimate (and health) back on MAVLink (publish/mavlink_out.py)."""

    enabled: bool = False
    link: str = ""  # a pymavlink connection string, e.g. udpout:127.0.0.1:14551
    system_id: int = 0  # 0: each vehicle's own system id (a component of that vehicle)
    component_id: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    rate_hz: float = 30.0  # ODOMETRY / VISION_SPEED_ESTIMATE per vehicle, vehicle time
    odometry: bool = True
    vision_speed_estimate: bool = False
    statustext: bool = True  # fault isolations and configuration switches
    named_value_float: bool = True  # per-axis health and the active configuration
    health_rate_hz: float = 1.0  # NAMED_VALUE_FLOAT per vehicle
    sigma_measured_mps: float = 0.05  # velocity std of a measured axis in the covariance
