"""The one small interface every sink implements (design.md, "Layout and data flow")."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from glmav_observer.records import Record


@runtime_checkable
class Sink(Protocol):
    """Receives every record the service produces, in vehicle-time order per vehicle.

    ``write`` must not block the estimation loop for long (a slow consumer is the
    sink's problem: decimate, queue with a bound, or drop and count). ``close`` flushes
    and releases whatever the sink opened; it is called once, also on SIGINT/SIGTERM.
    """

    def write(self, record: Record) -> None: ...

    def close(self) -> None: ...
