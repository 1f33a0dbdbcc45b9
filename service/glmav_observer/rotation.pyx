"""E (13) as nine plain floats, and E v / Eᵀ v: the per-sample rotation, compiled.

``E`` flat row-major: ``E[3 i + j]`` is row i, column j; ZYX Euler angles
``(roll φ, pitch θ, yaw ψ)``, body FRD to earth NED. The C functions (rotation.pxd) are
what the compiled core (estimation/inputs.pyx, estimation/bank_core.pyx) calls; the
Python functions return lists and are re-exported by :mod:`glmav_observer.frames`.
Each product and sum is rounded in the order the former Python code used (no fused
multiply-add: setup.py builds with -ffp-contract=off), so results are bit-for-bit those.
"""

from libc.math cimport cos, sin


cdef void e_flat_c(double phi_rad, double theta_rad, double psi_rad, double* E) noexcept nogil:
    cdef double sf = sin(phi_rad), cf = cos(phi_rad)
    cdef double st = sin(theta_rad), ct = cos(theta_rad)
    cdef double sp = sin(psi_rad), cp = cos(psi_rad)
    # (13), row by row
    E[0] = ct * cp
    E[1] = sf * st * cp - cf * sp
    E[2] = cf * st * cp + sf * sp
    E[3] = ct * sp
    E[4] = sf * st * sp + cf * cp
    E[5] = cf * st * sp - sf * cp
    E[6] = -st
    E[7] = sf * ct
    E[8] = cf * ct


cdef void rotate_c(const double* E, const double* v, double* out) noexcept nogil:
    cdef double v0 = v[0], v1 = v[1], v2 = v[2]
    out[0] = E[0] * v0 + E[1] * v1 + E[2] * v2
    out[1] = E[3] * v0 + E[4] * v1 + E[5] * v2
    out[2] = E[6] * v0 + E[7] * v1 + E[8] * v2


cdef void rotate_t_c(const double* E, const double* v, double* out) noexcept nogil:
    cdef double v0 = v[0], v1 = v[1], v2 = v[2]
    out[0] = E[0] * v0 + E[3] * v1 + E[6] * v2
    out[1] = E[1] * v0 + E[4] * v1 + E[7] * v2
    out[2] = E[2] * v0 + E[5] * v1 + E[8] * v2


def e_flat(double phi_rad, double theta_rad, double psi_rad):
    """E (13) as a flat row-major list of nine plain floats: ``E[3 i + j]`` is row i, column j."""
    cdef double E[9]
    e_flat_c(phi_rad, theta_rad, psi_rad, E)
    return [E[0], E[1], E[2], E[3], E[4], E[5], E[6], E[7], E[8]]


cdef inline void _load9(object seq, double* E) except *:
    cdef Py_ssize_t k
    if len(seq) != 9:
        raise ValueError(f"E: expected 9 entries (flat row-major), got {len(seq)}")
    for k in range(9):
        E[k] = seq[k]


def rotate_flat(E, v):
    """E v for a flat row-major E (:func:`e_flat`): body to earth."""
    cdef double Ec[9]
    cdef double vc[3]
    cdef double out[3]
    _load9(E, Ec)
    load3(v, vc)
    rotate_c(Ec, vc, out)
    return [out[0], out[1], out[2]]


def rotate_t_flat(E, v):
    """Eᵀ v for a flat row-major E (:func:`e_flat`): earth to body."""
    cdef double Ec[9]
    cdef double vc[3]
    cdef double out[3]
    _load9(E, Ec)
    load3(v, vc)
    rotate_t_c(Ec, vc, out)
    return [out[0], out[1], out[2]]
