"""Issue 31 D2 against the real ``serve --claim``, in the default worker mode and with one
worker: liveliness tokens ``glmav/@claim/{1..255}/0`` from a session that is not a member
(it holds no members token) stopped every record (31,150 messages, 0 records, no
warning). The in-process form is ``test_fleet_claims.py::
test_claims_of_a_non_member_flood_are_ignored_with_one_warning``; here the flood is on
the Zenoh router before ``serve`` starts, and 4 vehicles fly over UDP."""

from __future__ import annotations

import json
import subprocess
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from glmav_observer.fleet.claims import claim_key
from glmav_testkit.fleet_helpers import SITL, record_tlog, wait_drained
from glmav_testkit.serve_process import ServeProcess
from glmav_testkit.zenoh_helpers import RouterProcess, client_config, client_session

VEHICLES = 4
FLIGHT_S = 6.0


@pytest.fixture
def router(free_tcp_port: Callable[[], int]) -> Iterator[RouterProcess]:
    router = RouterProcess(free_tcp_port())
    router.start()
    yield router
    router.stop()


def _full_records(path: Path) -> Counter[int]:
    n: Counter[int] = Counter()
    with path.open(encoding="utf-8") as f:
        for line in f:
            r = json.loads(line)
            if r.get("schema") == "glmav.velocity/1" and r.get("config") == "full":
                n[r["sysid"]] += 1
    return n


@pytest.mark.timeout(180)
@pytest.mark.parametrize("workers", [None, 1], ids=["default-workers", "one-worker"])
def test_a_non_member_claim_flood_does_not_stop_serve_claim(
    workers: int | None,
    router: RouterProcess,
    tmp_path: Path,
    free_udp_port: Callable[[], int],
) -> None:
    tlog = record_tlog(tmp_path, FLIGHT_S)
    rogue = client_session(router.port)
    tokens = [rogue.liveliness().declare_token(claim_key("glmav", s, "0")) for s in range(1, 256)]
    zcfg = client_config(tmp_path / "client.json5", router.port)
    port = free_udp_port()
    out = tmp_path / "claim.jsonl"
    sp = ServeProcess(port, workers, tmp_path, out=out, zenoh=True,
                      extra=["--claim", "--zenoh", str(zcfg), "--service-id", f"claim-{port}"])  # fmt: skip
    try:
        sp.wait_ready()
        subprocess.run(
            [SITL, "fleet", "--tlog", str(tlog), "--vehicles", str(VEHICLES),
             "--link", f"udpout:127.0.0.1:{port}", "--stagger", "0.5"],
            check=True, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert wait_drained(port) == 0
    finally:
        stopped = sp.stop()
        for t in tokens:
            t.undeclare()
        rogue.close()
    assert stopped.returncode == 0, stopped.stderr[-3000:]
    assert stopped.summary.present
    if workers is None:
        assert len(stopped.summary.workers) == sp.workers > 1
    # one warning per claim manager (one per worker), naming the non-member
    warned = [ln for ln in stopped.stderr.splitlines() if "not a member" in ln]
    assert 1 <= len(warned) <= sp.workers, warned
    assert all("claims by 0 ignored" in ln for ln in warned), warned
    # every vehicle is claimed and estimated: the service claims ~1.5 s into the flight,
    # so at least 3 s of the 6 s remain (250 Hz IMU: 750 records of `full`; before: 0)
    full = _full_records(out)
    assert sorted(full) == list(range(1, VEHICLES + 1)), full
    assert min(full.values()) >= 250 * 3.0, full
