"""The benchmarks' default outputs (``benchmarks.outputs``) are the product's own: the sinks
``open_sinks`` opens with Zenoh on, with a subscriber in another process that receives
what they publish; a service id per run, so that two runs never collide."""

from __future__ import annotations

import time

from benchmarks.outputs import default_outputs, unique_service_id, with_unique_id

from glmav_observer.app import Service
from glmav_observer.app_sinks import open_sinks
from glmav_observer.config import ServiceConfig
from glmav_observer.records import VelocityRecord


def _record(i: int) -> VelocityRecord:
    return VelocityRecord(
        sysid=1, config="full", t_boot_s=0.004 * i, v_body_mps=(1.0, 0.0, 0.0),
        v_ned_mps=(1.0, 0.0, 0.0), lost_axis=None, health="ok", seq=i, source_config=None,
    )  # fmt: skip


def test_the_sinks_are_serves_and_the_subscriber_receives() -> None:
    config = with_unique_id(ServiceConfig(), "test")
    product = open_sinks(with_unique_id(ServiceConfig(), "test-product"), zenoh_enabled=True)
    try:
        expected = [type(s).__name__ for s in product]
    finally:
        for s in product:
            s.close()
    with default_outputs(config, subscriber=True) as out:
        assert [type(s).__name__ for s in out.sinks] == expected
        for i in range(200):
            for s in out.sinks:
                s.write(_record(i))
        time.sleep(0.5)
    assert out.stats["subscriber"]["samples"] == 200
    assert out.stats["ZenohSink"]["published"]["velocity"] == 200


def test_closed_by_the_service_once() -> None:
    with default_outputs(with_unique_id(ServiceConfig(), "test-svc")) as out:
        out.closed_by_service = True
        Service(ServiceConfig(), out.sinks).close()
    assert "ZenohSink" in out.stats


def test_service_ids_differ() -> None:
    assert unique_service_id("a") != unique_service_id("a")
