"""Type stub of the compiled controller.pyx."""

from collections.abc import Sequence

from glmav_sitl.params import VehicleParams
from glmav_sitl.scenario import ControllerGains, Setpoint

class Controller:
    """``update(t_s, x) -> u`` at the control rate."""

    p: VehicleParams
    setpoints: list[Setpoint]
    dt: float
    last_attitude_sp_rad: tuple[float, float, float]
    k: ControllerGains
    def __init__(
        self,
        p: VehicleParams,
        gains: ControllerGains,
        setpoints: Sequence[Setpoint],
        control_dt_s: float,
    ) -> None: ...
    def command(self, sp: Setpoint, t_s: float, x: Sequence[float]) -> None: ...
    def update(self, t_s: float, x: Sequence[float]) -> list[float]: ...
