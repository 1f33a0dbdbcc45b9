"""Shared test fixtures: loopback ports and the logs in tests/data."""

from __future__ import annotations

import socket
from collections.abc import Callable
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


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
