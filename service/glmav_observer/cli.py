"""``glmav-observer``: a thin command line over typed mains.

Each subcommand lives in ``glmav_observer.commands.<name>`` and provides
``register(subparsers) -> None``, which adds its parser and sets ``func``
(``Callable[[argparse.Namespace], int]``, the exit code). Modules keep heavy
imports (zenoh, rerun) inside their functions so that ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from glmav_observer import __version__
from glmav_observer.logs import configure_logging

#: Subcommand modules, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = ("demo", "check", "echo", "router", "serve", "replay", "batch")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="glmav-observer",
        description="Velocity estimation for the GLMAV from MAVLink (Koehl et al., IFAC 2011).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=("DEBUG", "INFO", "WARNING", "ERROR"),
        help="logging level (default INFO)",
    )
    parser.add_argument(
        "--log-format",
        default="text",
        choices=("text", "json"),
        help="text for people, json (one object per line) for log collectors",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"glmav_observer.commands.{name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(args.log_level, args.log_format)
    code: int = args.func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
