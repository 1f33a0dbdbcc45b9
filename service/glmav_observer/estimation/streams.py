"""The input streams' timing for one vehicle: mean intervals, and a velocity stream gone quiet.

The estimator needs three facts about its inputs' timing: the IMU rate (fault detection
arms only above ``min_imu_rate_hz``; γ of ``full`` follows the noise per interval), the
velocity measurement's interval (γ; how long a silence means "missing"), and whether the
measurement has stopped altogether (every configuration then dead-reckons, no switch:
a late burst on a loaded link looks the same as an all-axes dropout).

Intervals are running means in vehicle time, each step capped at ``max_gap_s`` (a gap
restarts the bank; it must not read as a slow stream): the IMU's with a time constant of
50 samples, the measurement's of 20 (real vehicles send it at 1-5 Hz, unevenly), the first
interval seeding each mean.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Running-mean gains: 1/50 per IMU sample, 1/20 per velocity measurement.
IMU_INTERVAL_GAIN = 0.02
MEASUREMENT_INTERVAL_GAIN = 0.05
#: A measurement is missing after max(missing_timeout_s, this many mean intervals).
MISSING_INTERVALS = 3.5


@dataclass
class StreamTiming:
    """Mean IMU and measurement intervals, s, and the measurement-missing state."""

    max_gap_s: float
    missing_timeout_s: float
    t_imu_s: float | None = None
    imu_interval_s: float = 0.0
    t_y_s: float = 0.0
    y_interval_s: float = 0.0
    missing: bool = False

    def imu(self, t_s: float) -> None:
        """An IMU sample at vehicle time ``t_s``."""
        if self.t_imu_s is not None and t_s > self.t_imu_s:
            dt = min(t_s - self.t_imu_s, self.max_gap_s)
            k = 1.0 if self.imu_interval_s == 0.0 else IMU_INTERVAL_GAIN
            self.imu_interval_s += k * (dt - self.imu_interval_s)
        self.t_imu_s = t_s

    @property
    def imu_hz(self) -> float:
        """The IMU's mean rate (0 before two samples)."""
        return 1.0 / self.imu_interval_s if self.imu_interval_s > 0 else 0.0

    def measurement(self, t_s: float) -> None:
        """A velocity measurement at ``t_s``: the interval's mean, and not missing."""
        if t_s > self.t_y_s:
            dt = min(t_s - self.t_y_s, self.max_gap_s)
            if self.y_interval_s == 0.0:
                self.y_interval_s = dt  # the first interval seeds the mean
            else:
                self.y_interval_s += MEASUREMENT_INTERVAL_GAIN * (dt - self.y_interval_s)
        self.t_y_s = t_s
        self.missing = False

    def check_missing(self, t_s: float) -> bool:
        """True once, when the measurement has been silent past its timeout at ``t_s``."""
        timeout = max(self.missing_timeout_s, MISSING_INTERVALS * self.y_interval_s)
        if self.missing or self.y_interval_s == 0.0 or t_s - self.t_y_s <= timeout:
            return False
        self.missing = True
        return True
