"""The frames module: the scalar and numpy forms of E, Eᵀ and the quaternion agree.

Both forms compute the same products of sines and cosines in a different order; each entry
is a sum of at most three products of factors of magnitude ≤ 1 (times |v| ≤ 30 for a
rotated vector), so they differ by a few ulp of 30 (≈ 1e-14 at most); 1e-12 leaves margin
and still catches any wrong sign or index (an error of order 1e-2 or more).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from glmav_observer.frames import (
    ShapeError,
    e_exact,
    e_flat,
    euler_from_quaternion_wxyz,
    quaternion_xyzw,
    quaternion_xyzw_array,
    rotate,
    rotate_flat,
    rotate_t,
    rotate_t_flat,
)

RNG = np.random.default_rng(15)
#: roll and yaw over the whole circle, pitch short of the poles (ZYX is singular there)
EULERS = RNG.uniform([-math.pi, -1.5, -math.pi], [math.pi, 1.5, math.pi], size=(500, 3))
VECTORS = RNG.uniform(-30.0, 30.0, size=(500, 3))


def test_scalar_e_equals_numpy_e() -> None:
    E_np = e_exact(EULERS)  # (500, 3, 3), one call over the batch
    for eul, E in zip(EULERS.tolist(), E_np, strict=True):
        np.testing.assert_allclose(np.reshape(e_flat(*eul), (3, 3)), E, rtol=0, atol=1e-12)


def test_e_is_the_zyx_body_to_ned_rotation() -> None:
    # yaw 90°: the body's forward axis points east; pitch up 90°: forward points up (−d);
    # roll 90°: the right wing points down
    for eul, body, ned in (
        ((0.0, 0.0, math.pi / 2), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        ((0.0, math.pi / 2, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),
        ((math.pi / 2, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    ):
        np.testing.assert_allclose(rotate_flat(e_flat(*eul), body), ned, atol=1e-15)
        np.testing.assert_allclose(e_exact(eul) @ body, ned, atol=1e-15)


def test_rotations_scalar_numpy_and_matmul_agree() -> None:
    E_np = e_exact(EULERS)
    ev_np = rotate(E_np, VECTORS)
    etv_np = rotate_t(E_np, VECTORS)
    np.testing.assert_allclose(ev_np, np.einsum("kij,kj->ki", E_np, VECTORS), atol=1e-12)
    np.testing.assert_allclose(etv_np, np.einsum("kji,kj->ki", E_np, VECTORS), atol=1e-12)
    for k, (eul, v) in enumerate(zip(EULERS.tolist(), VECTORS.tolist(), strict=True)):
        E = e_flat(*eul)
        np.testing.assert_allclose(rotate_flat(E, v), ev_np[k], rtol=0, atol=1e-12)
        np.testing.assert_allclose(rotate_t_flat(E, v), etv_np[k], rtol=0, atol=1e-12)
        # Eᵀ undoes E (orthogonal): round trip to a few ulp of |v| ≤ 52
        np.testing.assert_allclose(rotate_t_flat(E, rotate_flat(E, v)), v, rtol=0, atol=1e-12)


def test_quaternion_scalar_numpy_and_matrix_agree() -> None:
    q_np = quaternion_xyzw_array(EULERS)
    E_np = e_exact(EULERS)
    for eul, q_row, E in zip(EULERS.tolist(), q_np, E_np, strict=True):
        x, y, z, w = q = quaternion_xyzw(eul)
        np.testing.assert_allclose(q, q_row, rtol=0, atol=1e-12)
        assert x * x + y * y + z * z + w * w == pytest.approx(1.0, abs=1e-14)
        R = [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
        np.testing.assert_allclose(R, E, rtol=0, atol=1e-12)  # the same rotation as E


def test_euler_from_quaternion_inverts_the_quaternion() -> None:
    q_xyzw = quaternion_xyzw_array(EULERS)
    q_wxyz = np.roll(q_xyzw, 1, axis=-1)
    # a non-unit quaternion is normalised first
    back = euler_from_quaternion_wxyz(3.0 * q_wxyz)
    # pitch ≤ 1.5 rad: arcsin's conditioning 1/cos θ ≤ 15 keeps the error ≈ 1e-14
    np.testing.assert_allclose(back, EULERS, rtol=0, atol=1e-12)


def test_bad_shapes_are_named() -> None:
    with pytest.raises(ShapeError, match="euler_rad"):
        e_exact(np.zeros(4))
    with pytest.raises(ShapeError, match="q_wxyz"):
        euler_from_quaternion_wxyz(np.zeros((2, 3)))
