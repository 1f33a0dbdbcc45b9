"""The Zenoh configuration of the sink and the tools: the JSON5 file (or the embedded
peer-local default) checked and opened into a session, and the per-kind decimation, with
errors that name the file and the problem (:class:`ZenohConfigError`).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from glmav_observer.publish.schema import (
    DEFAULT_DECIMATION,
    KINDS,
    decimation_reason,
)

if TYPE_CHECKING:
    import zenoh


#: The embedded default (mirrored by configs/zenoh/peer-local.json5): a peer listening on
#: an ephemeral loopback port, trying a local router on tcp/127.0.0.1:7447 (retried in
#: the background, not an error when absent), no multicast scouting: no traffic leaves
#: the host.
EMBEDDED_DEFAULT_JSON5 = """{
  mode: "peer",
  listen: { endpoints: ["tcp/127.0.0.1:0"] },
  connect: { endpoints: ["tcp/127.0.0.1:7447"] },
  scouting: { multicast: { enabled: false } },
}"""
EMBEDDED_DEFAULT_NAME = "<embedded peer-local default>"

_ZERROR_LOCATION = re.compile(r"\s+at /\S+:\d+\.?")


class ZenohConfigError(ValueError):
    """A Zenoh configuration that cannot be used; the message names the file and problem."""


def clean_zenoh_error(exc: BaseException) -> str:
    """A ZError's message without the Rust source location."""
    return _ZERROR_LOCATION.sub("", str(exc)).strip()


def _get(config: zenoh.Config, key: str) -> Any:
    return json.loads(config.get_json(key))


def load_zenoh_config(path: str | os.PathLike[str] | None) -> tuple[zenoh.Config, str]:
    """Parse and check a Zenoh JSON5 file (None: the embedded default).

    Returns ``(config, name)``; raises :class:`ZenohConfigError` naming the file.
    """
    import zenoh

    if path is None:
        name, text = EMBEDDED_DEFAULT_NAME, EMBEDDED_DEFAULT_JSON5
    else:
        name = os.fspath(path)
        try:
            text = Path(name).read_text(encoding="utf-8")
        except OSError as exc:
            raise ZenohConfigError(f"{name}: cannot read: {exc.strerror or exc}") from exc
        except UnicodeDecodeError as exc:
            raise ZenohConfigError(f"{name}: not UTF-8 text: {exc}") from exc
    try:
        config = zenoh.Config.from_json5(text)
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"{name}: {clean_zenoh_error(exc)}") from exc
    mode = _get(config, "mode") or "peer"
    connect = _get(config, "connect/endpoints")
    multicast = _get(config, "scouting/multicast/enabled")
    has_connect = bool(connect) if not isinstance(connect, dict) else any(connect.values())
    if mode == "client" and not has_connect and multicast is False:
        raise ZenohConfigError(
            f"{name}: mode 'client' needs connect.endpoints (e.g. [\"tcp/127.0.0.1:7447\"]) "
            "when multicast scouting is off"
        )
    return config, name


def open_session(config: zenoh.Config, name: str) -> zenoh.Session:
    """Open a session; a failure raises :class:`ZenohConfigError` naming the config."""
    import zenoh

    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        mode = _get(config, "mode") or "peer"
        where = f"mode {mode}, connect {_get(config, 'connect/endpoints')}"
        listen = _get(config, "listen/endpoints")
        if isinstance(listen, list):  # explicitly set (else the per-mode defaults)
            where += f", listen {listen}"
        raise ZenohConfigError(
            f"{name}: cannot open the Zenoh session ({where}): {clean_zenoh_error(exc)}"
        ) from exc


def check_decimation(decimation: Mapping[str, int] | None) -> dict[str, int]:
    """The full per-kind decimation (every Nth record; 0 = never publish that kind)."""
    result = dict(DEFAULT_DECIMATION)
    for kind, every in (decimation or {}).items():
        if kind not in result:
            raise ZenohConfigError(
                f"zenoh decimation: unknown key kind {kind!r} (known: {', '.join(KINDS)})"
            )
        reason = decimation_reason(every)
        if reason is not None:
            raise ZenohConfigError(f"zenoh decimation.{kind}: {reason}, got {every!r}")
        result[kind] = every
    return result
