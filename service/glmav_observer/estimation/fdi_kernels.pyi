from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

def residual_ratios(
    resid: Iterable[float],
    d2y_sq: Iterable[float],
    bias_samples: int,
    noise_samples: int,
    bias_threshold_mps: float,
    sigma_r_mps: float,
    var_d2y_mps2: float,
    noise_ratio_threshold: float,
    chi2_1_median: float,
) -> tuple[float, float]: ...
def predict(
    theta: tuple[float, ...],
    cov: NDArray[np.float64],
    b_anchor: tuple[float, ...],
    c_anchor: tuple[float, float, float],
    axis: int,
    a_int_j: float,
    ints: tuple[tuple[float, ...], tuple[float, float, float], tuple[float, float, float]],
    lagged: bool,
) -> tuple[float, float]: ...
def fill_rows(
    out: NDArray[np.float64], rows: Iterable[tuple[Any, ...]], correlation_samples: float
) -> None: ...
def normal_equations(
    arr: NDArray[np.float64],
    anchor: NDArray[np.float64],
    info: NDArray[np.float64],
    rhs: NDArray[np.float64],
) -> None: ...
def spd_inverse(a: NDArray[np.float64], out: NDArray[np.float64]) -> bool: ...
