"""One flight through the fault proxy: simulator -> proxy -> service, all on loopback.

The simulator (in-process runner, in a thread) sends to the proxy, which forwards with
faults to the service (``Service.run`` on ``udpin:127.0.0.1:PORT`` in a thread). The
accuracy is the service's own RMSE of each estimate against the simulator's SIM_STATE
truth (which goes through the same proxy: lost truth samples only thin the statistics).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.ingest.links import Link
from glmav_observer.records import Record, VelocityRecord
from glmav_sitl.runner import run
from glmav_testkit.faultproxy import FaultSpec, UdpFaultProxy


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@dataclass
class FaultRun:
    spec: FaultSpec
    proxy: dict[str, int]
    frames: dict[str, int]
    vehicle: dict[str, int]
    rmse_active_mps: tuple[float, float, float] | None
    rmse_full_mps: tuple[float, float, float] | None
    truth_samples: int
    velocity_records: int
    t_records_s: list[float] = field(default_factory=list)
    sent: int = 0
    wall_s: float = 0.0

    def row(self) -> dict[str, Any]:
        r = self.rmse_active_mps or (float("nan"),) * 3
        return {
            "faults": self.spec.label(),
            "rmse_n_mps": r[0],
            "rmse_e_mps": r[1],
            "rmse_d_mps": r[2],
            "delivered_%": 100.0 * self.frames.get("frames_ok", 0) / max(1, self.sent),
            "late": self.vehicle.get("late", 0),
            "reordered": self.vehicle.get("reordered", 0),
            "duplicate": self.vehicle.get("duplicate", 0),
            "gaps": self.vehicle.get("gap", 0),
            "restarts": sum(
                v for k, v in self.vehicle.items() if k.startswith("estimator_restart")
            ),
        }


def fly_through_proxy(
    spec: FaultSpec,
    *,
    scenario: str = "cruise",
    duration_s: float = 20.0,
    speed: float = 1.0,
    seed: int = 1,
    blackout: tuple[float, float] | None = None,
    config: ServiceConfig | None = None,
    settle_s: float = 2.0,
    tap: Callable[[bytes], None] | None = None,
) -> FaultRun:
    """Fly ``scenario`` through a proxy with ``spec``; ``blackout`` = (at sim s, for wall s);
    ``tap`` sees every datagram the proxy forwards to the service."""
    port = free_udp_port()
    conn = f"udpin:127.0.0.1:{port}"
    svc = Service(config or ServiceConfig(request_rates=False))
    link = Link(conn)
    t_records: list[float] = []
    n_vel = [0]

    def on_records(recs: list[Record]) -> None:
        for r in recs:
            if isinstance(r, VelocityRecord) and r.config == "active":
                n_vel[0] += 1
                t_records.append(r.t_boot_s)

    svc.on_records = on_records
    stop = threading.Event()
    th = threading.Thread(target=svc.run, args=({conn: link}, stop), daemon=True)
    th.start()
    t0 = time.monotonic()
    try:
        with UdpFaultProxy(("127.0.0.1", port), spec, tap=tap) as proxy:
            fired = [False]

            def on_truth(truth: Any) -> None:
                if blackout is not None and not fired[0] and truth.t_s >= blackout[0]:
                    fired[0] = True
                    proxy.blackout(blackout[1])

            summary = run(
                scenario,
                [f"udpout:127.0.0.1:{proxy.port}"],
                duration_s=duration_s,
                speed=speed,
                seed=seed,
                on_truth=on_truth if blackout is not None else None,
                truth_every_s=0.01,
            )
            sent = sum(summary.messages_sent.values())
            # wait for the proxy's queue to drain and the service to take everything: on a
            # busy machine the proxy and the service may be seconds behind the simulator;
            # the loop ends as soon as they are done, the deadline is only a bound
            deadline = time.monotonic() + max(30.0, settle_s + spec.delay_s + spec.jitter_s + 1.0)
            dec = None
            while time.monotonic() < deadline:
                dec = svc.decoders.get(conn)
                st = proxy.stats()
                # everything forwarded (nothing held back by the delay) and taken in
                done = proxy.pending() == 0
                if (
                    done
                    and dec is not None
                    and dec.counters.counts["frames_ok"] >= st.get("forwarded", 0)
                ):
                    break
                time.sleep(0.02)
            pstats = proxy.stats()
    finally:
        stop.set()
        th.join(10.0)
        link.close()
        svc.close()
    s = svc.summary()
    v = s.vehicles.get(1)
    return FaultRun(
        spec=spec,
        proxy=pstats,
        frames=s.link_counters.get(conn, {}),
        vehicle=v.counters if v else {},
        rmse_active_mps=v.rmse_ned_mps.get("active") if v else None,
        rmse_full_mps=v.rmse_ned_mps.get("full") if v else None,
        truth_samples=v.truth_samples if v else 0,
        velocity_records=n_vel[0],
        t_records_s=t_records,
        sent=sent,
        wall_s=time.monotonic() - t0,
    )
