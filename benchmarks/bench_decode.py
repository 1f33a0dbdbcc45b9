"""Decode and ingest per message, over a corpus flight (issue 30, the compiled decode).

Every frame of one ArduPilot SITL flight of the tuning corpus
(``tests/data/ardupilot_sitl/a_quad_wind.tlog.xz``: RAW_IMU, SCALED_IMU2/3, ATTITUDE,
LOCAL_POSITION_NED, SIM_STATE and ArduPilot's other streams), one frame per datagram as
UDP brings them, through:

1. ``pymavlink MAVLink.decode``: the same-run baseline, pymavlink's decode of each frame
   (what a ``mavutil`` loop pays per message, without its byte-by-byte framing);
2. ``decode``: the service's :class:`~glmav_observer.ingest.framing.FrameDecoder`
   (datagram mode; the high-rate messages by ``ingest/fastframe.pyx``, the rest by
   pymavlink);
3. ``decode + ingest``: the same, each message then through
   :meth:`~glmav_observer.ingest.pipeline.Ingest.on_message` (clock, vetting, samples):
   everything between the socket's bytes and ``VehicleEstimator.on_sample``.

Each over every frame of the flight and over its high-rate frames alone (the eight
messages the compiled decoder takes: what 380 of 381 design-rate datagrams are). CPU time
(``process_time``) per frame, median of repeats measured round-robin, one core.

Then the service around them (docs/deployment.md, "where a vehicle's CPU goes"): one
vehicle's 20 s of design-rate traffic (``glmav_sitl.fleet.record_tlog``, as
``bench_worker``) through :meth:`~glmav_observer.app.Service.feed_bytes` with no sinks,
once as it is and once with every ``VehicleEstimator.on_sample`` answering from a
recording of a first run: the second is decode, ingest and the service's glue without the
estimator, everything else unchanged (the same events, records and calls).

The file runs unchanged on the tree before the compiled decode (main 1605b5c) for a
before/after pair: there the decoder's superseded-IMU prefilter is set as its service set
it.
"""

from __future__ import annotations

import gc
import lzma
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.common import format_table, main_for
from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.vehicle import VehicleEstimator
from glmav_observer.ingest import pipeline
from glmav_observer.ingest.framing import FrameCounters, FrameDecoder, iter_tlog
from glmav_observer.ingest.pipeline import Ingest, IngestConfig

LOG = Path(__file__).resolve().parents[1] / "tests/data/ardupilot_sitl/a_quad_wind.tlog.xz"
#: the messages the compiled decoder takes (ingest/fastframe.pyx's FAST_MESSAGES)
HIGH_RATE = frozenset(
    {
        "ATTITUDE",
        "RAW_IMU",
        "SCALED_IMU",
        "SCALED_IMU2",
        "SCALED_IMU3",
        "HIGHRES_IMU",
        "LOCAL_POSITION_NED",
        "SIM_STATE",
    }
)
BASELINE = "pymavlink MAVLink.decode (baseline)"
DECODE = "decode (FrameDecoder.feed)"
BOTH = "decode + ingest (feed + Ingest.on_message)"


def _stages(frames: list[bytes], t_host: list[float]) -> dict[str, Callable[[], int]]:
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    n = len(frames)

    def baseline() -> int:
        mav = dialect.MAVLink(None)
        for f in frames:
            mav.decode(bytearray(f))
        return n

    def decode() -> int:
        dec = FrameDecoder(datagram=True, counters=FrameCounters())
        for f in frames:
            dec.feed(f)
        return n

    def decode_ingest() -> int:
        dec = FrameDecoder(datagram=True, counters=FrameCounters())
        ing = Ingest(IngestConfig())
        ids = getattr(pipeline, "IMU_MESSAGE_IDS", None)  # before the compiled decode
        if ids is not None:
            dec.set_prefilter(ing.skip_superseded, ids)  # type: ignore[attr-defined]
        on_message = ing.on_message
        for f, t in zip(frames, t_host, strict=True):
            for m in dec.feed(f):
                on_message(m, t)
        return n

    return {BASELINE: baseline, DECODE: decode, BOTH: decode_ingest}


def _service_rows(repeats: int) -> list[dict[str, Any]]:
    """The service path per design-rate datagram, whole and with the estimator replayed."""
    from glmav_sitl.fleet import record_tlog

    with tempfile.TemporaryDirectory(prefix="glmav-bench-decode-") as tmp:
        tlog = record_tlog(Path(tmp) / "design.tlog", 20.0, truth=False)
        records = list(iter_tlog(tlog.read_bytes(), FrameCounters()))
    datagrams = [bytes(r.msg.get_msgbuf()) for r in records]
    t_host = [r.t_host_us * 1e-6 for r in records]
    config = ServiceConfig(request_rates=False)
    real = VehicleEstimator.on_sample
    answers: list[Any] = []

    def recording(est: VehicleEstimator, sample: Any) -> Any:
        out = real(est, sample)
        answers.append(out)
        return out

    def serve() -> tuple[float, int]:
        svc = Service(config, [])
        t0 = time.process_time()
        for d, t in zip(datagrams, t_host, strict=True):
            svc.feed_bytes("udp", d, t, datagram=True)
        return (time.process_time() - t0) / len(datagrams) * 1e6, svc.messages

    def replayed() -> tuple[float, int]:
        it = iter(list(answers))
        VehicleEstimator.on_sample = lambda est, sample: next(it)  # type: ignore[method-assign]
        try:
            return serve()
        finally:
            VehicleEstimator.on_sample = real  # type: ignore[method-assign]

    VehicleEstimator.on_sample = recording  # type: ignore[method-assign]
    try:
        _, messages = serve()
    finally:
        VehicleEstimator.on_sample = real  # type: ignore[method-assign]
    whole: list[float] = []
    glue: list[float] = []
    for _ in range(repeats):
        whole.append(serve()[0])
        us, n = replayed()
        assert n == messages, (n, messages)
        glue.append(us)
    rows = []
    for name, v in (
        ("Service.feed_bytes, whole path (no sinks)", whole),
        ("decode + ingest + glue (estimator replayed)", glue),
    ):
        rows.append({"stage": name, "us_per_datagram": statistics.median(v),
                     "min_us": min(v), "max_us": max(v)})  # fmt: skip
    return rows


def run(quick: bool = False) -> dict[str, Any]:
    repeats = 3 if quick else 9
    records = list(iter_tlog(lzma.decompress(LOG.read_bytes()), FrameCounters()))
    frames = [bytes(r.msg.get_msgbuf()) for r in records]
    t_host = [r.t_host_us * 1e-6 for r in records]
    high = [i for i, r in enumerate(records) if r.msg.get_type() in HIGH_RATE]
    del records
    sets = {
        "every frame": _stages(frames, t_host),
        "high-rate frames": _stages([frames[i] for i in high], [t_host[i] for i in high]),
    }
    for stages in sets.values():
        for fn in stages.values():
            fn()  # warm-up
    gc.collect()
    gc.freeze()
    samples: dict[tuple[str, str], list[float]] = {
        (s, name): [] for s, stages in sets.items() for name in stages
    }
    for r in range(repeats):  # round-robin: the machine's load hits every stage alike
        for s, stages in sets.items():
            for name, fn in stages.items():
                t0 = time.process_time()
                k = fn()
                samples[(s, name)].append((time.process_time() - t0) / k * 1e6)
        print(f"repeat {r + 1}/{repeats}", file=sys.stderr, flush=True)
    gc.unfreeze()
    rows = []
    for (s, name), v in samples.items():
        med = statistics.median(v)
        base = statistics.median(samples[(s, BASELINE)])
        rows.append(
            {
                "frames": s,
                "stage": name,
                "us_per_frame": med,
                "vs_pymavlink_decode": med / base,
                "min_us": min(v),
                "max_us": max(v),
            }
        )
    service = _service_rows(repeats)
    return {
        "name": "bench_decode",
        "quick": quick,
        "service": service,
        "log": LOG.name,
        "frames": len(frames),
        "high_rate_frames": len(high),
        "repeats": repeats,
        "rows": rows,
        "goals": [],
    }


def to_markdown(result: dict[str, Any]) -> str:
    label = f" Label: {result['label']}." if result.get("label") else ""
    return (
        "### Decode and ingest per message (bench_decode)\n\n"
        f"Command: `python -m benchmarks.bench_decode`. {result['log']}: "
        f"{result['frames']} frames, {result['high_rate_frames']} of them high-rate; CPU time "
        f"per frame, median of {result['repeats']} round-robin repeats.{label}\n\n"
        + format_table(result["rows"])
        + "\n\nThe service around them, one vehicle's 20 s of design-rate traffic, CPU per "
        "datagram:\n\n" + format_table(result["service"])
    )


if __name__ == "__main__":
    raise SystemExit(main_for(__import__(__name__)))
