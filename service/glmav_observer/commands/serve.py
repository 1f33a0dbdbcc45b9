"""``glmav-observer serve``: the daemon (links -> estimates -> sinks) until SIGINT/SIGTERM.

``--link`` connection strings (repeatable; default: ``[service].links`` of the config).
There is no built-in link: 14550 is the ground stations' port, and a daemon that took it
by default would steal the vehicle from the GCS (docs/deployment.md shows where to
attach). ``--config configs/service.toml``, ``--zenoh PATH.json5`` (enables Zenoh with
that session config), ``--rerun off|spawn|save:PATH|connect:URL|serve`` and ``--out
PATH.csv|.jsonl`` override the file. Estimates are published on Zenoh by default (the embedded loopback peer:
no router needed; ``--no-zenoh`` to stop, ``--full-rate`` for every record of every
configuration instead of ``[zenoh.rates]``), and the log says at start where they go.
``--workers N`` shards vehicles by system id across
N worker processes (:mod:`glmav_observer.fleet.workers`; ``--workers 1`` is the
single-process service). Without ``--workers``: the number of cores this process may use
(its CPU affinity), or 1 when an output needs one process (``--rerun spawn|serve``: one
viewer, one port; ``--mavlink-out``: one sender per vehicle link; a signing state file:
one writer), said in the log; ``--claim`` makes this service estimate only the
vehicles it claims on Zenoh, so that several services can share one fleet
(:mod:`glmav_observer.fleet.claims`). ``--service-id NAME`` names this service on Zenoh
(in every payload, its liveliness token and its config key; a second service with the
same id on one Zenoh network refuses to start); ``--mavlink-out CONN`` sends the active
estimate back on MAVLink (``[mavlink_out]``, :mod:`glmav_observer.publish.mavlink_out`).
SIGINT, SIGTERM and SIGHUP (a closed terminal) stop it the same way: the summary, whole
records, Zenoh closed. ``--out`` (one file, whatever the number of workers) and
``--rerun save:PATH`` never write through a link or onto a device; an existing file is
overwritten only with ``--force``. Exit codes: 0 stopped cleanly, 1 an output failed
while running (e.g. a full disk: the summary says which), 2 bad configuration, output or
link (a UDP port another process holds, a malformed string, a missing device), or a
namesake already running.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from glmav_observer.config import ServiceConfig
    from glmav_observer.publish.sink import Sink

#: What the "no link" message suggests: a loopback port a router forwards to (not 14550).
EXAMPLE_LINK = "udpin:127.0.0.1:14551"

logger = logging.getLogger(__name__)


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "serve",
        help="estimate velocities from live MAVLink links and publish them",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--link", action="append", default=None, metavar="CONN",
                   help="pymavlink connection string, repeatable (default: [service].links; "
                        f"required otherwise, e.g. {EXAMPLE_LINK})")  # fmt: skip
    p.add_argument("--config", default=None, help="service.toml (default: built-in defaults)")
    p.add_argument("--zenoh", default=None, metavar="PATH.json5",
                   help="Zenoh session config (default: [zenoh].config, or the embedded "
                   "loopback peer, which needs no router)")  # fmt: skip
    p.add_argument("--no-zenoh", action="store_true",
                   help="do not publish on Zenoh (it is on by default: [zenoh].enabled)")  # fmt: skip
    p.add_argument("--full-rate", action="store_true",
                   help="publish every record of every configuration on Zenoh (default: "
                   "[zenoh.rates], e.g. active 50 Hz, configurations 10 Hz, health 5 Hz)")  # fmt: skip
    p.add_argument("--rerun", default=None, metavar="MODE",
                   help="off | spawn | save:PATH | connect:URL | serve (default: config, off)")  # fmt: skip
    p.add_argument("--out", default=None, metavar="PATH", help="also write records to .csv/.jsonl")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing --out/--rerun save: file (never a link or a device)")  # fmt: skip
    p.add_argument("--workers", type=_workers, default=None, metavar="N",
                   help="worker processes, vehicles sharded by system id (default: the "
                   "usable cores, or 1 when an output needs one process; 1 = one process)")  # fmt: skip
    p.add_argument("--claim", action="store_true",
                   help="estimate only the vehicles claimed on Zenoh (several services, one fleet)")  # fmt: skip
    p.add_argument("--mavlink-out", default=None, metavar="CONN",
                   help="send the active estimate (ODOMETRY), fault events (STATUSTEXT) and "
                   "health (NAMED_VALUE_FLOAT) on this connection, as a component of each "
                   "vehicle ([mavlink_out] in the config)")  # fmt: skip
    p.add_argument("--service-id", default=None, metavar="NAME",
                   help="this service's id on Zenoh (default: [service] id, glmav-observer); "
                   "a second service with the same id on one Zenoh network refuses to start")  # fmt: skip
    p.set_defaults(func=main)


def _workers(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 1 <= n <= 256:
        raise argparse.ArgumentTypeError(f"{n} workers: must be 1..256")
    return n


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity: a container's or taskset's
    limit, not the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no sched_getaffinity (macOS)
        return max(1, os.cpu_count() or 1)


def default_workers(
    config: ServiceConfig, rerun_mode: str | None, links: Sequence[str] = ()
) -> tuple[int, str]:
    """``(workers, why)`` without ``--workers``: the usable cores, or 1 when an output
    or a link needs a single process."""
    held = [c for c in links if not c.startswith(("udpin:", "udp:"))]
    if config.request_rates and held:
        # the process that holds the link sees it go down, reconnect and fill, and sets the
        # rates back at the stop (ingest/rates.py); workers behind it would not
        return 1, f"rate requests on {held[0]} need one process (the link's state)"
    mode = rerun_mode if rerun_mode is not None else config.rerun.mode
    if mode in ("spawn", "serve"):
        return 1, f"--rerun {mode} needs one process (one viewer, one port)"
    if config.mavlink_out.enabled:
        return 1, "--mavlink-out needs one process (one sender on its link)"
    if config.signing_key is not None and config.signing_state_file:
        return 1, "a signing state file needs one process (one writer)"
    n = usable_cores()
    return n, f"{n} usable cores"


def main(args: argparse.Namespace) -> int:
    from glmav_observer.app import serve
    from glmav_observer.app_sinks import open_sinks
    from glmav_observer.config import check_rerun_mode, load_config
    from glmav_observer.ingest.links import LinkError
    from glmav_observer.publish.file_sink import FileSinkError
    from glmav_toml import ConfigError

    try:
        config = load_config(args.config)
        if args.service_id is not None:
            from dataclasses import replace

            from glmav_observer.publish.zenoh_keys import check_service_id

            config = replace(config, service_id=check_service_id(args.service_id))
        if args.mavlink_out is not None:
            from dataclasses import replace

            out = replace(config.mavlink_out, enabled=True, link=args.mavlink_out)
            config = replace(config, mavlink_out=out)
        if args.rerun is not None and (reason := check_rerun_mode(args.rerun)):
            raise ConfigError("--rerun", "mode", reason)
        if args.no_zenoh and args.zenoh is not None:
            raise ConfigError("--no-zenoh", "zenoh", "--zenoh PATH and --no-zenoh contradict")
        config = _zenoh_flags(config, args)
        links = args.link or list(config.links)
    except (ConfigError, OSError, ValueError) as err:
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    workers = args.workers
    if workers is None:
        workers, why = default_workers(config, args.rerun, links)
        logger.info("serve: %d worker process(es): %s (--workers N to choose)", workers, why)
    _log_outputs(config, args)
    if workers > 1:
        try:
            _check_outputs(args)  # the outputs' own errors first, as with one process
            _check_links(links)
        except (ConfigError, ValueError, LinkError) as err:
            print(f"glmav-observer serve: {err}", file=sys.stderr)
            return 2
        return _main_sharded(args, config, links, workers)
    try:
        sinks = open_sinks(
            config,
            out=args.out,
            zenoh_config=args.zenoh,
            zenoh_enabled=True if args.zenoh is not None else None,
            rerun_mode=args.rerun,
            force=args.force,
        )
    except (ConfigError, FileSinkError, OSError, ValueError) as err:
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    try:  # links are checked once the outputs' own errors have been reported
        _check_links(links)
    except (ConfigError, LinkError) as err:
        for sink in sinks:
            sink.close()
        _discard_empty_files(sinks)
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    if args.claim:
        return _main_claim(config, sinks, links)
    try:
        summary = serve(config, sinks, links)
    except LinkError as err:  # a link that would not open: nothing was served
        _discard_empty_files(sinks)
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    print(summary.to_text())
    if summary.failed_sinks:
        print("glmav-observer serve: an output failed: see SINK FAILED above", file=sys.stderr)
        return 1
    return 0


def _discard_empty_files(sinks: list[Sink]) -> None:
    """Remove the ``--out`` file a start that failed created (no empty output is left)."""
    from glmav_observer.publish.file_sink import FileSink

    for sink in sinks:
        if isinstance(sink, FileSink) and sink.rows == 0:
            sink.path.unlink(missing_ok=True)


def _zenoh_flags(config: ServiceConfig, args: argparse.Namespace) -> ServiceConfig:
    """``--zenoh PATH`` (on, with that session), ``--no-zenoh`` and ``--full-rate``."""
    from dataclasses import replace

    z = config.zenoh
    if args.zenoh is not None:
        z = replace(z, enabled=True, config=args.zenoh)
    if args.no_zenoh:
        z = replace(z, enabled=False)
    if args.full_rate:
        z = replace(z, full_rate=True)
    return replace(config, zenoh=z)


def _log_outputs(config: ServiceConfig, args: argparse.Namespace) -> None:
    """Say at start where the estimates go; warn when they go nowhere."""
    from glmav_observer.app_sinks import describe_outputs

    outputs = describe_outputs(config, out=args.out, rerun_mode=args.rerun)
    for line in outputs:
        logger.info("serve: output: %s", line)
    if not outputs:
        logger.warning(
            "serve: no output: the estimates are computed and published nowhere (Zenoh is "
            "off, no --out, --rerun or --mavlink-out); only the summary at exit shows them"
        )


def _check_outputs(args: argparse.Namespace) -> None:
    """Raise for a Zenoh config file that cannot be parsed (the workers open the session;
    their other errors come back from them)."""
    if args.zenoh is not None:
        from glmav_observer.publish.zenoh_config import load_zenoh_config

        load_zenoh_config(args.zenoh)


def _check_links(links: list[str]) -> None:
    """Raise LinkError for no link or a malformed connection string."""
    from glmav_observer.ingest.links import LinkError, check_connection_string

    if not links:
        raise LinkError(
            f"no link given: pass --link (e.g. --link {EXAMPLE_LINK} behind MAVProxy or "
            "mavlink-router; docs/deployment.md) or set [service].links"
        )
    for conn in links:
        check_connection_string(conn)


def _main_claim(config: ServiceConfig, sinks: list[Sink], links: list[str]) -> int:
    """One process, claiming vehicles: :func:`serve` with a ClaimingService."""
    from glmav_observer.app import serve
    from glmav_observer.fleet.claims import ClaimError, ClaimingService
    from glmav_observer.ingest.links import LinkError

    try:
        service = ClaimingService(config, sinks)
        summary = serve(config, sinks, links, service=service)
    except (ClaimError, LinkError) as err:
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    print(summary.to_text())
    return 0


def _main_sharded(
    args: argparse.Namespace, config: ServiceConfig, links: list[str], workers: int
) -> int:
    """``--workers N > 1``: the router here, the services in N worker processes."""
    from pathlib import Path

    from glmav_observer.fleet.worker_process import WorkerError
    from glmav_observer.fleet.workers import serve_sharded, worker_specs
    from glmav_observer.ingest.links import LinkError
    from glmav_observer.publish.file_sink import FileSink, FileSinkError

    out = args.out if args.out is not None else (config.out or None)
    made = False
    try:
        if out:  # the one file every worker appends to (with its CSV header), made here
            FileSink(out, force=args.force).close()
            made = True
        specs = worker_specs(
            config,
            workers,
            out=out,
            zenoh_config=args.zenoh,
            zenoh_enabled=True if args.zenoh is not None else None,
            rerun_mode=args.rerun,
            claim=args.claim,
            force=args.force,
        )
        result = serve_sharded(specs, links)
    except (WorkerError, LinkError, FileSinkError, OSError, ValueError) as err:
        if made and out:  # nothing was served: no empty output is left
            Path(out).unlink(missing_ok=True)
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    print(result.to_text())
    if result.summary.failed_sinks:
        print("glmav-observer serve: an output failed: see SINK FAILED above", file=sys.stderr)
        return 1
    return 0
