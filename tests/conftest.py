"""Shared test fixtures: loopback ports and the path to ../shared."""

from __future__ import annotations

import socket
from collections.abc import Callable
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED = REPO_ROOT.parent / "shared"


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


@pytest.fixture(scope="session")
def real_tlogs() -> Path:
    """``../shared/data/real-tlogs`` (ArduSub logs recorded by others)."""
    path = SHARED / "data" / "real-tlogs"
    if not path.is_dir():
        raise FileNotFoundError(f"{path} missing: CI must place ../shared beside the repo")
    return path


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
