cdef class HeldInputs:
    cdef public double g_mps2
    cdef public object euler_rad
    cdef public object omega_att_radps
    cdef public object omega_imu_radps
    cdef public object f_body_mps2
    cdef double y[3]
    cdef double a_int_c[3]
    cdef double a_at_y[3]
    cdef double b_int[9]
    cdef double b_at_y[9]
    cdef double c_int_c[3]
    cdef double f_int[4]
    cdef double f_at_y[4]
    cdef double* hist
    cdef Py_ssize_t h_cap, h_start, h_len

    cdef void y_for_step_c(self, const double* b, bint propagate, double* out) noexcept
    cdef void y_rate_c(self, const double* E, const double* f, const double* b, double* out) noexcept
    cdef void _hist_push(self, double t, const double* ai) except *
    cdef double* _hist_at(self, Py_ssize_t i) noexcept
    cdef void integrate_c(self, double t, double dt, const double* E, const double* f) except *
    cdef void kick_c(self, const double* E, const double* d_body) noexcept
