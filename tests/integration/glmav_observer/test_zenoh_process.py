"""Processes around the Zenoh sink: a router killed and restarted under a publishing sink,
the ``echo`` and ``router`` commands, bad configurations. Loopback only, real sessions.
(The daemon itself under SIGINT and a router restart: test_zenoh_serve.py.)"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from glmav_observer.publish.schema import ENCODINGS
from glmav_observer.publish.zenoh_sink import open_zenoh_sink
from glmav_testkit.zenoh_helpers import (
    RouterProcess,
    client_config,
    client_session,
    running_router,
    velocity,
    wait_until,
)

pytestmark = pytest.mark.timeout(90)

CLI = [sys.executable, "-m", "glmav_observer.cli"]


def test_router_killed_and_restarted_publishing_resumes(
    tmp_path: Path, free_tcp_port: Callable[[], int]
) -> None:
    router = RouterProcess(free_tcp_port())
    router.start()
    sink = open_zenoh_sink(
        str(client_config(tmp_path / "svc.json5", router.port)),
        service_id="restart-svc",
        effective_config={},
    )
    viewer = client_session(router.port)
    received: list[int] = []
    viewer.declare_subscriber(
        "glmav/1/velocity/active",
        lambda s: received.append(json.loads(s.payload.to_bytes())["seq"]),
    )
    written = [0]
    failures: list[BaseException] = []
    stop = threading.Event()

    def estimator() -> None:  # the daemon's loop, at ~500 Hz
        try:
            while not stop.is_set():
                sink.write(velocity(1, "active", written[0]))
                written[0] += 1
                time.sleep(0.002)
        except BaseException as exc:  # pragma: no cover - reported by the assert below
            failures.append(exc)

    thread = threading.Thread(target=estimator, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: len(received) > 20, 10)
        router.kill()
        killed_at = written[0]
        # the estimator goes on while the router is gone (writes don't block or raise)
        assert wait_until(lambda: written[0] > killed_at + 100, 5)
        router.start()  # same port
        restarted_at = written[0]
        # the client sessions reconnect by themselves; samples written after the restart
        # arrive (Zenoh's connect retry starts at 1 s and backs off: allow 20 s)
        assert wait_until(lambda: bool(received) and received[-1] > restarted_at, 20)
        replies = list(viewer.get("glmav/1/state", timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is not None
    finally:
        stop.set()
        thread.join(5)
        sink.close()
        viewer.close()
        router.stop()
    assert failures == []
    assert sink.errors == 0
    assert sink.published["active"] == written[0]


@pytest.mark.parametrize("encoding", list(ENCODINGS))
def test_echo_prints_json_lines_equal_to_the_records(
    tmp_path: Path, free_tcp_port: Callable[[], int], encoding: str
) -> None:
    """Whatever the wire encoding, echo decodes by the sample's encoding, validates, and
    prints the records' to_dict() + service_id."""
    with running_router(free_tcp_port()) as router:
        sink = open_zenoh_sink(
            str(client_config(tmp_path / "svc.json5", router.port)),
            service_id="echo-svc",
            effective_config={"x": 1},
            encoding=encoding,
        )
        endpoint = f"tcp/127.0.0.1:{router.port}"
        echo = subprocess.Popen(
            [
                *CLI,
                *("echo", "glmav/3/velocity/c2", "--connect", endpoint, "--format", "jsonl"),
                *("--count", "20", "--validate", "--duration", "30"),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            step = 0
            # publish until echo has its 20 samples and exits (it subscribes after start-up)
            while echo.poll() is None and step < 20000:
                sink.write(velocity(3, "c2", step))
                step += 1
                time.sleep(0.005)
            out, err = echo.communicate(timeout=20)
            query = subprocess.run(
                [
                    *CLI,
                    *("echo", "glmav/*/state", "--query", "--connect", endpoint),
                    *("--validate", "--format", "jsonl"),
                ],
                check=False,
                capture_output=True,
                text=True,
                timeout=30,
            )
        finally:
            if echo.poll() is None:
                echo.kill()
                echo.wait()
            sink.close()
    assert echo.returncode == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert len(lines) == 20
    for line in lines:
        assert line["key"] == "glmav/3/velocity/c2"
        assert line["encoding"] == ENCODINGS[encoding]
        want = {**velocity(3, "c2", line["value"]["seq"]).to_dict(), "service_id": "echo-svc"}
        assert line["value"] == want
    seqs = [line["value"]["seq"] for line in lines]
    assert seqs == list(range(seqs[0], seqs[0] + 20))  # consecutive: none lost, in order
    assert query.returncode == 0, query.stderr
    (state,) = [json.loads(line) for line in query.stdout.splitlines()]
    assert state["key"] == "glmav/3/state"
    assert state["value"]["velocity"]["c2"] == velocity(3, "c2", step - 1).to_dict()


def test_bad_zenoh_configs_exit_non_zero_naming_the_file(tmp_path: Path) -> None:
    bad_syntax = tmp_path / "broken.json5"
    bad_syntax.write_text('{ mode: "client", connect: { endpoints: [', encoding="utf-8")
    unknown_field = tmp_path / "typo.json5"
    unknown_field.write_text('{ mode: "router", listne: {} }', encoding="utf-8")
    peer = tmp_path / "peer.json5"
    peer.write_text('{ mode: "peer", scouting: { multicast: { enabled: false } } }', "utf-8")
    cases = [
        (["router", "--config", str(bad_syntax)], f"{bad_syntax}: "),
        (["router", "--config", str(unknown_field)], f"{unknown_field}: unknown field `listne`"),
        (["router", "--config", str(peer)], f"{peer}: mode is 'peer'"),
        (["echo", "--zenoh", str(tmp_path / "missing.json5")], "missing.json5: cannot read"),
        (["serve", "--zenoh", str(bad_syntax)], f"glmav-observer serve: {bad_syntax}: "),
        (["serve", "--zenoh", str(unknown_field)], f"{unknown_field}: unknown field `listne`"),
        (["echo", "glmav/**/", "--duration", "0.1"], "bad key expression"),
    ]
    # all at once: each is a fresh interpreter importing the CLI (~1 s)
    procs = [
        subprocess.Popen([*CLI, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for argv, _ in cases
    ]
    for proc, (argv, message) in zip(procs, cases, strict=True):
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 2, (argv, stderr)
        assert message in stderr, (argv, stderr)
        assert "Traceback" not in stderr
