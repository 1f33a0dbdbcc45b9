"""Many datagrams of a UDP socket in one system call (``recvmmsg(2)``), compiled (Cython).

:class:`UdpDrain` reads what a non-blocking IPv4 UDP socket holds, up to a bound, with
``recvmmsg`` and ``MSG_DONTWAIT``: one system call for up to ``batch`` datagrams instead
of one ``recvmsg`` each (8-15 µs a datagram in ``bench_fleet``'s ``read only`` mode,
most of it the call). Each datagram comes with its sender's address, as ``recvmsg``
gives it (``(host, port)``), and its arrival on ``time.monotonic``'s clock, converted as
:func:`glmav_observer.ingest.links._arrival_s` converts it: the kernel's receive stamp
(``SO_TIMESTAMPNS``, ``CLOCK_REALTIME``) moved by the offset of the two clocks read after
the call, and never later than the monotonic clock then; without a stamp, that clock.

Errors are those of ``socket.recvmsg``: nothing waiting (``EAGAIN``) and an earlier
send's ICMP error (``ECONNREFUSED``) end the drain with what was read; ``EINTR`` is
retried after the signal handlers ran (PEP 475); any other error is raised as the
``OSError`` Python would raise. Linux only (``AVAILABLE`` is False elsewhere, where the
links read a datagram at a time).
"""

from cpython.bytes cimport PyBytes_FromStringAndSize
from cpython.exc cimport PyErr_CheckSignals
from cpython.mem cimport PyMem_Free, PyMem_Malloc
from cpython.unicode cimport PyUnicode_FromString
from libc.errno cimport EAGAIN, ECONNREFUSED, EINTR, errno
from libc.stdint cimport int64_t, uint16_t, uint32_t
from libc.string cimport memcpy
from posix.time cimport CLOCK_MONOTONIC, CLOCK_REALTIME, clock_gettime, timespec

import os


cdef extern from *:
    """
    #if defined(__linux__)
    #ifndef _GNU_SOURCE
    #define _GNU_SOURCE
    #endif
    #include <sys/socket.h>
    #include <netinet/in.h>
    #include <arpa/inet.h>
    #define GLMAV_HAVE_RECVMMSG 1
    #ifndef SO_TIMESTAMPNS
    #define SO_TIMESTAMPNS 35
    #endif
    #define GLMAV_SCM_TIMESTAMPNS SO_TIMESTAMPNS
    static int glmav_recvmmsg(int fd, struct mmsghdr* v, unsigned int n) {
        return recvmmsg(fd, v, n, MSG_DONTWAIT, NULL);
    }
    #else
    #include <sys/socket.h>
    #include <netinet/in.h>
    #include <arpa/inet.h>
    #include <errno.h>
    #define GLMAV_HAVE_RECVMMSG 0
    #define GLMAV_SCM_TIMESTAMPNS 35
    struct mmsghdr { struct msghdr msg_hdr; unsigned int msg_len; };
    static int glmav_recvmmsg(int fd, struct mmsghdr* v, unsigned int n) {
        (void)fd; (void)v; (void)n; errno = ENOSYS; return -1;
    }
    #endif
    """
    int GLMAV_HAVE_RECVMMSG
    int GLMAV_SCM_TIMESTAMPNS


cdef extern from "<errno.h>" nogil:
    int EWOULDBLOCK

cdef extern from "<sys/uio.h>" nogil:
    struct iovec:
        void* iov_base
        size_t iov_len

cdef extern from "<sys/socket.h>" nogil:
    ctypedef unsigned int socklen_t
    struct msghdr:
        void* msg_name
        socklen_t msg_namelen
        iovec* msg_iov
        size_t msg_iovlen
        void* msg_control
        size_t msg_controllen
        int msg_flags
    struct cmsghdr:
        size_t cmsg_len
        int cmsg_level
        int cmsg_type
    struct mmsghdr:
        msghdr msg_hdr
        unsigned int msg_len
    cmsghdr* CMSG_FIRSTHDR(msghdr* m)
    cmsghdr* CMSG_NXTHDR(msghdr* m, cmsghdr* c)
    unsigned char* CMSG_DATA(cmsghdr* c)
    size_t CMSG_SPACE(size_t n)
    size_t CMSG_LEN(size_t n)
    int SOL_SOCKET
    int AF_INET
    int glmav_recvmmsg(int fd, mmsghdr* v, unsigned int n)

cdef extern from "<netinet/in.h>" nogil:
    struct in_addr:
        uint32_t s_addr
    struct sockaddr_in:
        unsigned short sin_family
        uint16_t sin_port
        in_addr sin_addr
    uint16_t ntohs(uint16_t v)
    int INET_ADDRSTRLEN

cdef extern from "<arpa/inet.h>" nogil:
    const char* inet_ntop(int af, const void* src, char* dst, socklen_t size)


#: True where ``recvmmsg`` exists (Linux): elsewhere a drain cannot be made
AVAILABLE = bool(GLMAV_HAVE_RECVMMSG)

cdef enum:
    _DATAGRAM_MAX = 65535

#: the largest datagram read whole (as the links' ``recvmsg(65535)``)
DATAGRAM_MAX = _DATAGRAM_MAX
#: the peers kept for reuse (one tuple per sender instead of one per datagram)
_PEERS_MAX = 4096

cdef struct _Stamp:
    int64_t tv_sec
    int64_t tv_nsec


cdef inline double _seconds(timespec ts) noexcept nogil:
    """A clock reading as Python's time functions make it a float (_PyTime_AsSecondsDouble)."""
    cdef int64_t ns = <int64_t>ts.tv_sec * 1000000000 + ts.tv_nsec
    if ns % 1000000000 == 0:
        return <double>(ns // 1000000000)
    return <double>ns / 1e9


cdef class UdpDrain:
    """Reads a UDP socket's datagrams ``batch`` at a time (``recvmmsg``); ``stamps``: the
    socket has ``SO_TIMESTAMPNS`` on (the arrivals are the kernel's stamps). The caller
    keeps the socket open while it uses the drain (the drain holds its number only)."""

    cdef int fd
    cdef unsigned int batch
    cdef bint stamps
    cdef mmsghdr* msgs
    cdef iovec* iovs
    cdef sockaddr_in* names
    cdef char* bufs
    cdef char* controls
    cdef size_t control_len
    cdef dict peers

    def __cinit__(self, int fd, int batch=64, bint stamps=True):
        if not GLMAV_HAVE_RECVMMSG:
            raise OSError(38, "recvmmsg is not available on this system")
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.fd = fd
        self.batch = batch
        self.stamps = stamps
        self.control_len = CMSG_SPACE(sizeof(_Stamp))
        self.peers = {}
        self.msgs = <mmsghdr*>PyMem_Malloc(batch * sizeof(mmsghdr))
        self.iovs = <iovec*>PyMem_Malloc(batch * sizeof(iovec))
        self.names = <sockaddr_in*>PyMem_Malloc(batch * sizeof(sockaddr_in))
        # large: only the pages a datagram is written to are ever touched
        self.bufs = <char*>PyMem_Malloc(<size_t>batch * _DATAGRAM_MAX)
        self.controls = <char*>PyMem_Malloc(batch * self.control_len)
        if (
            self.msgs == NULL or self.iovs == NULL or self.names == NULL
            or self.bufs == NULL or self.controls == NULL
        ):
            raise MemoryError()
        cdef int i
        for i in range(batch):
            self.iovs[i].iov_base = self.bufs + <size_t>i * _DATAGRAM_MAX
            self.iovs[i].iov_len = _DATAGRAM_MAX

    def __dealloc__(self):
        PyMem_Free(self.msgs)
        PyMem_Free(self.iovs)
        PyMem_Free(self.names)
        PyMem_Free(self.bufs)
        PyMem_Free(self.controls)

    cdef inline void _arm(self, unsigned int n) noexcept nogil:
        cdef unsigned int i
        cdef msghdr* h
        for i in range(n):
            h = &self.msgs[i].msg_hdr
            h.msg_name = &self.names[i]
            h.msg_namelen = sizeof(sockaddr_in)
            h.msg_iov = &self.iovs[i]
            h.msg_iovlen = 1
            if self.stamps:
                h.msg_control = self.controls + <size_t>i * self.control_len
                h.msg_controllen = self.control_len
            else:
                h.msg_control = NULL
                h.msg_controllen = 0
            h.msg_flags = 0
            self.msgs[i].msg_len = 0

    cdef object _peer(self, msghdr* h):
        cdef sockaddr_in* a = <sockaddr_in*>h.msg_name
        cdef char host[16]
        if h.msg_namelen < sizeof(sockaddr_in) or a.sin_family != AF_INET:
            return None
        key = (<unsigned long long>a.sin_addr.s_addr << 16) | a.sin_port
        peer = self.peers.get(key)
        if peer is None:
            inet_ntop(AF_INET, &a.sin_addr, host, sizeof(host))
            peer = (PyUnicode_FromString(host), ntohs(a.sin_port))
            if len(self.peers) >= _PEERS_MAX:
                self.peers.clear()
            self.peers[key] = peer
        return peer

    def drain(self, int max_n):
        """Up to ``max_n`` datagrams waiting now, in arrival order: a list of (bytes,
        arrival on ``time.monotonic``'s clock, sender ``(host, port)``), empty when none
        is waiting (or an ICMP error of an earlier send was all there was). Fewer than
        ``max_n``: the socket was empty. An empty datagram is in the list as ``b""``."""
        cdef list out = []
        cdef unsigned int want
        cdef int r, err, i
        cdef timespec mono_ts, real_ts
        cdef double mono, offset, t
        cdef msghdr* h
        cdef cmsghdr* c
        cdef _Stamp st
        cdef bint found
        while max_n > 0:
            want = self.batch if <unsigned int>max_n > self.batch else <unsigned int>max_n
            self._arm(want)
            while True:
                with nogil:
                    r = glmav_recvmmsg(self.fd, self.msgs, want)
                    err = errno
                if r >= 0 or err != EINTR:
                    break
                PyErr_CheckSignals()  # as Python does before it retries (PEP 475)
            if r < 0:
                if err == EAGAIN or err == EWOULDBLOCK or err == ECONNREFUSED:
                    return out
                raise OSError(err, os.strerror(err))
            # the clocks after the call, as _arrival_s reads them after each recvmsg
            clock_gettime(CLOCK_MONOTONIC, &mono_ts)
            clock_gettime(CLOCK_REALTIME, &real_ts)
            mono = _seconds(mono_ts)
            offset = _seconds(real_ts) - mono
            for i in range(r):
                h = &self.msgs[i].msg_hdr
                t = mono
                if self.stamps:
                    c = CMSG_FIRSTHDR(h)
                    while c != NULL:
                        if (
                            c.cmsg_level == SOL_SOCKET
                            and c.cmsg_type == GLMAV_SCM_TIMESTAMPNS
                            and c.cmsg_len >= CMSG_LEN(sizeof(_Stamp))
                        ):
                            memcpy(&st, CMSG_DATA(c), sizeof(_Stamp))
                            t = <double>st.tv_sec + <double>st.tv_nsec * 1e-9 - offset
                            if t > mono:  # a clock step between the reads: not later
                                t = mono
                            break
                        c = CMSG_NXTHDR(h, c)
                out.append((
                    PyBytes_FromStringAndSize(<char*>self.iovs[i].iov_base, self.msgs[i].msg_len),
                    t,
                    self._peer(h),
                ))
            max_n -= r
            if <unsigned int>r < want:
                break  # the socket is empty (as of the call)
        return out
