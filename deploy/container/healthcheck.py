"""The container image's HEALTHCHECK (Dockerfile; docs/container.md, "Health check").

Modes, chosen by the environment variable GLMAV_HEALTH:

- ``observer`` (default): healthy when the ``glmav-observer serve`` process of THIS
  container holds its Zenoh liveliness token ``<prefix>/@alive/<service-id>``. The
  service id defaults to ``<hostname>-<pid>`` (publish/zenoh_sink.py), so the expected
  ids are computed from the serve processes found in /proc; GLMAV_SERVICE_ID overrides.
  The check opens its own Zenoh session with the config in GLMAV_HEALTH_ZENOH (default
  /etc/glmav-observer/zenoh/client-router.json5): it must reach the daemon (through the router).
- ``zenoh``: healthy when a Zenoh session with that config opens and sees a router
  (for the router container: the client config connects to it).
- ``off``: always healthy (containers without a service to probe, e.g. the simulator).

Exit status 0 = healthy, 1 = unhealthy (with the reason on stdout, which podman/docker
keep in the health log). Runs inside the image only (its Python has zenoh).
"""

from __future__ import annotations

import json
import os
import re
import socket
import sys
import time
from pathlib import Path
from typing import Any

DEFAULT_CONFIG = "/etc/glmav-observer/zenoh/client-router.json5"
TIMEOUT_S = float(os.environ.get("GLMAV_HEALTH_TIMEOUT_S", "5"))


def serve_service_ids() -> set[str]:
    """``<hostname>-<pid>`` for each ``glmav-observer serve`` process visible here."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname()) or "host"
    ids: set[str] = set()
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        words = [a.decode(errors="replace") for a in argv if a]
        if any(w.endswith("glmav-observer") for w in words) and "serve" in words:
            ids.add(f"{host}-{proc.name}")
    return ids


def open_session(config_path: str) -> Any:
    import zenoh

    if not Path(config_path).is_file():
        raise SystemExit(f"unhealthy: Zenoh config {config_path} not found (GLMAV_HEALTH_ZENOH)")
    return zenoh.open(zenoh.Config.from_file(config_path))


def check_observer(config_path: str, prefix: str) -> str:
    wanted = {os.environ["GLMAV_SERVICE_ID"]} if os.environ.get("GLMAV_SERVICE_ID") else None
    if wanted is None:
        wanted = serve_service_ids()
        if not wanted:
            raise SystemExit("unhealthy: no 'glmav-observer serve' process in this container")
    alive: set[str] = set()
    deadline = time.monotonic() + TIMEOUT_S
    with open_session(config_path) as session:
        # Retried until the deadline: right after the session opens, the router may not
        # have forwarded the token declarations yet.
        while time.monotonic() < deadline and not (alive & wanted):
            for reply in session.liveliness().get(f"{prefix}/@alive/*", timeout=1.0):
                if reply.ok is not None:
                    alive.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
            if not alive & wanted:
                time.sleep(0.2)
    if not alive & wanted:
        raise SystemExit(
            f"unhealthy: no liveliness token for {sorted(wanted)} under {prefix}/@alive "
            f"(seen: {sorted(alive)})"
        )
    return f"healthy: {prefix}/@alive/{sorted(alive & wanted)[0]}"


def check_zenoh(config_path: str) -> str:
    deadline = time.monotonic() + TIMEOUT_S
    with open_session(config_path) as session:
        while time.monotonic() < deadline:
            routers = list(session.info.routers_zid())
            if routers:
                return f"healthy: connected to router {routers[0]}"
            time.sleep(0.2)
    raise SystemExit(f"unhealthy: no Zenoh router reachable with {config_path}")


def main() -> int:
    mode = os.environ.get("GLMAV_HEALTH", "observer")
    config_path = os.environ.get("GLMAV_HEALTH_ZENOH") or DEFAULT_CONFIG
    prefix = os.environ.get("GLMAV_HEALTH_PREFIX", "glmav")
    if mode == "off":
        message = "healthy: health check off (GLMAV_HEALTH=off)"
    elif mode == "zenoh":
        message = check_zenoh(config_path)
    elif mode == "observer":
        message = check_observer(config_path, prefix)
    else:
        print(json.dumps({"error": f"GLMAV_HEALTH={mode!r}: use observer, zenoh or off"}))
        return 1
    print(message)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except SystemExit as exc:
        if isinstance(exc.code, str):
            print(exc.code)
            sys.exit(1)
        raise
    except Exception as exc:  # any failure to probe is "unhealthy", with the reason
        print(f"unhealthy: {type(exc).__name__}: {exc}")
        sys.exit(1)
