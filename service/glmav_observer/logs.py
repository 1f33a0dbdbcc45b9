"""Structured logging for the service: text for people, JSON lines for collectors."""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

#: the standard fields of a record, and those a formatter sets on it
_RESERVED = frozenset(logging.LogRecord("", 0, "", 0, "", None, None).__dict__) | {
    "message",
    "asctime",
}


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time, level, logger, message and any ``extra=`` fields."""

    def format(self, record: logging.LogRecord) -> str:
        payload: dict[str, Any] = {
            "t": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        payload.update(_extras(record))
        if record.exc_info:
            payload["exc"] = self.formatException(record.exc_info)
        return json.dumps(payload, default=str)


def _extras(record: logging.LogRecord) -> dict[str, Any]:
    """The ``extra=`` fields of ``record`` (what the call added to the standard ones)."""
    return {
        k: v for k, v in record.__dict__.items() if k not in _RESERVED and not k.startswith("_")
    }


class TextFormatter(logging.Formatter):
    """``HH:MM:SS LEVEL logger: message (key=value, ...)``: the ``extra=`` fields (which
    link, which vehicle, how many) follow the message, as the JSON lines carry them."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)-7s %(name)s: %(message)s", "%H:%M:%S")

    def format(self, record: logging.LogRecord) -> str:
        extras = _extras(record)
        text = super().format(record)
        if not extras:
            return text
        fields = ", ".join(f"{k}={v}" for k, v in extras.items())
        head, nl, tail = text.partition("\n")  # a traceback stays below the line
        return f"{head} ({fields}){nl}{tail}"


def configure_logging(level: str = "INFO", fmt: str = "text") -> None:
    """Configure the root logger once, on stderr (stdout stays for command output)."""
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(TextFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
