"""The compiled core's choices against their alternatives, measured (issue 30).

1. **Frame decoding.** Per ATTITUDE frame (MAVLink 2, unsigned): the service's decoder
   (``ingest/fastframe.pyx``, compiled: CRC and fields straight from the frame bytes),
   pymavlink's own ``decode``, a bare ``struct.unpack_from`` of the payload (the
   floor of any Python-level decoder), and Auterion's ``libmav`` (C++, on the package
   index) when it is installed: its Python binding has no parser for bytes, only its own
   network runtime (sockets and threads), so it is measured as it can be used: frames
   sent to its ``UDPServer`` on loopback, each delivered to a Python callback as a dict
   (the same frames through a bare Python UDP socket beside it).
2. **The bank's step.** One call from Python with the held inputs as the service holds
   them (tuples of floats): the Cython :class:`BankCore`, the same closed form under
   numba's ``njit`` when numba is installed (its import and first-call compile times
   too), and the numpy oracle (``observer.zoh_step``).

``pip install libmav numba`` adds the optional rows; without them the rows say so.
CPU time per call (``process_time``), medians of repeats.
"""

from __future__ import annotations

import math
import socket
import statistics
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.common import format_table, git_head, machine, main_for
from glmav_observer.configurations import CONFIG_MASKS
from glmav_observer.estimation.bank_core import BankCore
from glmav_observer.estimation.observer import e_matrix, gamma_body_mps2, zoh_step
from glmav_observer.ingest.fastframe import decode as fastframe_decode


def _per_call_us(fn: Callable[[], None], n: int, repeats: int) -> float:
    fn()
    out = []
    for _ in range(repeats):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        out.append((time.process_time() - t0) / n * 1e6)
    return statistics.median(out)


def _frames(n: int) -> list[bytearray]:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for i in range(n):
        msg = mav.MAVLink_attitude_message(i, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03)
        out.append(bytearray(msg.pack(m)))
    return out


def _libmav_row(frames: list[bytearray]) -> dict[str, Any]:
    try:
        import libmav  # type: ignore[import-not-found]
    except ImportError:
        return {
            "case": "libmav (not installed: pip install libmav)",
            "us_per_frame": math.nan,
            "wall_us_per_frame": math.nan,
        }
    from pymavlink.dialects.v20 import ardupilotmega

    xml = ardupilotmega.__file__.replace(".py", ".xml")
    msgs = libmav.MessageSet()
    try:
        msgs.add_from_xml_file(xml, True)
    except Exception as err:  # the dialect file next to pymavlink's module
        return {
            "case": f"libmav (dialect not loaded: {err})",
            "us_per_frame": math.nan,
            "wall_us_per_frame": math.nan,
        }
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    iface = libmav.UDPServer(port)
    runtime = libmav.NetworkRuntime(msgs, iface)
    got: list[dict[str, Any]] = []
    done = threading.Event()
    n = len(frames) - 1
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        tx.sendto(bytes(frames[0]), ("127.0.0.1", port))
        conn = runtime.await_connection(2000)

        def on_message(msg: Any) -> None:
            got.append(msg.to_dict())
            if len(got) >= n:
                done.set()

        conn.add_message_callback(on_message)
        t0 = time.process_time()
        w0 = time.perf_counter()
        for f in frames[1:]:
            tx.sendto(bytes(f), ("127.0.0.1", port))
        done.wait(30)
        cpu = time.process_time() - t0
        wall = time.perf_counter() - w0
    runtime.stop()
    return {
        "case": f"libmav UDPServer -> Python callback -> dict ({len(got)} of {n} delivered)",
        "us_per_frame": cpu / max(len(got), 1) * 1e6,
        "wall_us_per_frame": wall / max(len(got), 1) * 1e6,
    }


def _udp_row(frames: list[bytearray]) -> dict[str, Any]:
    n = len(frames) - 1
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx,
    ):
        rx.bind(("127.0.0.1", 0))
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        rx.settimeout(5.0)
        got = 0
        t0 = time.process_time()
        w0 = time.perf_counter()
        for f in frames[1:]:
            tx.sendto(bytes(f), rx.getsockname())
        try:
            while got < n:
                rx.recv(512)
                got += 1
        except TimeoutError:
            pass
        cpu = time.process_time() - t0
        wall = time.perf_counter() - w0
    return {
        "case": f"bare Python UDP send + recv, same frames ({got} of {n} delivered)",
        "us_per_frame": cpu / max(got, 1) * 1e6,
        "wall_us_per_frame": wall / max(got, 1) * 1e6,
    }


def _decode_rows(quick: bool) -> list[dict[str, Any]]:
    n = 5000 if quick else 20000
    repeats = 3 if quick else 7
    frames = _frames(n)
    from pymavlink.dialects.v20 import ardupilotmega as mav

    parser = mav.MAVLink(None)
    unpack = struct.Struct("<Iffffff").unpack_from

    def cycle(fn: Callable[[bytearray], object]) -> Callable[[], None]:
        k = [0]

        def call() -> None:
            fn(frames[k[0]])
            k[0] = (k[0] + 1) % n

        return call

    nan = math.nan  # (no wall time: CPU only, in this process)
    rows = [
        {
            "case": "service decoder (fastframe.decode, compiled)",
            "us_per_frame": _per_call_us(
                cycle(lambda f: fastframe_decode(f, 0, len(f))), n, repeats
            ),
            "wall_us_per_frame": nan,
        },
        {
            "case": "pymavlink MAVLink.decode",
            "us_per_frame": _per_call_us(cycle(parser.decode), n, repeats),
            "wall_us_per_frame": nan,
        },
        {
            "case": "struct.unpack_from of the payload (floor)",
            "us_per_frame": _per_call_us(cycle(lambda f: unpack(f, 10)), n, repeats),
            "wall_us_per_frame": nan,
        },
        _libmav_row(frames),
        _udp_row(frames),
    ]
    return rows


def _bank_rows(quick: bool) -> list[dict[str, Any]]:
    n = 20000 if quick else 100000
    repeats = 3 if quick else 7
    eul, w, f, y = (0.1, 0.2, 0.3), (0.01, 0.02, 0.03), (0.1, 0.2, -9.8), (1.0, 2.0, 3.0)
    gam = (12.4, 12.4, 12.4, 12.4)
    core = BankCore(gam, 9.81)
    lost = (-1, 0, 1, 2)
    rows = [
        {
            "case": "Cython BankCore.step (the service's)",
            "us_per_step": _per_call_us(lambda: core.step(0.004, eul, w, f, y, lost), n, repeats),
        }
    ]
    x = np.zeros((4, 3))
    E = e_matrix(np.array(eul))
    G = gamma_body_mps2(np.array(f), np.array(eul))
    ga = np.array(gam)
    yv, wv = np.array(y), np.array(w)
    rows.append(
        {
            "case": "numpy oracle observer.zoh_step (4 configurations at once)",
            "us_per_step": _per_call_us(
                lambda: zoh_step(x, wv, G, E, yv, CONFIG_MASKS, ga, 0.004, orthogonal_e=True),
                max(n // 20, 500),
                repeats,
            ),
        }
    )
    rows.extend(_numba_rows(n, repeats, eul, w, f, y, gam))
    return rows


def _numba_rows(  # noqa: PLR0917 -- the inputs of one step
    n: int, repeats: int, eul: Any, w: Any, f: Any, y: Any, gam: Any
) -> list[dict[str, Any]]:
    t0 = time.perf_counter()
    try:
        from numba import njit  # type: ignore[import-not-found]
    except ImportError:
        return [{"case": "numba njit (not installed: pip install numba)", "us_per_step": math.nan}]
    import_s = time.perf_counter() - t0

    @njit(cache=False)  # type: ignore[misc]
    def step(  # noqa: PLR0917 -- the kernel's arrays and the inputs of one step
        x: Any, E: Any, gm: Any, terms: Any, h: float, eul: Any, w: Any, f: Any, y: Any,
        lost: Any, g: float,
    ) -> None:  # fmt: skip
        sf, cf = math.sin(eul[0]), math.cos(eul[0])
        st, ct = math.sin(eul[1]), math.cos(eul[1])
        sp, cp = math.sin(eul[2]), math.cos(eul[2])
        E[0], E[1], E[2] = ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp
        E[3], E[4], E[5] = ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp
        E[6], E[7], E[8] = -st, sf * ct, cf * ct
        we = np.empty(3)
        a = np.empty(3)
        z = np.empty(3)
        for r in range(3):
            we[r] = E[3 * r] * w[0] + E[3 * r + 1] * w[1] + E[3 * r + 2] * w[2]
            a[r] = E[3 * r] * f[0] + E[3 * r + 1] * f[1] + E[3 * r + 2] * f[2]
        a[2] += g
        for i in range(4):
            e, hp1, h2p2, gg = terms[i, 0], terms[i, 1], terms[i, 2], gm[i]
            for r in range(3):
                z[r] = E[3 * r] * x[i, 0] + E[3 * r + 1] * x[i, 1] + E[3 * r + 2] * x[i, 2]
            ln = lost[i]
            if ln < 0:
                z[0] = e * z[0] + hp1 * (a[0] - (we[1] * y[2] - we[2] * y[1]) + gg * y[0])
                z[1] = e * z[1] + hp1 * (a[1] - (we[2] * y[0] - we[0] * y[2]) + gg * y[1])
                z[2] = e * z[2] + hp1 * (a[2] - (we[0] * y[1] - we[1] * y[0]) + gg * y[2])
            else:
                m1, m2 = (ln + 1) % 3, (ln + 2) % 3
                zl0 = z[ln]
                cl = a[ln] - (we[m1] * y[m2] - we[m2] * y[m1])
                z[ln] = zl0 + h * cl
                z[m1] = (e * z[m1] + hp1 * (a[m1] + we[ln] * y[m2] + gg * y[m1] - we[m2] * zl0)
                         - h2p2 * we[m2] * cl)  # fmt: skip
                z[m2] = (e * z[m2] + hp1 * (a[m2] - we[ln] * y[m1] + gg * y[m2] + we[m1] * zl0)
                         + h2p2 * we[m1] * cl)  # fmt: skip
            for c in range(3):
                x[i, c] = E[c] * z[0] + E[3 + c] * z[1] + E[6 + c] * z[2]

    x = np.zeros((4, 3))
    E = np.eye(3).ravel().copy()
    gm = np.array(gam)
    terms = np.array([[math.exp(-g * 0.004), 0.0039, 7.8e-6] for g in gam])
    lost = np.array([-1, 0, 1, 2])
    t0 = time.perf_counter()
    step(x, E, gm, terms, 0.004, eul, w, f, y, lost, 9.81)
    jit_s = time.perf_counter() - t0
    us = _per_call_us(lambda: step(x, E, gm, terms, 0.004, eul, w, f, y, lost, 9.81), n, repeats)
    return [
        {
            "case": f"numba njit, same closed form (import {import_s:.2f} s, first call "
            f"compiles {jit_s:.2f} s, per process)",
            "us_per_step": us,
        }
    ]


def run(quick: bool = False) -> dict[str, Any]:
    decode = _decode_rows(quick)
    bank = _bank_rows(quick)
    return {
        "name": "bench_alternatives",
        "machine": machine(),
        "git_head": git_head(),
        "quick": quick,
        "decode": decode,
        "bank": bank,
        "goals": [],
    }


def to_markdown(result: dict[str, Any]) -> str:
    label = f"\n\nLabel: {result['label']}." if result.get("label") else ""
    return (
        "### The compiled core's alternatives (bench_alternatives)\n\n"
        "Command: `python -m benchmarks.bench_alternatives` (with `pip install libmav "
        f"numba` for the optional rows); CPU time per call, medians.{label}\n\n"
        "Decoding one ATTITUDE frame:\n\n"
        + format_table(result["decode"])
        + "\n\nThe bank's step, one call from Python with the held inputs as tuples:\n\n"
        + format_table(result["bank"])
    )


if __name__ == "__main__":
    raise SystemExit(main_for(__import__(__name__)))
