"""The compiled FDI kernels against the Python they replaced (written out here as oracles)."""

from __future__ import annotations

import math
import random
import statistics
from collections import deque
from itertools import pairwise
from operator import mul

import numpy as np
import pytest

from glmav_observer.estimation.fdi_axis import CHI2_1_MEDIAN
from glmav_observer.estimation.fdi_kernels import (
    fill_rows,
    normal_equations,
    predict,
    residual_ratios,
    spd_inverse,
)


def _ratios_oracle(  # noqa: PLR0917 -- the kernel's own arguments, in order
    resid: list[float], d2y: list[float], nb: int, nn: int, thr: float, s_r: float, v2: float
) -> tuple[float, float]:
    """AxisMonitor._ratios as it was in Python (statistics.median on lists)."""
    rb = resid[-nb:]
    bias = abs(statistics.median(rb)) / thr if len(rb) == nb else math.nan
    rn = resid[-(nn + 1) :]
    noise = math.nan
    if len(rn) == nn + 1:
        d2 = [(b - a) ** 2 for a, b in pairwise(rn)]
        noise = statistics.median(d2) / (2.0 * s_r**2 * CHI2_1_MEDIAN) / 12.0
        if len(d2y) >= nn:
            own = statistics.median(d2y[-nn:]) / (v2 * CHI2_1_MEDIAN) / 12.0
            if math.isfinite(own):
                noise = min(noise, own)
    return bias, noise


def test_residual_ratios_are_the_python_medians_bit_for_bit() -> None:
    rng = random.Random(7)
    for _ in range(3000):
        n_r = rng.randint(0, 13)
        n_y = rng.randint(0, 40)
        scale = 10.0 ** rng.uniform(-3, 1)
        resid = deque((rng.gauss(0.0, scale) for _ in range(n_r)), maxlen=13)
        d2y = deque((rng.expovariate(1.0 / scale) for _ in range(n_y)), maxlen=40)
        if rng.random() < 0.2 and resid:  # repeated values: ties in the sort
            resid[-1] = resid[0]
        nb, nn = rng.choice([(6, 12), (5, 7), (4, 4)])
        thr, s_r, v2 = rng.uniform(0.1, 1.0), rng.uniform(0.01, 0.2), rng.uniform(1e-4, 1e-1)
        got = residual_ratios(resid, d2y, nb, nn, thr, s_r, v2, 12.0, CHI2_1_MEDIAN)
        want = _ratios_oracle(list(resid), list(d2y), nb, nn, thr, s_r, v2)
        # the same doubles (NaN where too few): the same operations in the same order
        for g, w in zip(got, want, strict=True):
            assert (math.isnan(g) and math.isnan(w)) or g == w


def test_residual_ratios_refuse_a_window_beyond_their_buffer() -> None:
    with pytest.raises(ValueError, match="exceeds"):
        residual_ratios([0.1] * 300, [], 300, 12, 0.15, 0.05, 0.01, 12.0, CHI2_1_MEDIAN)


def test_predict_mean_is_the_python_sum_and_sigma_the_quadratic_form() -> None:
    rng = np.random.default_rng(3)
    for _ in range(500):
        a = rng.normal(size=(8, 8))
        cov = a @ a.T * 10.0 ** rng.uniform(-6, 0)
        theta = tuple(rng.normal(size=8).tolist())
        b_anchor = tuple(rng.normal(size=9).tolist())
        c_anchor = (*rng.normal(size=3).tolist(),)
        ints = (
            tuple(rng.normal(size=9).tolist()),
            (*rng.normal(size=3).tolist(),),
            (*rng.normal(size=3).tolist(),),
        )
        axis = int(rng.integers(0, 3))
        lagged = bool(rng.integers(0, 2))
        a_int = float(rng.normal())
        k = 3 * axis
        x = [0.0] * 8
        x[axis] = 1.0
        x[3:6] = [-(ints[0][k + i] - b_anchor[k + i]) for i in range(3)]
        x[6] = ints[1][axis] - c_anchor[axis]
        x[7] = -ints[2][axis] if lagged else 0.0
        mean, sigma = predict(theta, cov, b_anchor, c_anchor, axis, a_int, ints, lagged)
        # the mean: the same sum in the same order as before (bit for bit)
        assert mean == a_int + sum(map(mul, x, theta))
        # σ: x P x summed in another order than numpy's BLAS (FMA): rel 1e-13 is ~450
        # ulps, room for the cancellation inside 8-term sums, and far below 1e-9 m/s
        xv = np.asarray(x)
        assert sigma == pytest.approx(math.sqrt(float(xv @ cov @ xv)), rel=1e-13)


def test_predict_refuses_wrong_shapes() -> None:
    ints = ((0.0,) * 9, (0.0,) * 3, (0.0,) * 3)
    with pytest.raises(ValueError, match="8"):
        predict((0.0,) * 7, np.eye(8), (0.0,) * 9, (0.0,) * 3, 0, 0.0, ints, True)
    with pytest.raises(ValueError, match="axis"):
        predict((0.0,) * 8, np.eye(8), (0.0,) * 9, (0.0,) * 3, 3, 0.0, ints, True)


def test_fill_rows_are_the_python_row_values_bit_for_bit() -> None:
    """Each row as ReferenceFit's Python code built it: j, z, 1/σ²/corr (σ² as Python's
    ``** 2``, libm's pow, which differs from σ·σ in ~1 of 1200 values), V0's indicator,
    −B_j, C_j, −L_j."""
    rng = random.Random(11)
    rows: deque[tuple[float, int, float, tuple[float, ...], tuple[float, ...], float,
                      tuple[float, ...]]] = deque()  # fmt: skip
    for _ in range(5000):
        b = tuple(rng.gauss(0.0, 3.0) for _ in range(9))
        c = tuple(rng.gauss(0.0, 1.0) for _ in range(3))
        lag = tuple(rng.gauss(0.0, 2.0) for _ in range(3))
        rows.append((rng.random(), rng.randint(0, 2), rng.gauss(0.0, 1.0), b, c,
                     rng.uniform(0.001, 1.0), lag))  # fmt: skip
    out = np.empty((4000, 11))
    fill_rows(out, rows, 3.0)
    got = out.tolist()
    for row, values in zip(list(rows)[1000:], got, strict=True):
        _, j, z, b, c, sigma, lag = row
        k = 3 * j
        want = [j, z, 1.0 / sigma**2 / 3.0, float(j == 0), float(j == 1), float(j == 2),
                -b[k], -b[k + 1], -b[k + 2], c[j], -lag[j]]  # fmt: skip
        assert values == want  # the same doubles


def test_fill_rows_refuses_more_rows_than_held() -> None:
    with pytest.raises(ValueError, match="11"):
        fill_rows(np.empty((3, 11)), deque([(0.0, 0, 0.0, (0.0,) * 9, (0.0,) * 3, 1.0,
                                             (0.0,) * 3)]), 1.0)  # fmt: skip


@pytest.mark.parametrize("n", [1, 17, 600])
def test_normal_equations_are_numpys_xtwx_and_xtwz(n: int) -> None:
    """The oracle: ReferenceFit._fit's numpy before the kernel, X = the rows' regressors
    less the anchor of each row's axis, XᵀWX = (Xᵀ * w) @ X and XᵀWz = (Xᵀ * w) @ z."""
    rng = np.random.default_rng(n)
    arr = np.empty((n, 11))
    arr[:, 0] = rng.integers(0, 3, n)
    arr[:, 1] = rng.normal(0.0, 3.0, n)
    arr[:, 2] = rng.uniform(10.0, 400.0, n)
    arr[:, 3:] = rng.normal(0.0, 50.0, (n, 8))
    anchor = rng.normal(0.0, 50.0, (3, 8))
    x = arr[:, 3:] - anchor.take(arr[:, 0].astype(np.intp), axis=0)
    xtw = x.T * arr[:, 2]
    info, rhs = np.empty((8, 8)), np.empty(8)
    normal_equations(arr, anchor, info, rhs)
    # sums of n products of numbers ~1e2·1e2·4e2: the order of summation differs from
    # BLAS's, so a few ulps of the largest term (1e-16 relative × n terms)
    scale = float(np.abs(xtw).max() * np.abs(x).max()) * n * 1e-15
    np.testing.assert_allclose(info, xtw @ x, rtol=0.0, atol=scale)
    np.testing.assert_allclose(rhs, xtw @ arr[:, 1], rtol=0.0, atol=scale)
    assert (info == info.T).all()


def test_normal_equations_refuse_a_bad_axis_or_shape() -> None:
    arr = np.zeros((2, 11))
    arr[1, 0] = 3.0
    with pytest.raises(ValueError, match="axis is 0-2"):
        normal_equations(arr, np.zeros((3, 8)), np.empty((8, 8)), np.empty(8))
    with pytest.raises(ValueError, match="rows of 11"):
        normal_equations(np.zeros((2, 10)), np.zeros((3, 8)), np.empty((8, 8)), np.empty(8))


@pytest.mark.parametrize("seed", range(5))
def test_spd_inverse_is_numpys_inverse_on_the_fits_matrices(seed: int) -> None:
    """The fit's information matrices: XᵀWX of rows like the fit's plus the priors'
    diagonal (1e-4 to 1e12, the held parameters' 1e12 included)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 30.0, (300, 8))
    prior = np.array([1e-4] * 3 + [11.1] * 3 + [100.0, 1e12 if seed % 2 else 100.0])
    info = (x.T * rng.uniform(10.0, 400.0, 300)) @ x + np.diag(prior)
    out = np.empty((8, 8))
    assert spd_inverse(info, out)
    ref = np.linalg.inv(info)
    # both are backward stable: their difference is bounded by cond(info) × ε of the
    # inverse's scale (cond up to ~1e16 here with the 1e12 prior)
    np.testing.assert_allclose(out @ info, np.eye(8), atol=1e-6)
    np.testing.assert_allclose(out, ref, rtol=1e-6, atol=1e-12 * float(np.abs(ref).max()))
    assert (out == out.T).all()


def test_spd_inverse_declines_a_matrix_that_is_not_positive_definite() -> None:
    out = np.empty((2, 2))
    assert not spd_inverse(np.array([[1.0, 2.0], [2.0, 1.0]]), out)
    assert not spd_inverse(np.array([[0.0, 0.0], [0.0, 1.0]]), out)
    assert not spd_inverse(np.array([[np.nan, 0.0], [0.0, 1.0]]), out)
