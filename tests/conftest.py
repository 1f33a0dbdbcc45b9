"""Shared test fixtures: loopback ports, the logs in tests/data, and the lock that lets a
test marked ``exclusive`` run alone among the suite's workers (pytest-xdist)."""

from __future__ import annotations

import fcntl
import os
import random
import socket
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    """A readers-writer lock over the suite's workers (``-n 2`` in pyproject's addopts).

    Every test holds ``suite.lock`` shared; a test marked ``exclusive`` (it measures what
    the machine can hold in real time: drops, latency, failover timing, a flight flown
    at its real rate) holds it alone, so the other worker does not run a test beside it:
    those tests get both cores, as they did before the suite ran on two workers. A waiting
    exclusive test holds ``turnstile.lock``, which every test passes through first, so
    the other worker cannot keep it waiting.

    Taken around the whole test protocol, outside pytest-timeout's own wrapper (this one
    is ``tryfirst``): the wait for the other worker's exclusive test (the soak: minutes)
    is not counted against a test's timeout. The files are in a directory of this run,
    which its workers share (``PYTEST_XDIST_TESTRUNUID``; one process without xdist has
    its own: no one waits)."""
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID") or f"pid{os.getpid()}"
    run_dir = Path(tempfile.gettempdir()) / f"glmav-pytest-{run_id}"
    run_dir.mkdir(exist_ok=True)
    exclusive = item.get_closest_marker("exclusive") is not None
    with (run_dir / "turnstile.lock").open("a") as gate, (run_dir / "suite.lock").open("a") as lock:
        fcntl.flock(gate, fcntl.LOCK_EX)
        if exclusive:
            fcntl.flock(lock, fcntl.LOCK_EX)  # waits for the other worker's test to end
            fcntl.flock(gate, fcntl.LOCK_UN)
        else:
            fcntl.flock(gate, fcntl.LOCK_UN)
            fcntl.flock(lock, fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _ephemeral_low() -> int:
    """The first port the kernel hands out for bind(0) and connect (32768 by default)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


_PORT_RNG = random.Random()


def _free_port(kind: int) -> int:
    """A port that is free now, chosen at random **below the ephemeral range**: a port the
    kernel picked for bind(0) is handed to the next process that binds or connects without
    a port (a Zenoh session, a client socket), and on a busy machine one took a test's
    service port between this check and the service's bind (exit 2, "already taken")."""
    high = _ephemeral_low()
    low = max(10_000, high - 12_000)
    for _ in range(200):
        port = _PORT_RNG.randrange(low, high)
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    with socket.socket(socket.AF_INET, kind) as s:  # (a crowded range: the kernel's pick)
        s.bind(("127.0.0.1", 0))
        chosen: int = s.getsockname()[1]
        return chosen


@pytest.fixture
def free_udp_port() -> Callable[[], int]:
    """A function returning a currently free UDP port on 127.0.0.1."""
    return lambda: _free_port(socket.SOCK_DGRAM)


@pytest.fixture
def free_tcp_port() -> Callable[[], int]:
    """A function returning a currently free TCP port on 127.0.0.1."""
    return lambda: _free_port(socket.SOCK_STREAM)


REAL_TLOGS = REPO_ROOT / "tests" / "data" / "real-tlogs"


@pytest.fixture(scope="session")
def real_tlogs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Real ArduSub logs recorded by others (tests/data/real-tlogs, xz-compressed whole:
    the tests count every frame), unpacked once per session."""
    import lzma

    out = tmp_path_factory.mktemp("real-tlogs")
    for xz in sorted(REAL_TLOGS.glob("*.tlog.xz")):
        (out / xz.name.removesuffix(".xz")).write_bytes(lzma.decompress(xz.read_bytes()))
    return out


PUBLIC_LOGS = REPO_ROOT / "tests" / "data" / "public-logs"


@pytest.fixture(scope="session")
def public_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The trimmed public flight logs (tests/data/public-logs/README.md), decompressed once:
    ``{"dataflash": ....BIN, "ulog": ....ulg}``."""
    import gzip

    out = tmp_path_factory.mktemp("public-logs")
    paths = {}
    for key, name in (
        ("dataflash", "arducopter_sitl_trimmed.BIN"),
        ("ulog", "px4_sitl_trimmed.ulg"),
    ):
        dst = out / name
        dst.write_bytes(gzip.decompress((PUBLIC_LOGS / f"{name}.gz").read_bytes()))
        paths[key] = dst
    return paths
