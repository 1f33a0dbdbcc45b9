"""``glmav-observer serve``: the daemon (links -> estimates -> sinks) until SIGINT/SIGTERM.

``--link`` connection strings (repeatable; default: ``[service].links`` of the config).
There is no built-in link: 14550 is the ground stations' port, and a daemon that took it
by default would steal the vehicle from the GCS (docs/deployment.md shows where to
attach). ``--config configs/service.toml``, ``--zenoh PATH.json5`` (enables Zenoh with
that session config), ``--rerun off|spawn|save:PATH|connect:URL|serve`` and ``--out
PATH.csv|.jsonl`` override the file. Exit codes: 0 stopped cleanly, 2 bad configuration
or link (a UDP port another process holds, a malformed string, a missing device).
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

#: What the "no link" message suggests: a loopback port a router forwards to (not 14550).
EXAMPLE_LINK = "udpin:127.0.0.1:14551"

logger = logging.getLogger(__name__)


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "serve", help="estimate velocities from live MAVLink links and publish them"
    )
    p.add_argument("--link", action="append", default=None, metavar="CONN",
                   help="pymavlink connection string, repeatable (default: [service].links; "
                        f"required otherwise, e.g. {EXAMPLE_LINK})")  # fmt: skip
    p.add_argument("--config", default=None, help="service.toml (default: built-in defaults)")
    p.add_argument("--zenoh", default=None, metavar="PATH.json5",
                   help="enable Zenoh with this session config")  # fmt: skip
    p.add_argument("--rerun", default=None, metavar="MODE",
                   help="off | spawn | save:PATH | connect:URL | serve (default: config, off)")  # fmt: skip
    p.add_argument("--out", default=None, metavar="PATH", help="also write records to .csv/.jsonl")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from glmav_observer.app import open_sinks, serve
    from glmav_observer.config import ConfigError, check_rerun_mode, load_config
    from glmav_observer.ingest.links import LinkError, check_connection_string
    from glmav_observer.publish.file_sink import FileSinkError

    try:
        config = load_config(args.config)
        if args.rerun is not None and (reason := check_rerun_mode(args.rerun)):
            raise ConfigError("--rerun", "mode", reason)
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
    try:  # links are checked once the outputs' own errors have been reported
        links = args.link or list(config.links)
        if not links:
            raise LinkError(
                f"no link given: pass --link (e.g. --link {EXAMPLE_LINK} behind MAVProxy or "
                "mavlink-router; docs/deployment.md) or set [service].links"
            )
        for conn in links:
            check_connection_string(conn)
    except (ConfigError, LinkError) as err:
        for sink in sinks:
            sink.close()
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    try:
        summary = serve(config, sinks, links)
    except LinkError as err:
        print(f"glmav-observer serve: {err}", file=sys.stderr)
        return 2
    print(summary.to_text())
    if summary.failed_sinks:
        print("glmav-observer serve: an output failed: see SINK FAILED above", file=sys.stderr)
        return 1
    return 0
