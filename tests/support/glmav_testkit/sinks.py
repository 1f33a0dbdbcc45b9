"""A sink that keeps every record in memory (the sink protocol: write, close)."""

from __future__ import annotations

from glmav_observer.records import Record


class MemorySink:
    def __init__(self) -> None:
        self.records: list[Record] = []

    def write(self, record: Record) -> None:
        self.records.append(record)

    def close(self) -> None:
        pass
