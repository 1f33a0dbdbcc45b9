"""Type stub of the compiled models.pyx."""

import numpy as np

from glmav_sitl.scenario import Fault, SensorConfig

Vec3 = tuple[float, float, float]

class Normals:
    def __init__(self, rng: np.random.Generator) -> None: ...
    def draw(self) -> float: ...

class ImuModel:
    @property
    def gyro_bias_radps(self) -> list[float]: ...
    @property
    def accel_bias_mps2(self) -> list[float]: ...
    def __init__(
        self, cfg: SensorConfig, rng: np.random.Generator, faults: tuple[Fault, ...] = ()
    ) -> None: ...
    def accel_fault_bias(self, t_s: float) -> Vec3: ...
    def sample(
        self, t_s: float, omega_body_radps: Vec3, f_body_mps2: Vec3, rate_hz: float
    ) -> tuple[Vec3, Vec3]: ...
    def sample_fast(
        self, t_s: float, omega_body_radps: Vec3, f_body_mps2: Vec3, rate_hz: float
    ) -> tuple[Vec3, Vec3]: ...

class AttitudeSensor:
    def __init__(self, cfg: SensorConfig, rng: np.random.Generator) -> None: ...
    def sample(
        self, euler_rad: Vec3, omega_body_radps: Vec3, rate_hz: float
    ) -> tuple[Vec3, Vec3]: ...

class PositionVelocitySensor:
    def __init__(
        self,
        cfg: SensorConfig,
        rng: np.random.Generator,
        fault_rng: np.random.Generator,
        faults: tuple[Fault, ...] = (),
    ) -> None: ...
    @property
    def velocity_sigma_mps(self) -> float: ...
    def set_velocity_sigma_mps(self, sigma_mps: float) -> None: ...
    def set_faults(self, faults: tuple[Fault, ...]) -> None: ...
    def sample(self, t_s: float, p_ned_m: Vec3, v_ned_mps: Vec3) -> tuple[Vec3, Vec3]: ...

class FastImu:
    gyro_radps: Vec3
    accel_mps2: Vec3
    def __init__(
        self,
        imu: ImuModel,
        g_mps2: float,
        interval_us: int,
        v0_ned_mps: Vec3,
        trim2: tuple[float, float],
        vib: list[list[tuple[float, tuple[float, ...], tuple[float, ...]]]],
        vib_on: bool,
        accel0_mps2: Vec3,
    ) -> None: ...
    def sample(
        self,
        t_us: int,
        qw: float,
        qx: float,
        qy: float,
        qz: float,
        v_ned: Vec3,
        omega: Vec3,
        w1: float,
        w2: float,
    ) -> None: ...
    def take_sums(self) -> tuple[list[float], int]: ...
