"""The fleet generator's send loop, compiled (Cython): one window of frames, each sent
once its due time has come, with ``send(2)`` on each vehicle's connected UDP sockets.

:func:`send_window` is the loop of :mod:`glmav_sitl.fleet` (one implementation, for
every kind of link): per frame, in the window's order, it reads the clock, sleeps
through ``stop_wait`` (the stop event's ``wait``, after ``flush``) when the frame is
more than ``min_sleep_s`` away, sends the frame on each of its vehicle's descriptors, then calls its vehicle's Python ``emit`` (the
stream links' part) if it has one. A send that fails is passed to ``failed(slot, error)``
with the ``OSError`` Python's ``socket.send`` raises (ECONNREFUSED from an earlier
datagram's ICMP, EAGAIN with the socket's buffer full, ...); ``EINTR`` is retried as
Python does. A frame is counted in the returned total whether its sends succeeded or not,
as the Python loop counted it; successes are counted per descriptor slot in ``sent``.

The clock is :func:`monotonic_s` (``CLOCK_MONOTONIC``): the caller's ``wall0`` must be
read from it. What is left per frame is the system call (about 3.5 µs on loopback).
"""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_GET_SIZE
from cpython.exc cimport PyErr_CheckSignals
from libc.errno cimport EINTR, errno
from posix.time cimport CLOCK_MONOTONIC, clock_gettime, timespec

import os


cdef extern from "<sys/socket.h>" nogil:
    ssize_t send(int fd, const void* buf, size_t n, int flags)


cdef inline double _now() noexcept nogil:
    cdef timespec ts
    clock_gettime(CLOCK_MONOTONIC, &ts)
    return <double>ts.tv_sec + <double>ts.tv_nsec * 1e-9


def monotonic_s() -> float:
    """``CLOCK_MONOTONIC`` in s: the clock of :func:`send_window`."""
    return _now()


def send_window(
    const long long[::1] order not None,
    const double[::1] due_s not None,
    list datas not None,
    const long long[::1] owners not None,
    const int[::1] fd_start not None,
    const int[::1] fds not None,
    long long[::1] sent not None,
    list emits,
    object failed,
    object flush,
    object stop_wait,
    double wall0,
    double min_sleep_s,
):
    """Send frames ``order[0], order[1], ...`` (indices into ``due_s``, ``datas`` and
    ``owners``); frame i belongs to vehicle ``owners[i]``, whose descriptors are
    ``fds[fd_start[k]:fd_start[k + 1]]`` and whose ``emits[k]`` (``emits`` None, or the
    entry None: nothing) is called with the frame after them. Returns (frames sent, the
    most any was sent after its due time, the clock read at each frame); stops early when ``stop_wait``
    returns true."""
    cdef Py_ssize_t n_frames = order.shape[0]
    cdef Py_ssize_t n = 0, j, i, k, slot
    cdef double now = _now() - wall0
    cdef double late_max = 0.0, due
    cdef bytes data
    cdef const char* buf
    cdef Py_ssize_t size
    cdef ssize_t r
    cdef int err
    if due_s.shape[0] != len(datas) or owners.shape[0] != len(datas):
        raise ValueError("due_s, datas and owners must have one entry per frame")
    if fd_start.shape[0] < 1 or fd_start[fd_start.shape[0] - 1] > fds.shape[0]:
        raise ValueError("fd_start must end within fds")
    for k in range(fd_start.shape[0] - 1):
        if not 0 <= fd_start[k] <= fd_start[k + 1]:
            raise ValueError("fd_start must be non-decreasing from 0")
    if sent.shape[0] < fds.shape[0]:
        raise ValueError("sent must have one counter per descriptor")
    if emits is not None and len(emits) < fd_start.shape[0] - 1:
        raise ValueError("emits must have one entry per vehicle")
    for j in range(n_frames):
        i = order[j]
        if i < 0 or i >= due_s.shape[0]:
            raise IndexError(f"frame {i} not in the window")
        k = owners[i]
        if k < 0 or k >= fd_start.shape[0] - 1:
            raise IndexError(f"vehicle {k} not in the window")
        due = due_s[i]
        # the clock at every frame (vDSO: tens of ns): a stall of the process while it
        # sends a backlog is lateness too, which a clock read only at the sleeps misses
        now = _now() - wall0
        if due > now:
            flush()
            if due - now > min_sleep_s and stop_wait(due - now):
                break
            now = _now() - wall0
        if now - due > late_max:
            late_max = now - due
        data = datas[i]
        buf = PyBytes_AS_STRING(data)
        size = PyBytes_GET_SIZE(data)
        for slot in range(fd_start[k], fd_start[k + 1]):
            while True:
                with nogil:
                    r = send(fds[slot], buf, <size_t>size, 0)
                    err = errno
                if r >= 0 or err != EINTR:
                    break
                PyErr_CheckSignals()  # as Python does before it retries (PEP 475)
            if r >= 0:
                sent[slot] += 1
            else:
                failed(slot, OSError(err, os.strerror(err)))
        if emits is not None:
            emit = emits[k]
            if emit is not None:
                emit(data)
        n += 1
    return n, late_max
