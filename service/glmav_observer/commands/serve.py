"""``glmav-observer serve``: the daemon (links -> estimates -> sinks) until SIGINT/SIGTERM.

``--link`` connection strings (repeatable; default: ``[service].links`` of the config,
else ``udpin:127.0.0.1:14550``), ``--config configs/service.toml``, ``--zenoh PATH.json5``
(enables Zenoh with that session config), ``--rerun off|spawn|save:PATH|connect:URL|serve``
and ``--out PATH.csv|.jsonl`` override the file; ``--service-id NAME`` names this service
on Zenoh (in every payload, its liveliness token and its config key; a second service with
the same id on one Zenoh network refuses to start); ``--mavlink-out CONN`` sends the active
estimate back on MAVLink (``[mavlink_out]``, :mod:`glmav_observer.publish.mavlink_out`). Exit codes: 0 stopped cleanly, 2 bad
configuration or link, or a namesake already running.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

DEFAULT_LINK = "udpin:127.0.0.1:14550"

logger = logging.getLogger(__name__)


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "serve",
        help="estimate velocities from live MAVLink links and publish them",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--link", action="append", default=None, metavar="CONN",
                   help=f"pymavlink connection string, repeatable (default {DEFAULT_LINK})")  # fmt: skip
    p.add_argument("--config", default=None, help="service.toml (default: built-in defaults)")
    p.add_argument("--zenoh", default=None, metavar="PATH.json5",
                   help="enable Zenoh with this session config")  # fmt: skip
    p.add_argument("--rerun", default=None, metavar="MODE",
                   help="off | spawn | save:PATH | connect:URL | serve (default: config, off)")  # fmt: skip
    p.add_argument("--out", default=None, metavar="PATH", help="also write records to .csv/.jsonl")
    p.add_argument("--mavlink-out", default=None, metavar="CONN",
                   help="send the active estimate (ODOMETRY), fault events (STATUSTEXT) and "
                   "health (NAMED_VALUE_FLOAT) on this connection, as a component of each "
                   "vehicle ([mavlink_out] in the config)")  # fmt: skip
    p.add_argument("--service-id", default=None, metavar="NAME",
                   help="this service's id on Zenoh (default: [service] id, glmav-observer); "
                   "a second service with the same id on one Zenoh network refuses to start")  # fmt: skip
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from glmav_observer.app import open_sinks, serve
    from glmav_observer.config import ConfigError, check_rerun_mode, load_config
    from glmav_observer.ingest.links import LinkError
    from glmav_observer.publish.file_sink import FileSinkError

    try:
        config = load_config(args.config)
        if args.service_id is not None:
            from dataclasses import replace

            from glmav_observer.publish.zenoh_sink import check_service_id

            config = replace(config, service_id=check_service_id(args.service_id))
        if args.mavlink_out is not None:
            from dataclasses import replace

            out = replace(config.mavlink_out, enabled=True, link=args.mavlink_out)
            config = replace(config, mavlink_out=out)
        if args.rerun is not None and (reason := check_rerun_mode(args.rerun)):
            raise ConfigError("--rerun", "mode", reason)
        links = args.link or list(config.links) or [DEFAULT_LINK]
        sinks = open_sinks(
            config,
            out=args.out,
            zenoh_config=args.zenoh,
            zenoh_enabled=True if args.zenoh is not None else None,
            rerun_mode=args.rerun,
        )
    except (ConfigError, FileSinkError, OSError, ValueError) as err:
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    try:
        summary = serve(config, sinks, links)
    except LinkError as err:
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    print(summary.to_text())
    return 0
