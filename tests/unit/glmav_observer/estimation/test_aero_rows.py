"""The drag model's compiled rows against the Python floats they replaced (an oracle here)."""

from __future__ import annotations

import math
import random
from operator import mul

import pytest

from glmav_observer.estimation.aero.rows import RowFits


def _oracle_step(  # noqa: PLR0917 -- the state and one sample, in order
    th: list[list[float]],
    P: list[list[list[float]]],
    sums: list[list[float]],
    f: list[float],
    e_flat: list[float],
    v: list[float],
    rho: tuple[float, float] | None,
    sig_f: list[float],
    lam: float,
) -> bool:
    """DragModel.learn's arithmetic as it was in Python (in place); the outlier flag."""
    outlier = False
    terms = []
    for j in range(2):
        rn, re, rd = e_flat[j], e_flat[3 + j], e_flat[6 + j]
        sj = rn * v[0] + re * v[1] + rd * v[2]
        phi = [1.0, -sj, rn, re, -sj * abs(sj)]
        if rho is None:
            p_phi = [Pa[0] * phi[0] + Pa[1] * phi[1] + Pa[2] * phi[2] + Pa[3] * phi[3]
                     + Pa[4] * phi[4] for Pa in P[j]]  # fmt: skip
            t = th[j]
            e = f[j] - (t[0] + t[1] * phi[1] + t[2] * rn + t[3] * re + t[4] * phi[4])
            ppp = (phi[0] * p_phi[0] + phi[1] * p_phi[1] + phi[2] * p_phi[2]
                   + phi[3] * p_phi[3] + phi[4] * p_phi[4])  # fmt: skip
        else:
            phi.append(rho[j])
            p_phi = [sum(map(mul, Pa, phi)) for Pa in P[j]]
            e = f[j] - sum(map(mul, th[j], phi))
            ppp = sum(map(mul, phi, p_phi))
        var_f = sig_f[j] ** 2
        outlier = outlier or e * e > 25.0 * (var_f + ppp)
        terms.append((sj, p_phi, e, ppp, var_f))
    inv_l = 1.0 / lam
    for j, (sj, p_phi, e, ppp, var_f) in enumerate(terms):
        sums[0][j] = lam * sums[0][j] + e * e * var_f / (var_f + ppp)
        sums[1][j] = lam * sums[1][j] + sj
        sums[2][j] = lam * sums[2][j] + sj * sj
        denom = var_f + ppp * inv_l
        ge = inv_l / denom * e
        th[j] = [t + ge * pa for t, pa in zip(th[j], p_phi, strict=True)]
        c = inv_l * inv_l / denom
        P[j] = [[pr * inv_l - c * p_phi[a] * pk for pr, pk in zip(P[j][a], p_phi, strict=True)]
                for a in range(len(p_phi))]  # fmt: skip
    return outlier


@pytest.mark.parametrize("n_param", [5, 6])
def test_rows_are_the_python_floats_bit_for_bit(n_param: int) -> None:
    rng = random.Random(n_param)
    th = [[rng.gauss(0.0, 0.3) for _ in range(n_param)] for _ in range(2)]
    P = [[[(1.0 if a == b else 0.01) * rng.uniform(0.5, 2.0) for b in range(n_param)]
          for a in range(n_param)] for _ in range(2)]  # fmt: skip
    rows = RowFits(n_param, th, P)
    sums = [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
    for _ in range(300):
        phi_, theta_, psi = (rng.uniform(-0.5, 0.5) for _ in range(3))
        # a rotation's entries (any 9 floats in [-1, 1] do for the arithmetic)
        e_flat = [math.cos(phi_ + k * theta_ + psi) for k in range(9)]
        v = [rng.gauss(0.0, 5.0) for _ in range(3)]
        f = [rng.gauss(0.0, 2.0) for _ in range(3)]
        rho = (rng.uniform(-1, 1), rng.uniform(-1, 1)) if n_param == 6 else None
        sig_f = [rng.uniform(0.02, 0.5), rng.uniform(0.02, 0.5)]
        lam = math.exp(-rng.uniform(0.01, 0.1) / 90.0)
        got_outlier = rows.terms(f, e_flat, v, rho, sig_f, True, True, 25.0)
        rows.commit(lam)
        want_outlier = _oracle_step(th, P, sums, f, e_flat, v, rho, sig_f, lam)
        assert got_outlier == want_outlier
    # the same operations in the same order: the same doubles after 300 updates
    assert rows.theta() == th
    assert rows.cov() == P
    assert [rows.res_sum, rows.s_sum, rows.s2_sum] == sums


def test_rows_refuse_other_sizes() -> None:
    with pytest.raises(ValueError, match="5 or 6"):
        RowFits(4, [[0.0] * 4] * 2, [[[0.0] * 4] * 4] * 2)


@pytest.mark.parametrize("n_param", [5, 6])
def test_quad_form_is_the_python_nested_sum(n_param: int) -> None:
    rng = random.Random(10 + n_param)
    for _ in range(200):
        P = [[[rng.gauss(0.0, 1.0) for _ in range(n_param)] for _ in range(n_param)]
             for _ in range(2)]  # fmt: skip
        rows = RowFits(n_param, [[0.0] * n_param] * 2, P)
        phi = tuple(rng.gauss(0.0, 3.0) for _ in range(n_param))
        for j in range(2):
            want = sum(
                phi[a] * sum(P[j][a][b] * phi[b] for b in range(n_param)) for a in range(n_param)
            )
            assert rows.quad_form(j, phi) == want  # the same doubles
    with pytest.raises(ValueError, match="regressors"):
        rows.quad_form(0, phi[:-1])
