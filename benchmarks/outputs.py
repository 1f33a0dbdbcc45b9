"""The service's default outputs for the benchmarks, opened by the product's own code.

"Default outputs" are what ``glmav-observer serve`` opens with the configuration's
defaults and Zenoh on (the container's and compose's way of running it):
:func:`glmav_observer.app_sinks.open_sinks` with ``zenoh_enabled=True``, i.e. today a
:class:`~glmav_observer.publish.zenoh_sink.ZenohSink` on the embedded loopback peer (no
router needed). Nothing here names a rate, a decimation or a record kind: whatever the
product's defaults publish, the benchmarks measure.

- :func:`default_output_sinks`: the sinks, for a Service built in this process;
- :func:`default_outputs`: a context manager over them (closed on exit), optionally with
  one real subscriber on ``<prefix>/**`` in a subprocess (its CPU is not this process's),
  connected to the sinks' sessions so that the publishers have a consumer;
- :func:`subscriber_for`: the same subscriber for sessions opened by other processes
  (``serve --workers N``'s workers open their own sinks: see bench_fleet);
- :func:`unique_service_id`: one id per run and mode, so that the liveliness check of a
  sink (``@alive/<service-id>``) never meets another run's or another agent's sink.

    python -m benchmarks.outputs subscribe --prefix glmav tcp/127.0.0.1:PORT ...

is the subscriber (it prints ``ready`` once connected, then its counts as JSON when its
standard input closes).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from glmav_observer.app_sinks import open_sinks
from glmav_observer.config import ServiceConfig
from glmav_observer.publish.sink import Sink

ROOT = Path(__file__).resolve().parents[1]
#: how long the subscriber waits for its sessions to connect and its interest to reach them
SUBSCRIBER_START_TIMEOUT_S = 20.0
#: after the subscriber sees its peers: its subscription reaching their publishers (s)
SUBSCRIPTION_SETTLE_S = 0.5


def unique_service_id(tag: str) -> str:
    """A service id no other run shares (one plain key chunk)."""
    clean = "".join(ch if ch.isalnum() else "-" for ch in tag).strip("-") or "run"
    return f"bench-{clean}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def with_unique_id(config: ServiceConfig, tag: str) -> ServiceConfig:
    """``config`` with a service id of its own (:func:`unique_service_id`)."""
    return replace(config, service_id=unique_service_id(tag))


def default_output_sinks(config: ServiceConfig) -> list[Sink]:
    """The sinks ``serve`` opens for ``config`` with Zenoh on (closed by the caller)."""
    return open_sinks(config, zenoh_enabled=True)


def _listening_tcp(pids: Sequence[int]) -> set[str]:
    """The loopback TCP endpoints the processes ``pids`` listen on (``tcp/IP:PORT``)."""
    import psutil

    found = set()
    for pid in pids:
        for c in psutil.Process(pid).net_connections(kind="tcp"):
            if c.status == psutil.CONN_LISTEN and c.laddr and c.laddr.ip.startswith("127."):
                found.add(f"tcp/{c.laddr.ip}:{c.laddr.port}")
    return found


@dataclass
class Subscriber:
    """A subscriber subprocess on ``<prefix>/**`` connected to ``endpoints``."""

    endpoints: list[str]
    prefix: str
    proc: subprocess.Popen[str] | None = None
    #: the counts it printed at stop: samples, bytes, per kind, its CPU time
    result: dict[str, Any] = field(default_factory=dict)

    def start(self) -> None:
        if not self.endpoints:
            raise RuntimeError("no Zenoh session to subscribe to (no listening endpoint)")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.outputs", "subscribe", "--prefix", self.prefix,
             "--peers", str(len(self.endpoints)), *sorted(self.endpoints)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT,
        )  # fmt: skip
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline().strip()
        if line != "ready":
            self.stop()
            raise RuntimeError(f"the subscriber did not start: {line!r}")

    def stop(self) -> dict[str, Any]:
        if self.proc is None:
            return self.result
        proc, self.proc = self.proc, None
        try:
            out, _ = proc.communicate(input="", timeout=30.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        lines = [ln for ln in out.splitlines() if ln.startswith("{")]
        self.result = json.loads(lines[-1]) if lines else {"error": out[-300:]}
        return self.result


def subscriber_for(pids: Sequence[int], config: ServiceConfig) -> Subscriber:
    """A started subscriber connected to every Zenoh session the processes ``pids`` opened
    (call it once their sinks are open and before anything else there listens)."""
    sub = Subscriber(sorted(_listening_tcp(pids)), config.zenoh.prefix)
    sub.start()
    return sub


@dataclass
class Outputs:
    """The sinks :func:`default_outputs` opened, and its subscriber (None without)."""

    sinks: list[Sink]
    subscriber: Subscriber | None
    stats: dict[str, Any] = field(default_factory=dict)
    #: set when a Service was given the sinks and closes them (``Service.close``, as
    #: ``serve`` does): then they are not closed a second time here
    closed_by_service: bool = False


@contextlib.contextmanager
def default_outputs(config: ServiceConfig, *, subscriber: bool = False) -> Iterator[Outputs]:
    """The default output sinks of ``config`` (:func:`default_output_sinks`), closed on
    exit; ``subscriber``: with one real subscriber connected to their session(s). On exit,
    :attr:`Outputs.stats` holds the sinks' own statistics and the subscriber's counts."""
    before = _listening_tcp([os.getpid()]) if subscriber else set()
    sinks = default_output_sinks(config)
    sub: Subscriber | None = None
    out = Outputs(sinks, None)
    try:
        if subscriber:
            sub = Subscriber(sorted(_listening_tcp([os.getpid()]) - before), config.zenoh.prefix)
            sub.start()
            out.subscriber = sub
        yield out
    finally:
        if sub is not None:
            out.stats["subscriber"] = sub.stop()
        for s in sinks:
            if not out.closed_by_service:
                s.close()
            stats = getattr(s, "stats", None)
            if callable(stats):
                out.stats[type(s).__name__] = stats()


def sinks_summary(sinks: Sequence[Sink]) -> list[str]:
    """The sinks' class names (what "default outputs" was in this run)."""
    return [type(s).__name__ for s in sinks]


# ---------------------------------------------------------------------- the subscriber
def _subscribe(prefix: str, endpoints: list[str], peers: int) -> int:
    import zenoh

    conf = zenoh.Config.from_json5(
        json.dumps(
            {
                "mode": "peer",
                "listen": {"endpoints": ["tcp/127.0.0.1:0"]},
                "connect": {"endpoints": endpoints},
                "scouting": {"multicast": {"enabled": False}},
            }
        )
    )
    counts: Counter[str] = Counter()
    lock = threading.Lock()
    nbytes = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        kind = parts[2] if len(parts) > 2 else "?"
        size = len(sample.payload.to_bytes())
        with lock:
            counts[kind] += 1
            nbytes[0] += size

    session = zenoh.open(conf)
    sub = session.declare_subscriber(f"{prefix}/**", on_sample)
    deadline = time.monotonic() + SUBSCRIBER_START_TIMEOUT_S
    while len(list(session.info.peers_zid())) < peers and time.monotonic() < deadline:
        time.sleep(0.05)
    connected = len(list(session.info.peers_zid()))
    time.sleep(SUBSCRIPTION_SETTLE_S)
    print("ready" if connected >= peers else f"connected to {connected} of {peers}", flush=True)
    sys.stdin.read()  # until the parent closes it
    cpu_s = time.process_time()
    sub.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]
    with lock:
        result = {"samples": sum(counts.values()), "bytes": nbytes[0],
                  "by_kind": dict(sorted(counts.items())), "cpu_s": cpu_s}  # fmt: skip
    print(json.dumps(result), flush=True)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("subscribe", help="count samples on PREFIX/** from these sessions")
    p.add_argument("--prefix", default="glmav")
    p.add_argument("--peers", type=int, default=1, help="sessions to wait for")
    p.add_argument("endpoints", nargs="+", help="tcp/127.0.0.1:PORT of each session")
    args = parser.parse_args(argv)
    return _subscribe(args.prefix, args.endpoints, args.peers)


if __name__ == "__main__":
    sys.exit(main())
