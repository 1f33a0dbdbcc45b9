"""Zenoh over TLS with mutual authentication, on loopback, with the shipped example configs.

``configs/zenoh/router-tls.json5`` (router) and ``client-tls.json5`` (the service) are used
as shipped, with only the endpoint and certificate paths rewritten; the certificates are
made here with the openssl CLI (a CA, the router's certificate for localhost/127.0.0.1,
one client certificate for the service and one for a viewer). The service's sink
publishes, the viewer receives; a client without a certificate and a plain-TCP client are
refused.
"""

from __future__ import annotations

import json
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from glmav_observer.publish.zenoh_sink import open_zenoh_sink
from glmav_observer.records import VelocityRecord
from glmav_testkit.rel_helpers import wait_until

pytestmark = pytest.mark.timeout(90)

CONFIGS = Path(__file__).resolve().parents[3] / "configs" / "zenoh"


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


def make_certs(d: Path) -> None:
    """CA, router (SAN localhost, 127.0.0.1), service and viewer client certificates."""
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca-key.pem",
             "-out", "ca.pem", "-days", "2", "-subj", "/CN=glmav-test-ca", cwd=d)  # fmt: skip
    for name, ext in (
        ("router", "subjectAltName=DNS:localhost,IP:127.0.0.1"),
        ("service", "subjectAltName=DNS:glmav-service"),
        ("viewer", "subjectAltName=DNS:ground-viewer"),
    ):
        (d / f"{name}.ext").write_text(ext + "\n", encoding="ascii")
        _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}-key.pem",
                 "-out", f"{name}.csr", "-subj", f"/CN={name}", cwd=d)  # fmt: skip
        _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
                 "-CAcreateserial", "-out", f"{name}.pem", "-days", "2",
                 "-extfile", f"{name}.ext", cwd=d)  # fmt: skip


def _shipped(name: str, port: int, certs: Path, extra: dict[str, str]) -> str:
    text = (CONFIGS / name).read_text(encoding="utf-8")
    text = text.replace("tls/0.0.0.0:7447", f"tls/127.0.0.1:{port}")
    text = text.replace("tls/router.ground.lan:7447", f"tls/localhost:{port}")
    for shipped, ours in extra.items():
        text = text.replace(f'"configs/zenoh/certs/{shipped}"', json.dumps(str(certs / ours)))
    assert '"configs/zenoh/certs' not in text, "a certificate path was not rewritten"
    return text


def _client(port: int, certs: Path, tls: dict[str, Any]) -> Any:
    config = {
        "mode": "client",
        "connect": {"endpoints": [f"tls/localhost:{port}"], "timeout_ms": 3000},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": {"root_ca_certificate": str(certs / "ca.pem"), **tls}}},
    }
    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


def _velocity(step: int) -> VelocityRecord:
    return VelocityRecord(
        sysid=7,
        config="full",
        t_boot_s=0.01 * step,
        v_body_mps=(1.0, 0.0, 0.0),
        v_ned_mps=(1.0, 0.0, 0.0),
        lost_axis=None,
        health="ok",
        seq=step,
    )


def test_service_publishes_to_a_tls_router_and_only_certified_clients_connect(
    tmp_path: Path, free_tcp_port: Callable[[], int]
) -> None:
    make_certs(tmp_path)
    port = free_tcp_port()
    router_cfg = _shipped(
        "router-tls.json5",
        port,
        tmp_path,
        {"ca.pem": "ca.pem", "router.pem": "router.pem", "router-key.pem": "router-key.pem"},
    )
    client_path = tmp_path / "client-tls.json5"
    client_path.write_text(
        _shipped(
            "client-tls.json5",
            port,
            tmp_path,
            {
                "ca.pem": "ca.pem",
                "service.pem": "service.pem",
                "service-key.pem": "service-key.pem",
            },
        ),
        encoding="utf-8",
    )
    router = zenoh.open(zenoh.Config.from_json5(router_cfg))
    sink = None
    viewer = None
    try:
        sink = open_zenoh_sink(str(client_path), service_id="tls-svc", effective_config={})
        viewer = _client(
            port,
            tmp_path,
            {
                "connect_certificate": str(tmp_path / "viewer.pem"),
                "connect_private_key": str(tmp_path / "viewer-key.pem"),
                "enable_mtls": True,
            },
        )
        got: list[dict[str, Any]] = []
        viewer.declare_subscriber(
            "glmav/7/velocity/full", lambda s: got.append(json.loads(s.payload.to_bytes()))
        )
        step = [0]

        def published() -> bool:
            step[0] += 1
            sink.write(_velocity(step[0]))
            return bool(got)

        wait_until(published, 20.0, "a sample over TLS")
        assert got[0]["sysid"] == 7 and got[0]["v_ned_mps"] == [1.0, 0.0, 0.0]
        # both sessions are TLS transports to the router (the only endpoint it listens on)
        rc = zenoh.Config.from_json5(router_cfg)
        assert json.loads(rc.get_json("listen/endpoints")) == [f"tls/127.0.0.1:{port}"]

        # refused: a TLS client without a certificate (mTLS), and plain TCP
        t0 = time.monotonic()
        with pytest.raises(zenoh.ZError):
            _client(port, tmp_path, {})
        with pytest.raises(zenoh.ZError):
            zenoh.open(
                zenoh.Config.from_json5(
                    json.dumps(
                        {
                            "mode": "client",
                            "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"], "timeout_ms": 3000},
                            "scouting": {"multicast": {"enabled": False}},
                        }
                    )
                )
            )
        assert time.monotonic() - t0 < 30.0
    finally:
        if viewer is not None:
            viewer.close()
        if sink is not None:
            sink.close()
        router.close()
