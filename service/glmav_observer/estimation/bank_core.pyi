from collections.abc import Sequence

from glmav_observer.estimation.inputs import HeldInputs

class BankCore:
    g_mps2: float
    rotate_y: bool
    imu_lead_s: float
    def __init__(
        self,
        gammas: Sequence[float],
        g_mps2: float,
        config_lost: Sequence[int] = ...,
        rotate_y: bool = ...,
        imu_lead_s: float = ...,
    ) -> None: ...
    def centre_imu(self, inputs: HeldInputs, f_new: Sequence[float], dt_imu_s: float) -> None: ...
    def lost(self) -> list[int]: ...
    def advance(
        self,
        t: float,
        dt: float,
        inputs: HeldInputs,
        bias_body_mps2: Sequence[float],
        propagate: bool,
        b_obs: Sequence[float] | None,
        use: Sequence[bool],
    ) -> bool: ...
    def set_gammas(self, gammas: Sequence[float]) -> None: ...
    def rows(self) -> list[list[float]]: ...
    def set_row(self, i: int, v: Sequence[float]) -> None: ...
    def set_rows(self, rows: Sequence[Sequence[float]]) -> None: ...
    def ned_rows(self) -> list[tuple[float, float, float]]: ...
    def e_list(self) -> list[float]: ...
    def set_e_list(self, e_flat: Sequence[float]) -> None: ...
    def set_attitude(self, phi_rad: float, theta_rad: float, psi_rad: float) -> None: ...
    def step(
        self,
        h: float,
        eul: Sequence[float],
        w: Sequence[float],
        f: Sequence[float],
        y: Sequence[float],
        lost: Sequence[int],
        y_rate: Sequence[float] | None = ...,
    ) -> None: ...
