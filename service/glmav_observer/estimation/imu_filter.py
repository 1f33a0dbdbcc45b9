"""The delay of the autopilot's accelerometer low-pass, from what the link says it is.

An autopilot sends its accelerometer after its own low-pass filter: ArduPilot's
``RAW_IMU`` and ``SCALED_IMU2/3`` carry ``AP_InertialSensor::get_accel``, filtered by a
two-pole Butterworth biquad at ``INS_ACCEL_FILTER`` (``LowPassFilter2p``; 20 Hz by
default, 10 Hz on a rover: ``DEFAULT_ACCEL_FILTER`` in ``AP_InertialSensor.cpp``). Below
its cutoff such a filter delays the signal by its group delay at DC, √2/(2π f_c) (11.25 ms
at 20 Hz), so a velocity integrated from it lags truth by as much. The bank takes each
IMU sample's change that much earlier (``BankCore.centre_imu``; docs/field-failures.md,
"The accelerometer's filter").

Which filter: ``[estimation] imu_filter_hz`` when set (> 0); else the vehicle's own
``INS_ACCEL_FILTER`` when a log carries its parameters (an ArduPilot dataflash log: its
``IMU`` messages are ``get_accel`` too); else the firmware's default from the vehicle's
HEARTBEAT (autopilot and type); else none (a PX4 vehicle, a simulator: their filters were
not measured here, so nothing is assumed).
"""

from __future__ import annotations

import math

#: MAVLink MAV_AUTOPILOT_ARDUPILOTMEGA (every ArduPilot vehicle)
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
#: MAVLink MAV_TYPE of ArduPilot's Rover firmware (its default filter is 10 Hz)
_ROVER_TYPES = frozenset({10, 11})  # MAV_TYPE_GROUND_ROVER, MAV_TYPE_SURFACE_BOAT
#: ArduPilot's DEFAULT_ACCEL_FILTER (Hz): Rover 10, every other vehicle 20
ARDUPILOT_ACCEL_FILTER_HZ = 20.0
ARDUPILOT_ROVER_ACCEL_FILTER_HZ = 10.0


def lowpass2_group_delay_s(cutoff_hz: float) -> float:
    """The group delay at DC of a two-pole Butterworth low-pass at ``cutoff_hz``:
    √2/(2π f_c) s (0 for no filter, ``cutoff_hz`` ≤ 0)."""
    if not cutoff_hz > 0.0:
        return 0.0
    return math.sqrt(2.0) / (2.0 * math.pi * cutoff_hz)


def firmware_accel_filter_hz(autopilot: int, mav_type: int) -> float:
    """The accelerometer low-pass cutoff a firmware sends by default (0: not known)."""
    if autopilot != MAV_AUTOPILOT_ARDUPILOTMEGA:
        return 0.0
    return (
        ARDUPILOT_ROVER_ACCEL_FILTER_HZ if mav_type in _ROVER_TYPES else ARDUPILOT_ACCEL_FILTER_HZ
    )


def accel_filter_delay_s(
    configured_hz: float,
    autopilot: int | None,
    mav_type: int | None,
    vehicle_hz: float | None = None,
) -> float:
    """The delay to take out of the accelerometer: the configured cutoff's (> 0), else
    the vehicle's own setting (``vehicle_hz``, a logged parameter), else the firmware
    default's once the HEARTBEAT has named it, else 0."""
    if configured_hz > 0.0:
        return lowpass2_group_delay_s(configured_hz)
    if vehicle_hz is not None:
        return lowpass2_group_delay_s(vehicle_hz)
    if autopilot is None or mav_type is None:
        return 0.0
    return lowpass2_group_delay_s(firmware_accel_filter_hz(autopilot, mav_type))
