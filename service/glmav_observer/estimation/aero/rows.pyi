from collections.abc import Sequence

class RowFits:
    n_param: int
    def __init__(
        self,
        n_param: int,
        theta: Sequence[Sequence[float]],
        cov: Sequence[Sequence[Sequence[float]]],
    ) -> None: ...
    def set(
        self, theta: Sequence[Sequence[float]], cov: Sequence[Sequence[Sequence[float]]]
    ) -> None: ...
    def theta(self) -> list[list[float]]: ...
    def cov(self) -> list[list[list[float]]]: ...
    @property
    def res_sum(self) -> list[float]: ...
    @property
    def s_sum(self) -> list[float]: ...
    @property
    def s2_sum(self) -> list[float]: ...
    def terms(
        self,
        f_body_mps2: Sequence[float],
        e_flat: Sequence[float],
        v_ned_mps: Sequence[float],
        rho: Sequence[float] | None,
        sig_f: Sequence[float],
        quadratic: bool,
        trusted: bool,
        outlier_sigma_sq: float,
    ) -> bool: ...
    def quad_form(self, j: int, phi: Sequence[float]) -> float: ...
    def commit(self, lam: float) -> None: ...
