"""Type stub of the compiled frame.pyx."""

from collections.abc import Sequence
from typing import IO, Any

from glmav_sitl.mavlink.links import Link

def i16(x: float) -> int: ...

class StreamWriter:
    def __init__(self, mav: Any, links: Sequence[Link], tlog: IO[bytes] | None) -> None: ...
    def highres_imu(
        self, stamp_us: int, t_us: int, gyro: Sequence[float], acc: Sequence[float]
    ) -> None: ...
    def raw_imu(
        self,
        stamp_us: int,
        t_us: int,
        gyro: Sequence[float],
        acc: Sequence[float],
        ka: float,
        kg: float,
    ) -> None: ...
    def scaled_imu(
        self, stamp_us: int, t_ms: int, gyro: Sequence[float], acc: Sequence[float]
    ) -> None: ...
    def attitude(
        self, stamp_us: int, t_ms: int, eul: Sequence[float], w: Sequence[float]
    ) -> None: ...
    def local_position_ned(
        self, stamp_us: int, t_ms: int, pos: Sequence[float], vel: Sequence[float]
    ) -> None: ...
    def sim_state(
        self, stamp_us: int, floats: Sequence[float], lat_int: int, lon_int: int
    ) -> None: ...
