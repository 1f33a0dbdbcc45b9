"""A loopback fault proxy for UDP MAVLink: drops, reorders, duplicates and delays datagrams.

    vehicle --udpout--> [proxy listen port] --faults--> target (the service's udpin port)
    vehicle <---------- [proxy listen port] <---------- target (replies, no faults)

Faults apply to the vehicle-to-target direction, per datagram, seeded (reproducible):

- ``drop``: probability of losing a datagram (radio loss);
- ``duplicate``: probability of sending it twice (the copy ``dup_delay_s`` later);
- ``reorder``: probability of holding it back ``reorder_delay_s`` (netem's model: it
  arrives after the datagrams sent just after it);
- ``delay_s`` and ``jitter_s``: latency added to every datagram (uniform jitter; order
  kept unless jitter exceeds the spacing of datagrams, which reorders them too);
- :meth:`UdpFaultProxy.blackout`: lose everything for a while (a link outage).

Used by the reliability tests and the ``faults_accuracy`` benchmark, and by people via
``scripts/faultproxy.py``. Standard library only.
"""

from __future__ import annotations

import collections
import heapq
import math
import random
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class FaultSpec:
    """What the proxy does to each datagram (probabilities in [0, 1], times in s)."""

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    reorder_delay_s: float = 0.02
    dup_delay_s: float = 0.001
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "reorder"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], got {p}")
        for name in ("delay_s", "jitter_s", "reorder_delay_s", "dup_delay_s"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name} must be >= 0")

    def label(self) -> str:
        parts = []
        if self.drop:
            parts.append(f"drop {self.drop:.0%}")
        if self.reorder:
            parts.append(f"reorder {self.reorder:.0%}")
        if self.duplicate:
            parts.append(f"dup {self.duplicate:.0%}")
        if self.delay_s or self.jitter_s:
            parts.append(f"delay {self.delay_s * 1e3:.0f}±{self.jitter_s * 1e3:.0f} ms")
        return ", ".join(parts) or "none"


class UdpFaultProxy:
    """Forwards UDP datagrams from ``listen`` to ``target`` with faults, in a thread."""

    def __init__(
        self,
        target: tuple[str, int],
        spec: FaultSpec,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        tap: Callable[[bytes], None] | None = None,
    ) -> None:
        self.spec = spec
        #: called with each datagram forwarded to ``target``, in the order sent (this thread)
        self.tap = tap
        self.target = target
        self.rng = random.Random(spec.seed)
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # room for bursts while this thread waits for a CPU on a loaded machine: the
        # faults are the spec's, not the kernel's (capped by net.core.rmem_max)
        self.front.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.front.bind(listen)
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.front.setblocking(False)
        self.back.setblocking(False)
        self.port: int = self.front.getsockname()[1]
        self.counters: collections.Counter[str] = collections.Counter()
        self._client: tuple[str, int] | None = None
        self._queue: list[tuple[float, int, bytes]] = []
        self._seq = 0
        self._blackout_until = 0.0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._loop, name="faultproxy", daemon=True)

    def __enter__(self) -> UdpFaultProxy:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        self.front.close()
        self.back.close()

    def blackout(self, duration_s: float) -> None:
        """Lose every datagram for the next ``duration_s`` seconds (counted ``blackout``)."""
        with self._lock:
            self._blackout_until = time.monotonic() + duration_s

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counters)

    def pending(self) -> int:
        """Datagrams scheduled and not yet forwarded (held by the delay, jitter or reorder),
        from the counters (a datagram leaves the count once its ``forwarded`` is counted)."""
        with self._lock:
            c = self.counters
            scheduled = c["received"] - c["dropped"] - c["blackout"] + c["duplicated"]
            return scheduled - c["forwarded"] - c["send_errors"]

    # ------------------------------------------------------------------ internals
    def _schedule(self, t: float, data: bytes) -> None:
        self._seq += 1
        heapq.heappush(self._queue, (t, self._seq, data))

    def _on_datagram(self, data: bytes, now: float) -> None:
        s, r = self.spec, self.rng
        c = self.counters
        c["received"] += 1
        if now < self._blackout_until:
            c["blackout"] += 1
            return
        if r.random() < s.drop:
            c["dropped"] += 1
            return
        t = now + s.delay_s + (r.uniform(0.0, s.jitter_s) if s.jitter_s else 0.0)
        if s.reorder and r.random() < s.reorder:
            c["reordered"] += 1
            t += s.reorder_delay_s
        self._schedule(t, data)
        if s.duplicate and r.random() < s.duplicate:
            c["duplicated"] += 1
            self._schedule(t + s.dup_delay_s, data)

    def _loop(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            while self._queue and self._queue[0][0] <= now:
                _, _, data = heapq.heappop(self._queue)
                with self._lock:  # counted first: a reader never sees more arrive than sent
                    self.counters["forwarded"] += 1
                try:
                    self.back.sendto(data, self.target)
                except OSError:
                    with self._lock:
                        self.counters["forwarded"] -= 1
                        self.counters["send_errors"] += 1
                else:
                    if self.tap is not None:
                        self.tap(data)
            timeout = 0.05
            if self._queue:
                timeout = max(0.0, min(timeout, self._queue[0][0] - now))
            try:
                ready, _, _ = select.select([self.front, self.back], [], [], timeout)
            except (OSError, ValueError):
                return
            for sock in ready:
                while True:
                    try:
                        data, addr = sock.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        break  # ICMP unreachable from an earlier send: the peer is not up
                    if sock is self.front:
                        self._client = addr
                        with self._lock:
                            self._on_datagram(data, time.monotonic())
                    elif self._client is not None:  # replies go back unharmed
                        try:
                            self.front.sendto(data, self._client)
                            with self._lock:
                                self.counters["replies"] += 1
                        except OSError:
                            pass


class VehicleTimeDisorder:
    """What a link delivered, measured in vehicle time: feed it each forwarded datagram
    (:attr:`UdpFaultProxy.tap`) and it decodes the timed samples (``time_boot_ms`` /
    ``time_usec``) and keeps, per sample, how far behind the newest vehicle time seen so
    far it arrived (its *disorder*).

    A reorder window of W s can put back in order only samples whose disorder is at most W:
    the ingest releases what is older than newest - W. On an idle machine the disorder of
    a jittered link is the jitter (the sender paces in real time); on a busy one the
    sender stalls and then sends a burst whose vehicle times span the stall, and the
    jitter reorders the burst across that span. This measures the run's own figure, so
    a test can judge the window against what its link really did.
    """

    def __init__(self) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        self._mav = mavlink2.MAVLink(None)
        self._mav.robust_parsing = True
        self._newest_s = -math.inf
        self.samples = 0
        self.behind = 0  # samples that arrived behind a newer one (the link reordered them)
        self.disorder_s: list[float] = []

    def feed(self, data: bytes) -> None:
        for msg in self._mav.parse_buffer(data) or ():
            t_ms = getattr(msg, "time_boot_ms", None)
            t_us = getattr(msg, "time_usec", None)
            if t_ms is not None:
                t_s = t_ms * 1e-3
            elif t_us is not None:
                t_s = t_us * 1e-6
            else:
                continue
            self.samples += 1
            lag_s = self._newest_s - t_s
            if lag_s > 0.0:
                self.behind += 1
                self.disorder_s.append(lag_s)
            self._newest_s = max(self._newest_s, t_s)

    def beyond(self, window_s: float) -> int:
        """Samples no window of ``window_s`` could put back in order."""
        return sum(1 for d in self.disorder_s if d > window_s)
