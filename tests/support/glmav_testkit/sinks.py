"""A sink that keeps every record in memory (the sink protocol: write, close)."""

from __future__ import annotations

from glmav_observer.records import Record, TruthRecord, VelocityRecord


class MemorySink:
    def __init__(self) -> None:
        self.records: list[Record] = []

    def write(self, record: Record) -> None:
        self.records.append(record)

    def close(self) -> None:
        pass


class AidedSink:
    """Keeps what the lost-axis aiding tests compare: the ``aided`` records, the ``active``
    records by time, and the truth."""

    def __init__(self) -> None:
        self.aided: list[VelocityRecord] = []
        self.active: dict[float, VelocityRecord] = {}
        self.truth: list[TruthRecord] = []

    def write(self, r: Record) -> None:
        if isinstance(r, VelocityRecord) and r.config == "aided":
            self.aided.append(r)
        elif isinstance(r, VelocityRecord) and r.config == "active":
            self.active[r.t_boot_s] = r
        elif isinstance(r, TruthRecord):
            self.truth.append(r)

    def close(self) -> None:
        return None
