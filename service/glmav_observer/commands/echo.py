"""``glmav-observer echo [KEYEXPR]``: print what the service publishes on Zenoh.

Subscribes to KEYEXPR (default ``glmav/**``) and prints each sample, decoded by its
encoding (``application/json``, or ``application/msgpack`` from a service with ``[zenoh]
encoding = "msgpack"``; anything else as text): ``--format pretty``
(the default: the key, then the indented JSON) or ``--format jsonl`` (one object per
line ``{"key": ..., "encoding": ..., "value": ...}``, for jq and loggers). ``--query``
sends one query instead (e.g. ``glmav/*/state`` or ``glmav/@config/*``) and prints the
replies; ``--alive`` lists the liveliness tokens under KEYEXPR (default
``glmav/@alive/**``) and then prints their changes (``+`` appeared, ``-`` gone).
``--validate`` checks every payload against its schema and reports violations on stderr
(exit code 1 if any).

The session: ``--zenoh PATH.json5``, or ``--connect ENDPOINT`` (client of that router),
or by default a loopback peer that connects to ``tcp/127.0.0.1:7447`` (a local
``glmav-observer router``) with multicast scouting off.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import sys
import time
from typing import Any

from glmav_observer.publish.schema import validate
from glmav_observer.publish.zenoh_config import (
    ZenohConfigError,
    clean_zenoh_error,
    load_zenoh_config,
    open_session,
)
from glmav_observer.publish.zenoh_keys import decode_payload

DEFAULT_KEYEXPR = "glmav/**"
DEFAULT_ALIVE_KEYEXPR = "glmav/@alive/**"
_DEFAULT_ECHO_JSON5 = """{
  mode: "peer",
  connect: { endpoints: ["tcp/127.0.0.1:7447"] },
  scouting: { multicast: { enabled: false } },
}"""


def _session_config(args: argparse.Namespace) -> tuple[Any, str]:
    import zenoh

    if args.zenoh is not None:
        config, name = load_zenoh_config(args.zenoh)
    elif args.connect:
        config = zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "client",
                    "connect": {"endpoints": args.connect},
                    "scouting": {"multicast": {"enabled": False}},
                }
            )
        )
        name = f"--connect {' '.join(args.connect)}"
    else:
        config, name = zenoh.Config.from_json5(_DEFAULT_ECHO_JSON5), "echo defaults"
    return config, name


def _decode(payload: bytes, encoding: str) -> Any:
    """The payload decoded by its sample's encoding (JSON, MessagePack), else as text."""
    try:
        return decode_payload(payload, encoding)
    except ValueError:  # also UnicodeDecodeError and MessagePack's decode errors
        return payload.decode("utf-8", errors="replace")


class _Printer:
    def __init__(self, fmt: str, check: bool) -> None:
        self.fmt = fmt
        self.check = check
        self.count = 0
        self.invalid = 0

    def show(self, key: str, encoding: str, payload: bytes, mark: str = "") -> None:
        value = _decode(payload, encoding) if payload else None
        self.count += 1
        if self.check and value is not None:
            errors = validate(value)
            if errors:
                self.invalid += 1
                print(f"INVALID {key}: {'; '.join(errors)}", file=sys.stderr, flush=True)
        if self.fmt == "jsonl":
            line: dict[str, Any] = {"key": key, "encoding": encoding, "value": value}
            if mark:
                line["kind"] = "put" if mark == "+" else "delete"
            print(json.dumps(line, separators=(",", ":")), flush=True)
        elif value is None:
            print(f"{mark}{key}", flush=True)
        else:
            text = json.dumps(value, indent=2) if not isinstance(value, str) else value
            print(f"{mark}{key} ({encoding})\n{text}", flush=True)


def _run_stream(session: Any, args: argparse.Namespace, printer: _Printer) -> None:
    """Subscribe (or watch liveliness) and print until --count, --duration or Ctrl-C."""
    import zenoh

    samples: queue.Queue[tuple[str, str, bytes, str]] = queue.Queue()

    def on_sample(sample: zenoh.Sample) -> None:
        mark = ""
        if args.alive:
            mark = "+" if sample.kind == zenoh.SampleKind.PUT else "-"
        samples.put((str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes(), mark))

    if args.alive:
        entity = session.liveliness().declare_subscriber(args.keyexpr, on_sample, history=True)
    else:
        entity = session.declare_subscriber(args.keyexpr, on_sample)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        while args.count is None or printer.count < args.count:
            timeout = 0.2
            if deadline is not None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                timeout = min(timeout, remaining)
            try:
                key, encoding, payload, mark = samples.get(timeout=timeout)
            except queue.Empty:
                continue
            printer.show(key, encoding, payload, mark)
    finally:
        entity.undeclare()


def _run_query(session: Any, args: argparse.Namespace, printer: _Printer) -> None:
    timeout = 5.0 if args.duration is None else args.duration
    for reply in session.get(args.keyexpr, timeout=timeout):
        if reply.ok is not None:
            sample = reply.ok
            printer.show(str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes())
        else:
            print(f"error reply: {reply.err.payload.to_string()}", file=sys.stderr, flush=True)


def main(args: argparse.Namespace) -> int:
    import zenoh

    if args.keyexpr is None:
        args.keyexpr = DEFAULT_ALIVE_KEYEXPR if args.alive else DEFAULT_KEYEXPR
    try:
        zenoh.KeyExpr(args.keyexpr)
    except zenoh.ZError as exc:
        print(
            f"glmav-observer echo: bad key expression {args.keyexpr!r}: {clean_zenoh_error(exc)}",
            file=sys.stderr,
        )
        return 2
    try:
        config, name = _session_config(args)
        session = open_session(config, name)
    except ZenohConfigError as exc:
        print(f"glmav-observer echo: {exc}", file=sys.stderr)
        return 2
    printer = _Printer(args.format, args.validate)
    try:
        if args.query:
            _run_query(session, args, printer)
        else:
            _run_stream(session, args, printer)
    except KeyboardInterrupt:
        pass
    except BrokenPipeError:  # `echo | head`: the reader left; keep exit quiet
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    finally:
        session.close()  # type: ignore[no-untyped-call]
    if args.validate and printer.invalid:
        print(f"{printer.invalid} of {printer.count} payloads invalid", file=sys.stderr)
        return 1
    return 0


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "echo",
        help="print what the service publishes on Zenoh",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "keyexpr",
        nargs="?",
        metavar="KEYEXPR",
        help=f"key expression (default {DEFAULT_KEYEXPR}; {DEFAULT_ALIVE_KEYEXPR} with --alive)",
    )
    parser.add_argument("--format", choices=("pretty", "jsonl"), default="pretty")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--query", action="store_true", help="query KEYEXPR once, print replies")
    mode.add_argument("--alive", action="store_true", help="watch liveliness tokens")
    parser.add_argument(
        "--validate", action="store_true", help="check payloads against their schema"
    )
    parser.add_argument("--count", type=int, metavar="N", help="exit after N samples")
    parser.add_argument(
        "--duration", type=float, metavar="S", help="exit after S seconds (query timeout)"
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--zenoh", metavar="PATH.json5", help="Zenoh JSON5 config")
    source.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="be a client of this router (e.g. tcp/127.0.0.1:7447), repeatable",
    )
    parser.set_defaults(func=main)
