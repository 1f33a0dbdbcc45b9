"""The container image's HEALTHCHECK (Dockerfile; docs/container.md, "Health check").

Modes, chosen by the environment variable GLMAV_HEALTH:

- ``observer`` (default): healthy when the ``glmav-observer serve`` process of THIS
  container holds its Zenoh liveliness token ``<prefix>/@alive/<service-id>``. The
  expected id is taken from the serve processes found in /proc (their ``--config``
  file's ``[service] id``, read with the daemon's own loader); GLMAV_SERVICE_ID overrides.
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
import sys
import time
from pathlib import Path
from typing import Any

DEFAULT_CONFIG = "/etc/glmav-observer/zenoh/client-router.json5"
TIMEOUT_S = float(os.environ.get("GLMAV_HEALTH_TIMEOUT_S", "5"))


def _option(words: list[str], name: str) -> str | None:
    """The value of ``--name VALUE`` or ``--name=VALUE`` in an argv (last one wins)."""
    value = None
    for i, word in enumerate(words):
        if word == name and i + 1 < len(words):
            value = words[i + 1]
        elif word.startswith(name + "="):
            value = word.split("=", 1)[1]
    return value


def serve_service_ids() -> set[str]:
    """The Zenoh service id of each ``glmav-observer serve`` process visible here.

    The id is the daemon's ``[service] id`` setting: read with the daemon's own loader
    from the ``--config`` file the process was started with (relative to its working
    directory), the loader's default without one; a ``--service-id`` flag wins.
    """
    from glmav_observer.config import load_config

    ids: set[str] = set()
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = (proc / "cmdline").read_bytes().split(b"\0")
            cwd = (proc / "cwd").resolve()
        except OSError:
            continue
        words = [a.decode(errors="replace") for a in argv if a]
        if not (any(w.endswith("glmav-observer") for w in words) and "serve" in words):
            continue
        explicit = _option(words, "--service-id")
        if explicit:
            ids.add(explicit)
            continue
        config = _option(words, "--config")
        ids.add(load_config(cwd / config if config else None).service_id)
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
