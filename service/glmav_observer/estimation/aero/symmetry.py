"""The drag of a symmetric airframe: one (k, q) for both body rows (issue 32).

A multicopter whose rotors sit symmetrically about its z axis (quad, hexa, octa) has the
same drag along body x and body y: ArduPilot's frame model (``SIM_Frame.cpp``) applies one
momentum-drag coefficient and one ``areaCd`` to both, so in hover k_x = k_y = 0.242 1/s
and q_x = q_y = 0.034 1/m. The drag model (:mod:`.model`, (A1)) fits each body row on its
own, and a row whose body speed barely varied (a hover, or a flight along the other body
axis) cannot identify its own k: its data fix only the intercept at the speed it held,
a_j − k_j s̄_j, along a ridge of (intercept, k) that the data do not resolve.

With the symmetry (a user's statement about the vehicle: ``DragModelConfig.symmetric_xy``)
the other row's posterior on (k, q) is a measurement of this row's (k, q). Each row's
Gaussian posterior N(θ_j, P_j) is updated with the other's marginal N(m_o, M_o) on the
shared indices S = (k, q), as a Kalman update with an exact observation of θ_j[S] whose
noise is the other row's uncertainty (the rows' posteriors are independent: each is fitted
on its own specific force, from independent priors):

    H = P_j[S,S] + M_o,   G = P_j[:,S] H⁻¹,
    θ_j' = θ_j + G (m_o − θ_j[S]),   P_j' = P_j − G P_j[S,:]                     (S1)

so the row ends with the precision-weighted mean of the two (k, q) and every other
parameter of the row (its intercept, its k·w) moves along the ridge its own data left
open: a hovering row's pseudo-measurement becomes s_j = s̄_j + (f̄_j − f_j)/k.

The model (:meth:`.model.DragModel._use_lists`) applies (S1) only to a row whose own speed
did not vary (it fails the spread test) and only when the other row's did: a row whose
data identify its k keeps its own fit, so the symmetry, a statement the user makes, is
used only where the row's own data are silent. (Measured on the ArduPilot tuning flights,
updating both rows instead changed the already-aided losses of h_quad_gps_glitch: 60 s
RMS of the 60 losses summed 11.126 against 11.113 m/s, worst excess over dead reckoning
0.0154 against 0.0105 m/s.)

The data can refuse the symmetry: the two rows' (k, q) must agree,

    χ² = dᵀ (P_x[S,S] + P_y[S,S])⁻¹ d ≤ ``symmetric_gate_chi2``,   d = θ_x[S] − θ_y[S]   (S2)

(a 2-degree-of-freedom χ²: 11.8 is its 99.73 % point, the 3σ of one dimension). A row
whose own k is unidentified has a large P_j[S,S] and passes (S2) whatever its k; a row
whose low-spread data still carry information on its k (jitter against a clean
accelerometer) must agree with the other row's, or keeps its own fit (another airframe,
a payload hung off-centre).

After (S1) the two rows share the coefficients' error: their pseudo-measurements' model
parts are correlated, which :meth:`.model.DragModel.pseudo_measurement` takes as fully
correlated (an upper bound) when it combines the two rows.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def shared_drag_chi2(theta_rows: FloatArray, cov_rows: FloatArray, idx: tuple[int, ...]) -> float:
    """(S2): χ² of the difference of the two rows' coefficients ``idx`` (θ (2, n), P (2, n,
    n) per body row x, y)."""
    s = list(idx)
    d = theta_rows[0, s] - theta_rows[1, s]
    h = cov_rows[0][np.ix_(s, s)] + cov_rows[1][np.ix_(s, s)]
    return float(d @ np.linalg.solve(h, d))


def share_drag(
    theta_rows: FloatArray,
    cov_rows: FloatArray,
    idx: tuple[int, ...],
    rows: tuple[int, ...] = (0, 1),
) -> tuple[FloatArray, FloatArray]:
    """(S1): θ (2, n) and P (2, n, n) per body row (x, y), each row of ``rows`` updated with
    the other row's marginal on the coefficients ``idx`` (k and q: the same on both rows
    of a symmetric airframe; the model passes only the row that borrows). The inputs are
    not modified."""
    s = list(idx)
    theta_out = np.array(theta_rows, dtype=np.float64)
    cov_out = np.array(cov_rows, dtype=np.float64)
    for j in rows:
        o = 1 - j
        p_j = cov_rows[j]
        h = p_j[np.ix_(s, s)] + cov_rows[o][np.ix_(s, s)]
        g = np.linalg.solve(h, p_j[s, :]).T  # P_j[:,S] H⁻¹ (H and P_j symmetric)
        theta_out[j] = theta_rows[j] + g @ (theta_rows[o, s] - theta_rows[j, s])
        p_new = p_j - g @ p_j[s, :]
        cov_out[j] = 0.5 * (p_new + p_new.T)
    return theta_out, cov_out
