"""Rotations between body FRD and earth NED, ZYX Euler angles and unit quaternions.

Quaternions are ``(w, x, y, z)``, Hamilton convention, rotating body vectors into
earth axes: ``v_ned = R(q) v_body``. ``R`` equals the paper's E(phi, theta, psi) of
eq. (13) for the same ZYX angles. Plain floats (math module) for speed in the
integrator; numpy helpers are for tests and offline use.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

Quat = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]


def quat_from_euler(phi_rad: float, theta_rad: float, psi_rad: float) -> Quat:
    """Unit quaternion of the ZYX rotation (yaw psi, then pitch theta, then roll phi)."""
    cr, sr = math.cos(phi_rad / 2), math.sin(phi_rad / 2)
    cp, sp = math.cos(theta_rad / 2), math.sin(theta_rad / 2)
    cy, sy = math.cos(psi_rad / 2), math.sin(psi_rad / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(qw: float, qx: float, qy: float, qz: float) -> Vec3:
    """ZYX Euler angles (phi, theta, psi) in rad of a unit quaternion; psi in (-pi, pi]."""
    phi = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    s = 2.0 * (qw * qy - qz * qx)
    theta = math.asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s))
    psi = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return (phi, theta, psi)


def rotation_from_quat(qw: float, qx: float, qy: float, qz: float) -> NDArray[np.float64]:
    """3x3 body-to-earth rotation matrix R(q) (numpy; equals E of eq. (13))."""
    return np.array(
        [
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)],
            [2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)],
            [2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)],
        ]
    )


def euler_matrix(phi: float, theta: float, psi: float) -> NDArray[np.float64]:
    """The paper's E(phi, theta, psi), eq. (13), body to earth."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
            [-st, sf * ct, cf * ct],
        ]
    )


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product a * b."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q: Quat) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def rotate_body_to_ned(q: Quat, v: Vec3) -> Vec3:
    """R(q) v for a body vector v."""
    qw, qx, qy, qz = q
    x, y, z = v
    return (
        (1 - 2 * (qy * qy + qz * qz)) * x
        + 2 * (qx * qy - qw * qz) * y
        + 2 * (qx * qz + qw * qy) * z,
        2 * (qx * qy + qw * qz) * x
        + (1 - 2 * (qx * qx + qz * qz)) * y
        + 2 * (qy * qz - qw * qx) * z,
        2 * (qx * qz - qw * qy) * x
        + 2 * (qy * qz + qw * qx) * y
        + (1 - 2 * (qx * qx + qy * qy)) * z,
    )


def rotate_ned_to_body(q: Quat, v: Vec3) -> Vec3:
    """R(q)^T v for an earth vector v."""
    qw, qx, qy, qz = q
    x, y, z = v
    return (
        (1 - 2 * (qy * qy + qz * qz)) * x
        + 2 * (qx * qy + qw * qz) * y
        + 2 * (qx * qz - qw * qy) * z,
        2 * (qx * qy - qw * qz) * x
        + (1 - 2 * (qx * qx + qz * qz)) * y
        + 2 * (qy * qz + qw * qx) * z,
        2 * (qx * qz + qw * qy) * x
        + 2 * (qy * qz - qw * qx) * y
        + (1 - 2 * (qx * qx + qy * qy)) * z,
    )
