"""Helpers of the reliability tests: the service and the simulator on loopback, in threads."""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.links import Link
from glmav_observer.publish.sink import Sink
from glmav_observer.records import Record, VelocityRecord
from glmav_sitl.runner import RunSummary, run


def wait_until(pred: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Poll ``pred`` until true or raise (no fixed sleeps)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return
        time.sleep(0.01)
    raise TimeoutError(f"{what}: not within {timeout_s} s")


@dataclass
class LiveService:
    """A :class:`Service` serving one link in a thread; records collected as they come."""

    service: Service
    link: Link
    thread: threading.Thread
    stop: threading.Event
    records: list[Record] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def velocity(self, sysid: int = 1, config: str = "active") -> list[VelocityRecord]:
        with self.lock:
            return [
                r
                for r in self.records
                if isinstance(r, VelocityRecord) and r.sysid == sysid and r.config == config
            ]


@contextmanager
def live_service(
    conn: str,
    *,
    config: ServiceConfig | None = None,
    sinks: Sequence[Sink] = (),
    signing_key: bytes | None = None,
) -> Iterator[LiveService]:
    cfg = config or ServiceConfig(request_rates=False)
    if signing_key is not None:
        cfg = dataclasses.replace(cfg, signing_key=signing_key)
    svc = Service(cfg, sinks)
    link = Link(conn)
    stop = threading.Event()
    live = LiveService(svc, link, threading.Thread(target=lambda: None), stop)

    def on_records(recs: list[Record]) -> None:
        with live.lock:
            live.records.extend(recs)

    svc.on_records = on_records
    live.thread = threading.Thread(
        target=svc.run, args=({conn: link}, stop), name="service", daemon=True
    )
    live.thread.start()
    try:
        yield live
    finally:
        stop.set()
        live.thread.join(10.0)
        link.close()
        svc.close()


@contextmanager
def sitl_thread(
    scenario: str, links: Sequence[Any], finish_timeout_s: float = 60.0, **kw: Any
) -> Iterator[tuple[threading.Event, list[RunSummary]]]:
    """Run the simulator in a thread; yields (stop event, [summary once done]).

    Leaving the block normally waits for the flight to end (set the event to cut it
    short); an exception stops it at once."""
    stop = threading.Event()
    started = threading.Event()
    out: list[RunSummary] = []
    err: list[BaseException] = []

    def target() -> None:
        try:
            out.append(run(scenario, links, stop_event=stop, started=started, **kw))
        except BaseException as e:  # surfaced to the test below
            err.append(e)

    t = threading.Thread(target=target, name="sitl", daemon=True)
    t.start()
    try:
        wait_until(lambda: started.is_set() or bool(err), 10.0, "simulator start")
        yield stop, out
        t.join(finish_timeout_s)  # on a normal exit, let the scenario fly to its end
    finally:
        stop.set()
        t.join(30.0)
    if err:
        raise err[0]


def udp_drops(port: int) -> int:
    """Datagrams the kernel dropped for the UDP socket bound to 127.0.0.1:``port``
    (receive buffer full), from ``/proc/net/udp`` (last column)."""
    want = f"0100007F:{port:04X}"
    with open("/proc/net/udp", encoding="ascii") as f:
        for line in f.readlines()[1:]:
            cols = line.split()
            if cols[1] == want:
                return int(cols[-1])
    raise LookupError(f"no UDP socket on 127.0.0.1:{port}")


def rms(xs: Sequence[float]) -> float:
    return math.sqrt(sum(x * x for x in xs) / len(xs)) if xs else math.nan
