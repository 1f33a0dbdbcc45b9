"""The ``--rerun`` mode string (``[rerun] mode``): parsed without importing rerun."""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_CONNECT_URL = "rerun+http://127.0.0.1:9876/proxy"
_URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


class RerunModeError(ValueError):
    """A ``--rerun`` mode string that is not one of the modes (names the string and why)."""


@dataclass(frozen=True, slots=True)
class RerunMode:
    """A parsed mode: ``kind`` in off, spawn, connect, serve, save; ``target`` URL or path."""

    kind: str
    target: str | None = None

    @property
    def live(self) -> bool:
        """True for the modes that feed a viewer as data arrives (decimated, time-flushed)."""
        return self.kind in ("spawn", "connect", "serve")

    def __str__(self) -> str:
        return self.kind if self.target is None else f"{self.kind}:{self.target}"


def parse_rerun_mode(mode: str) -> RerunMode:
    """Parse ``off | spawn | connect[:URL] | serve | save:PATH``; raise RerunModeError."""
    text = mode.strip()
    kind, sep, target = text.partition(":")
    kind = kind.lower()
    if kind in ("off", "spawn", "serve"):
        if sep:
            raise RerunModeError(f"rerun mode {mode!r}: {kind!r} takes no argument")
        return RerunMode(kind)
    if kind == "connect":
        url = target.strip() if sep else DEFAULT_CONNECT_URL
        if not url.startswith(_URL_SCHEMES) or not url.rstrip("/").endswith("/proxy"):
            raise RerunModeError(
                f"rerun mode {mode!r}: the URL must look like rerun+http://HOST:PORT/proxy "
                f"(scheme one of {', '.join(_URL_SCHEMES)}, path /proxy)"
            )
        return RerunMode("connect", url)
    if kind == "save":
        path = target.strip()
        if not path:
            raise RerunModeError(f"rerun mode {mode!r}: save needs a path, e.g. save:out.rrd")
        return RerunMode("save", path)
    raise RerunModeError(
        f"rerun mode {mode!r}: expected off, spawn, connect[:URL], serve or save:PATH"
    )
