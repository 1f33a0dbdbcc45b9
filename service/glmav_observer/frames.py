"""Frames: the body-to-earth rotation E and its quaternion, in one place.

Conventions (the whole service): earth frame NED, body frame FRD, ZYX Euler angles
``euler_rad = (roll φ, pitch θ, yaw ψ)``. ``E`` (the paper's (13)) maps body vectors to
earth vectors, ``v_ned = E v_body``; it is orthogonal, so ``v_body = Eᵀ v_ned``. The unit
quaternion of the same rotation is given in Rerun's order (x, y, z, w); PX4's logs give it
as (w, x, y, z) (:func:`euler_from_quaternion_wxyz`).

Two forms of each, tested against each other to 1e-12 (tests/unit/glmav_observer/test_frames.py):

- scalar (plain floats, the per-sample fast path: numpy's per-call overhead dominates for
  one 3×3 matrix; compiled in :mod:`glmav_observer.rotation`, re-exported here):
  :func:`e_flat` gives E as a flat row-major list of nine floats,
  :func:`rotate_flat` / :func:`rotate_t_flat` give E v / Eᵀ v, :func:`quaternion_xyzw`;
- numpy, broadcasting over leading batch dimensions ``...``: :func:`e_exact` (..., 3, 3),
  :func:`rotate` / :func:`rotate_t`, :func:`quaternion_xyzw_array` (..., 4),
  :func:`euler_from_quaternion_wxyz`.

The two forms keep their own operation order (the scalar E multiplies sinφ sinθ first, the
numpy E sinθ cosψ first): each is bit-for-bit what its callers computed before they shared
it, so the replay output did not change; they differ by a few ulp.

The simulator (``sim_bridge/glmav_sitl/dynamics/frames.py``) has its own quaternion
kinematics: it is a separate package that does not import the service.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

# the scalar forms are compiled (rotation.pyx, cimported by the per-sample core)
from glmav_observer.rotation import e_flat as e_flat  # noqa: PLC0414
from glmav_observer.rotation import rotate_flat as rotate_flat  # noqa: PLC0414
from glmav_observer.rotation import rotate_t_flat as rotate_t_flat  # noqa: PLC0414

FloatArray = NDArray[np.float64]

#: Standard gravity used by the project (design.md, vehicle parameters), m/s²: the g of
#: V̇ = E f + g e_d, for the estimator and for whatever integrates the IMU the same way.
G_MPS2 = 9.81


class ShapeError(ValueError):
    """An input whose shape does not fit (wrong trailing dimensions or batch shape)."""


def as_vectors(name: str, value: ArrayLike, trailing: tuple[int, ...]) -> FloatArray:
    """``value`` as float64 with the given trailing shape, else :class:`ShapeError`."""
    arr = np.asarray(value, dtype=np.float64)
    n = len(trailing)
    if arr.ndim < n or arr.shape[arr.ndim - n :] != trailing:
        raise ShapeError(
            f"{name}: expected shape (..., {', '.join(map(str, trailing))}), got {arr.shape}"
        )
    return arr


# --------------------------------------------------------------------------- scalar forms


def quaternion_xyzw(euler_rad: Sequence[float]) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of E (13), ZYX: q = q_z(ψ) q_y(θ) q_x(φ)."""
    phi, theta, psi = (0.5 * a for a in euler_rad)
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return (
        sf * ct * cp - cf * st * sp,
        cf * st * cp + sf * ct * sp,
        cf * ct * sp - sf * st * cp,
        cf * ct * cp + sf * st * sp,
    )


# --------------------------------------------------------------------------- numpy forms


def e_exact(euler_rad: ArrayLike) -> FloatArray:
    """Body(FRD)-to-earth(NED) rotation matrix (13), ZYX Euler angles, shape (..., 3, 3)."""
    eul = as_vectors("euler_rad", euler_rad, (3,))
    s = np.sin(eul)
    c = np.cos(eul)
    sphi, sth, spsi = s[..., 0], s[..., 1], s[..., 2]
    cphi, cth, cpsi = c[..., 0], c[..., 1], c[..., 2]
    sth_cpsi = sth * cpsi
    sth_spsi = sth * spsi
    E = np.empty((*eul.shape[:-1], 3, 3))
    # (13), row by row
    E[..., 0, 0] = cth * cpsi
    E[..., 0, 1] = sphi * sth_cpsi - cphi * spsi
    E[..., 0, 2] = cphi * sth_cpsi + sphi * spsi
    E[..., 1, 0] = cth * spsi
    E[..., 1, 1] = sphi * sth_spsi + cphi * cpsi
    E[..., 1, 2] = cphi * sth_spsi - sphi * cpsi
    E[..., 2, 0] = -sth
    E[..., 2, 1] = sphi * cth
    E[..., 2, 2] = cphi * cth
    return E


def rotate(M: FloatArray, v: FloatArray) -> FloatArray:
    """M v for 3×3 M (..., 3, 3) and v (..., 3), broadcast; three fused terms (faster than
    np.matmul's per-matrix loop for many tiny matrices)."""
    return v[..., 0:1] * M[..., :, 0] + v[..., 1:2] * M[..., :, 1] + v[..., 2:3] * M[..., :, 2]


def rotate_t(M: FloatArray, v: FloatArray) -> FloatArray:
    """Mᵀ v for 3×3 M (..., 3, 3) and v (..., 3), broadcast."""
    return v[..., 0:1] * M[..., 0, :] + v[..., 1:2] * M[..., 1, :] + v[..., 2:3] * M[..., 2, :]


def quaternion_xyzw_array(euler_rad: ArrayLike) -> FloatArray:
    """:func:`quaternion_xyzw` over (..., 3) Euler angles: (..., 4), (x, y, z, w)."""
    half = 0.5 * as_vectors("euler_rad", euler_rad, (3,))
    s = np.sin(half)
    c = np.cos(half)
    sf, st, sp = s[..., 0], s[..., 1], s[..., 2]
    cf, ct, cp = c[..., 0], c[..., 1], c[..., 2]
    return np.stack(
        (
            sf * ct * cp - cf * st * sp,
            cf * st * cp + sf * ct * sp,
            cf * ct * sp - sf * st * cp,
            cf * ct * cp + sf * st * sp,
        ),
        axis=-1,
    )


def euler_from_quaternion_wxyz(q_wxyz: ArrayLike) -> FloatArray:
    """ZYX Euler angles (roll, pitch, yaw) of body-to-NED quaternions (w, x, y, z), (N, 3).

    PX4 logs attitude as a quaternion (w, x, y, z), rotating FRD body to NED; the
    estimator takes Euler angles as MAVLink ``ATTITUDE`` does. Normalised first; pitch is
    clipped to ±π/2 (round-off past the pole).
    """
    q_ = as_vectors("q_wxyz", q_wxyz, (4,))
    q = q_ / np.linalg.norm(q_, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)
