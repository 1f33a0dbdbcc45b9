"""``glmav-observer router``: a Zenoh router for the ground network, no separate binary.

A Python Zenoh session in router mode routes between clients and peers exactly like
``zenohd`` (without zenohd's plugins: no REST, no storages). Without options it listens
on ``tcp/127.0.0.1:7447`` only, with multicast scouting off; ``--config`` takes a Zenoh
JSON5 file (``configs/zenoh/router.json5``, ``router-tls.json5``, ``acl-router.json5``),
``--listen``/``--connect`` replace its endpoints. It prints one line
``router <zid> listening on [...]`` on stdout once it is up, then runs until SIGINT or
SIGTERM and closes its session.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from types import FrameType
from typing import Any

from glmav_observer.publish.zenoh_config import (
    ZenohConfigError,
    clean_zenoh_error,
    load_zenoh_config,
    open_session,
)
from glmav_observer.stop import set_from_signal_handler

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
_DEFAULT_ROUTER_JSON5 = '{ mode: "router", scouting: { multicast: { enabled: false } } }'


def build_config(
    config_path: str | None, listen: list[str] | None, connect: list[str] | None
) -> tuple[Any, str]:
    """The router's ``zenoh.Config`` and the name errors quote."""
    import zenoh

    if config_path is None:
        config = zenoh.Config.from_json5(_DEFAULT_ROUTER_JSON5)
        name = "router defaults"
        if not listen:
            listen = [DEFAULT_LISTEN]
    else:
        config, name = load_zenoh_config(config_path)
        mode = json.loads(config.get_json("mode"))
        if mode not in (None, "router"):
            raise ZenohConfigError(f"{name}: mode is {mode!r}; `router` needs mode 'router'")
        config.insert_json5("mode", '"router"')
    try:
        if listen:
            config.insert_json5("listen/endpoints", json.dumps(listen))
        if connect:
            config.insert_json5("connect/endpoints", json.dumps(connect))
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"{name}: bad endpoint option: {clean_zenoh_error(exc)}") from exc
    return config, name


def main(args: argparse.Namespace) -> int:
    try:
        config, name = build_config(args.config, args.listen, args.connect)
        session = open_session(config, name)
    except ZenohConfigError as exc:
        print(f"glmav-observer router: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        set_from_signal_handler(stop)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        listen = json.loads(config.get_json("listen/endpoints"))
        print(f"router {session.zid()} listening on {json.dumps(listen)}", flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        session.close()  # type: ignore[no-untyped-call]
    print("router closed", flush=True)
    return 0


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "router",
        help="run a Zenoh router (a Python session in router mode)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--config", metavar="PATH.json5", help="Zenoh JSON5 config (mode must be router)"
    )
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default {DEFAULT_LISTEN} without --config)",
    )
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="another router to connect to, repeatable",
    )
    parser.set_defaults(func=main)
