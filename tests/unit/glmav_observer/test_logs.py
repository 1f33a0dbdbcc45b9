"""The service's log lines: text for people and JSON lines carry the same fields."""

from __future__ import annotations

import json
import logging

from glmav_observer.logs import JsonFormatter, TextFormatter


def _record(msg: str, **extra: object) -> logging.LogRecord:
    logger = logging.getLogger("glmav_observer.test")
    rec = logger.makeRecord(logger.name, logging.WARNING, __file__, 1, msg, (), None, extra=extra)
    rec.created = 0.0  # 00:00:00 UTC (the text line's clock is local time: not asserted)
    return rec


def test_a_text_line_says_which_link_and_how_many() -> None:
    """The ``extra=`` fields (which link, how many) were in the JSON lines only: the text
    line said "the kernel dropped datagrams" without naming the link."""
    rec = _record("the kernel dropped datagrams", link="udpin:0.0.0.0:14550", dropped=120)
    line = TextFormatter().format(rec)
    assert line.endswith(
        "WARNING glmav_observer.test: the kernel dropped datagrams "
        "(link=udpin:0.0.0.0:14550, dropped=120)"
    )
    payload = json.loads(JsonFormatter().format(rec))
    assert (payload["link"], payload["dropped"], payload["msg"]) == (
        "udpin:0.0.0.0:14550",
        120,
        "the kernel dropped datagrams",
    )


def test_a_line_without_fields_is_unchanged_and_a_traceback_stays_below() -> None:
    assert (
        TextFormatter()
        .format(_record("link open"))
        .endswith("WARNING glmav_observer.test: link open")
    )
    try:
        raise ValueError("boom")
    except ValueError:
        import sys

        rec = _record("sink failed", sink="zenoh")
        rec.exc_info = sys.exc_info()
    first, _, rest = TextFormatter().format(rec).partition("\n")
    assert first.endswith("sink failed (sink=zenoh)")
    assert rest.startswith("Traceback") and rest.rstrip().endswith("ValueError: boom")
