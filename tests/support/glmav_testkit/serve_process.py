"""``glmav-observer serve`` as a real process on a loopback UDP port, watched from outside.

The pieces the worker-mode soak and fuzz (``benchmarks/soak.py --serve``,
``benchmarks/fuzz_ingest.py --serve``, ``tests/integration/glmav_observer/
test_serve_fuzz.py``) share:

- :class:`ServeProcess`: starts ``serve --workers N --link udpin:127.0.0.1:PORT``
  (stdout and stderr to files: a pipe nobody reads would block a long run), samples the
  resident memory and open file descriptors of the parent and of every child process
  (the workers and multiprocessing's resource tracker) with psutil, and stops it with a
  signal to the parent's pid (as ``kill PID`` or a service manager does), returning the
  exit code, the time to exit and the parsed summary;
- :func:`parse_summary`: the counters of serve's summary text;
- :func:`free_udp_port`: a free port below the kernel's ephemeral range (tests/conftest's
  rule: a port bind(0) handed out is reused by the next client socket);
- :class:`PacedSender`: sends datagrams on a schedule, holding back while the port's
  receive queues (all of its sockets: one per worker) hold more than a bound, so that on
  a loaded machine the sender waits for the service instead of overflowing the kernel's
  buffer (the drops are then the service's failure to keep up with the bound, not the
  machine's load).
"""

from __future__ import annotations

import contextlib
import os
import random
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import psutil

from glmav_testkit.fleet_helpers import udp_queue, wait_bound_udp

OBS = str(Path(sys.executable).with_name("glmav-observer"))


def free_udp_port() -> int:
    """A UDP port free now on 127.0.0.1, chosen at random below the ephemeral range."""
    try:
        high = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        high = 32768
    rng = random.Random()
    for _ in range(200):
        port = rng.randrange(max(10_000, high - 12_000), high)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise OSError("no free UDP port below the ephemeral range")


@dataclass
class ServeSummary:
    """What ``serve`` printed at exit (stdout), parsed."""

    text: str
    messages: int = 0
    records: int = 0
    rejected_frames: int = 0
    #: link counters summed over the links (frames_ok, bad_crc, kernel_drops, ...)
    link: dict[str, int] = field(default_factory=dict)
    service: dict[str, int] = field(default_factory=dict)
    vehicles: list[int] = field(default_factory=list)
    #: ``worker i: K vehicles [...]`` lines (empty with one process)
    workers: list[str] = field(default_factory=list)

    @property
    def present(self) -> bool:
        return bool(re.match(r"messages \d+, records \d+", self.text))


def _counters(text: str) -> dict[str, int]:
    return {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", text)}


def parse_summary(text: str) -> ServeSummary:
    s = ServeSummary(text)
    m = re.search(r"(?m)^messages (\d+), records (\d+), rejected frames (\d+)", text)
    if m is None:
        return s
    s.messages, s.records, s.rejected_frames = (int(g) for g in m.groups())
    for line in re.findall(r"(?m)^link \S+: (\w+=.*)$", text):
        for k, v in _counters(line).items():
            s.link[k] = s.link.get(k, 0) + v
    svc = re.search(r"(?m)^service: (.*)$", text)
    if svc is not None:
        s.service = _counters(svc.group(1))
    s.vehicles = [int(v) for v in re.findall(r"(?m)^vehicle (\d+):", text)]
    s.workers = re.findall(r"(?m)^worker \d+: .*$", text)
    return s


@dataclass
class Stopped:
    """How ``serve`` ended after the signal."""

    returncode: int
    stop_s: float
    summary: ServeSummary
    stderr: str


def _role(p: psutil.Process) -> str:
    try:
        cmd = " ".join(p.cmdline())
    except psutil.Error:
        return "gone"
    if "resource_tracker" in cmd:
        return "resource_tracker"
    return "worker" if "multiprocessing" in cmd or "spawn_main" in cmd else "child"


def usable_cores() -> int:
    """serve's default number of workers here (its CPU affinity, as ``serve`` counts)."""
    from glmav_observer.commands.serve import usable_cores as cores

    return cores()


class ServeProcess:
    """``glmav-observer serve`` on ``udpin:127.0.0.1:port`` with ``workers`` workers
    (``None``: no ``--workers``, serve's default)."""

    def __init__(
        self,
        port: int,
        workers: int | None,
        workdir: Path,
        *,
        zenoh: bool = False,
        out: Path | None = None,
        service_id: str | None = None,
        extra: Sequence[str] = (),
    ) -> None:
        self.port = port
        #: None: serve's default (one worker per usable core, said in its log)
        self.workers = workers if workers is not None else usable_cores()
        args = [OBS, "serve", "--link", f"udpin:127.0.0.1:{port}"]
        if workers is not None:
            args += ["--workers", str(workers)]
        if not zenoh:
            args.append("--no-zenoh")
        if out is not None:
            args += ["--out", str(out)]
        if service_id is not None:
            args += ["--service-id", service_id]
        args += list(extra)
        self.stdout_path = workdir / f"serve-{port}.out"
        self.stderr_path = workdir / f"serve-{port}.err"
        self._out: IO[str] = self.stdout_path.open("w", encoding="utf-8")
        self._err: IO[str] = self.stderr_path.open("w", encoding="utf-8")
        self.proc = subprocess.Popen(args, stdout=self._out, stderr=self._err, text=True)
        self.ps = psutil.Process(self.proc.pid)
        self._children: dict[int, psutil.Process] = {}
        self._names: dict[int, str] = {}

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """Until the port is bound and, with workers, every worker process is running."""
        wait_bound_udp(self.port, self.proc, timeout_s)
        deadline = time.monotonic() + timeout_s
        while self.workers > 1 and len(self.processes()) < 1 + self.workers:
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise AssertionError(f"serve: workers not running ({self.proc.poll()})")
            time.sleep(0.05)

    def wait_log(self, text: str, timeout_s: float = 120.0) -> None:
        """Until ``text`` is in serve's log (stderr), or raise."""
        deadline = time.monotonic() + timeout_s
        while text not in self.stderr_path.read_text(encoding="utf-8", errors="replace"):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise AssertionError(f"serve: no {text!r} in its log ({self.proc.poll()})")
            time.sleep(0.05)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def processes(self) -> list[tuple[str, psutil.Process]]:
        """(role, process): the parent first, then its workers (not the resource tracker,
        which is multiprocessing's, not the service's)."""
        out = [("parent", self.ps)]
        try:
            kids = self.ps.children(recursive=True)
        except psutil.Error:
            return out
        for kid in sorted(kids, key=lambda k: k.pid):
            p = self._children.setdefault(kid.pid, kid)  # one object per pid: cpu times
            if _role(p) == "worker":
                # a stable name per process, in the order they started
                name = self._names.setdefault(p.pid, f"worker{len(self._names)}")
                out.append((name, p))
        return out

    def sample(self) -> dict[str, dict[str, float]]:
        """RSS (MB) and open fds of the parent and every worker, now."""
        got: dict[str, dict[str, float]] = {}
        for name, p in self.processes():
            try:
                with p.oneshot():
                    got[name] = {
                        "rss_mb": p.memory_info().rss / 2**20,
                        "fds": float(p.num_fds()),
                        "threads": float(p.num_threads()),
                    }
            except psutil.Error:
                continue
        return got

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 120.0) -> Stopped:
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10.0)
        stop_s = time.monotonic() - t0
        self._out.close()
        self._err.close()
        # the workers exit once the parent closed their pipes; none may stay behind
        for p in self._children.values():
            try:
                p.wait(30.0)
            except psutil.TimeoutExpired:
                p.kill()
            except psutil.Error:
                pass
        return Stopped(
            self.proc.returncode,
            stop_s,
            parse_summary(self.stdout_path.read_text(encoding="utf-8")),
            self.stderr_path.read_text(encoding="utf-8", errors="replace"),
        )

    def kill(self) -> None:
        """Clean-up after a failure: the parent and its workers, by pid."""
        for p in [self.ps, *self._children.values()]:
            with contextlib.suppress(psutil.Error):
                p.kill()
        self._out.close()
        self._err.close()


class PacedSender:
    """Datagrams to 127.0.0.1:``port`` on a schedule, never more than ``max_queued_bytes``
    waiting in the port's receive queues (the kernel's accounting, ``/proc/net/udp``).

    ``SO_RCVBUF`` is 4 MB (``[service] udp_receive_buffer_bytes``, and net.core.rmem_max
    here): a bound of a quarter of it leaves the service's burst headroom untouched, so
    a datagram is dropped only if the service stops reading altogether."""

    def __init__(self, port: int, max_queued_bytes: int = 1 << 20, check_every: int = 64) -> None:
        self.port = port
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.max_queued = max_queued_bytes
        self.check_every = check_every
        self.sent = 0
        self.held_s = 0.0  # time spent waiting for the service to read
        self.replies = 0  # datagrams the service sent back (rate requests)
        self._since_check = 0

    def send(self, data: bytes) -> None:
        self._since_check += 1
        if self._since_check >= self.check_every:
            self._since_check = 0
            self._hold()
        self.sock.sendto(data, ("127.0.0.1", self.port))
        self.sent += 1

    def _hold(self) -> None:
        t0 = time.monotonic()
        while udp_queue(self.port)[0] > self.max_queued:
            time.sleep(0.002)
            if time.monotonic() - t0 > 120.0:
                raise TimeoutError(f"UDP {self.port}: the service stopped reading")
        self.held_s += time.monotonic() - t0
        while True:  # what the service sends back is read and counted, not left queued
            try:
                self.sock.recv(65535)
            except BlockingIOError:
                break
            self.replies += 1

    def pace(self, t_due_s: float) -> None:
        """Sleep until ``t_due_s`` (``time.monotonic``) if it is still ahead."""
        dt = t_due_s - time.monotonic()
        if dt > 0:
            time.sleep(dt)

    def close(self) -> None:
        self.sock.close()


def loadavg_1min() -> float:
    return os.getloadavg()[0]


def slope_per_min(series: Sequence[tuple[float, float]]) -> float:
    """Least-squares slope of ``(t_s, value)`` in value per minute (0 for < 2 points)."""
    n = len(series)
    if n < 2:
        return 0.0
    mt = sum(t for t, _ in series) / n
    mv = sum(v for _, v in series) / n
    sxx = sum((t - mt) ** 2 for t, _ in series)
    if sxx == 0:
        return 0.0
    return 60.0 * sum((t - mt) * (v - mv) for t, v in series) / sxx


def summarise_processes(
    samples: Sequence[tuple[float, dict[str, dict[str, float]]]], warmup_s: float
) -> dict[str, dict[str, Any]]:
    """Per process: RSS after the warm-up and at the end (medians of 5 samples), its slope
    (MB/min, least squares after the warm-up) and its open fds (first after warm-up, last,
    max)."""
    names = sorted({n for _, s in samples for n in s})
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        pts = [(t, s[name]) for t, s in samples if name in s and t >= warmup_s]
        if len(pts) < 2:
            continue
        rss = [(t, v["rss_mb"]) for t, v in pts]
        fds = [v["fds"] for _, v in pts]
        first = sorted(v for _, v in rss[:5])[len(rss[:5]) // 2]
        last = sorted(v for _, v in rss[-5:])[len(rss[-5:]) // 2]
        out[name] = {
            "rss_warm_mb": first,
            "rss_end_mb": last,
            "rss_growth_pct": 100.0 * (last - first) / first,
            "rss_slope_mb_per_min": slope_per_min(rss),
            "rss_max_mb": max(v for _, v in rss),
            "fds_warm": int(fds[0]),
            "fds_end": int(fds[-1]),
            "fds_max": int(max(fds)),
        }
    return out
