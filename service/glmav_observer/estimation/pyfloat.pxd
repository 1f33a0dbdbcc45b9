"""Python's float arithmetic where C's differs: ``x ** 2``.

CPython computes ``x ** 2`` with libm's ``pow``, which on glibc differs from the one
rounding of ``x * x`` in about 1 of 1200 values (by one ulp); and a C compiler turns
``pow(x, 2.0)`` into ``x * x``. The compiled kernels that replace Python's ``** 2`` call
:func:`py_square`, whose exponent the compiler cannot see (a volatile 2.0): the same doubles
as the Python they replace.
"""

from libc.math cimport pow

cdef extern from *:
    """
    static volatile double glmav_pyfloat_two = 2.0;
    """
    double glmav_pyfloat_two


cdef inline double py_square(double x) noexcept nogil:
    """``x ** 2`` as Python computes it (libm's pow, not x * x)."""
    return pow(x, glmav_pyfloat_two)
