# The body-to-earth rotation E (13) in C, for the compiled per-sample core to cimport
# (rotation.pyx has the Python-visible forms and the docs).

cdef void e_flat_c(double phi_rad, double theta_rad, double psi_rad, double* E) noexcept nogil
cdef void rotate_c(const double* E, const double* v, double* out) noexcept nogil
cdef void rotate_t_c(const double* E, const double* v, double* out) noexcept nogil


cdef inline void load3(object seq, double* v) except *:
    """Three floats of a Python sequence into a C vector (ValueError if not three)."""
    v[0], v[1], v[2] = seq
