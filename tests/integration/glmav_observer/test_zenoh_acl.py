"""configs/zenoh/acl-router.json5 as shipped (endpoint and dictionary path rewritten to this
test's loopback port and the repository path): only the service may publish under glmav/."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from glmav_observer.publish.zenoh_config import ZenohConfigError
from glmav_observer.publish.zenoh_sink import open_zenoh_sink
from glmav_testkit.zenoh_helpers import client_config, client_session, velocity, wait_until

pytestmark = pytest.mark.timeout(60)

CONFIGS = Path(__file__).resolve().parents[3] / "configs" / "zenoh"


def _credentials() -> dict[str, str]:
    text = (CONFIGS / "credentials.example.txt").read_text(encoding="utf-8")
    return dict(line.split(":", 1) for line in text.splitlines() if line.strip())


def _login(user: str, password: str) -> dict[str, Any]:
    return {"transport": {"auth": {"usrpwd": {"user": user, "password": password}}}}


def test_only_the_service_publishes_everyone_logged_in_reads(
    tmp_path: Path, free_tcp_port: Callable[[], int]
) -> None:
    port = free_tcp_port()
    text = (CONFIGS / "acl-router.json5").read_text(encoding="utf-8")
    text = text.replace("tcp/0.0.0.0:7447", f"tcp/127.0.0.1:{port}")
    text = text.replace(
        '"configs/zenoh/credentials.example.txt"',
        json.dumps(str(CONFIGS / "credentials.example.txt")),
    )
    router = zenoh.open(zenoh.Config.from_json5(text))
    creds = _credentials()
    service_login = _login("glmav-service", creds["glmav-service"])
    sink = open_zenoh_sink(
        str(client_config(tmp_path / "svc.json5", port, **service_login)),
        service_id="acl-svc",
        effective_config={},
    )
    viewer = client_session(port, **_login("ground-viewer", creds["ground-viewer"]))
    rogue = client_session(port, **_login("ground-viewer", creds["ground-viewer"]))
    try:
        got: list[tuple[str, int]] = []
        viewer.declare_subscriber(
            "glmav/**",
            lambda s: got.append((str(s.key_expr), json.loads(s.payload.to_bytes())["sysid"])),
        )
        step = [0]

        def publish_both() -> bool:
            sink.write(velocity(1, "full", step[0]))
            # a logged-in reader trying to publish a fake estimate
            rogue.put("glmav/1/velocity/full", json.dumps({"sysid": 66}))
            step[0] += 1
            return len(got) >= 20

        assert wait_until(publish_both, 10)
        assert {key for key, _ in got} == {"glmav/1/velocity/full"}
        # the service's estimates pass, the reader's put is denied at the router's ingress
        assert {sysid for _, sysid in got} == {1}
        replies = list(viewer.get("glmav/*/state", timeout=5.0))
        assert [str(r.ok.key_expr) for r in replies if r.ok is not None] == ["glmav/1/state"]
        alive = [str(r.ok.key_expr) for r in viewer.liveliness().get("glmav/@alive/**", timeout=5)]
        assert sorted(alive) == ["glmav/@alive/acl-svc", "glmav/@alive/acl-svc/1"]
        # no login, or a wrong password: the router refuses the session
        for extra in ({}, _login("ground-viewer", "wrong")):
            with pytest.raises(ZenohConfigError, match="cannot open the Zenoh session"):
                open_zenoh_sink(
                    str(client_config(tmp_path / "anon.json5", port, **extra)),
                    service_id="anon",
                    effective_config={},
                )
    finally:
        sink.close()
        viewer.close()
        rogue.close()
        router.close()


def test_only_members_claim_and_answer_states_through_the_acl_router(
    free_tcp_port: Callable[[], int],
) -> None:
    """Issue 31 D1/D2 on the network: a logged-in reader (not the service's user) tries
    to claim vehicle 1, to join the members and to answer ``glmav/1/state`` with a false
    state; the router drops all three, while a second service's claim passes."""
    from glmav_observer.fleet.claims import ClaimManager, claim_key, members_key

    port = free_tcp_port()
    text = (CONFIGS / "acl-router.json5").read_text(encoding="utf-8")
    text = text.replace("tcp/0.0.0.0:7447", f"tcp/127.0.0.1:{port}")
    text = text.replace(
        '"configs/zenoh/credentials.example.txt"',
        json.dumps(str(CONFIGS / "credentials.example.txt")),
    )
    router = zenoh.open(zenoh.Config.from_json5(text))
    creds = _credentials()
    service = client_session(port, **_login("glmav-service", creds["glmav-service"]))
    friend = client_session(port, **_login("glmav-service", creds["glmav-service"]))
    rogue = client_session(port, **_login("ground-viewer", creds["ground-viewer"]))
    queried: list[str] = []
    false_state = {
        "schema": "glmav.state/1",
        "sysid": 1,
        "velocity": {"active": {"t_boot_s": 10.0, "v_ned_mps": [40.0, -40.0, 15.0]}},
        "health": None,
    }

    def answer(q: zenoh.Query) -> None:
        queried.append(str(q.key_expr))
        q.reply("glmav/1/state", json.dumps(false_state))

    entities = [
        rogue.liveliness().declare_token(members_key("glmav", "rogue")),
        rogue.liveliness().declare_token(claim_key("glmav", 1, "rogue")),
        rogue.declare_queryable("glmav/1/state", answer),
        friend.liveliness().declare_token(members_key("glmav", "friend")),
        friend.liveliness().declare_token(claim_key("glmav", 2, "friend")),
    ]
    manager = ClaimManager(service, "glmav", period_s=3600.0)  # turns run by hand
    try:
        # the service's own claims pass the router: the friend's claim arrives
        assert wait_until(lambda: manager.claimants(2) == {"friend"}, 10)
        manager.saw(1)
        manager._query_states(set())
        # the state query's timeout is 2 s: its replies (none may come) are in by then
        assert wait_until(lambda: manager.state_replies > 0, 3.0) is False
        assert manager.claimants(1) == set()
        assert "rogue" not in manager._members and "friend" in manager._members
        assert queried == []  # the router never forwards a query to a reader's queryable
        assert manager.take_seed(1) is None
    finally:
        manager.close()
        for e in entities:
            e.undeclare()
        for s in (service, friend, rogue):
            s.close()
        router.close()
