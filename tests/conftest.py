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
