"""What a MAVLink telemetry log (``.tlog``) offers the estimator, found before it is replayed.

A tlog replays through MAVLink ingest (:func:`glmav_observer.app_replay.replay_tlog`). The
estimator needs three streams from one vehicle (one system id): an attitude (``ATTITUDE``),
an IMU (``HIGHRES_IMU``, ``SCALED_IMU`` or ``RAW_IMU``) and a velocity measurement
(``LOCAL_POSITION_NED``). A log without one of them is refused ("unsupported: this log has
no X", :class:`~glmav_observer.ingest.logfiles.streams.UnsupportedLogError`) instead of
replaying to estimates that measure nothing (``GLOBAL_POSITION_INT`` carries a velocity too,
but the service does not take it as the measurement: a vehicle sending both would be
measured twice).

:func:`scan_tlog` decodes frames from the start of the log and stops as soon as one vehicle
has sent all three (in ArduPilot's logs, when its EKF first reports a position: 0.1-42 %
into the logs of tests/data). The replay goes on from there with the frames the scan
decoded (:meth:`TlogScan.replay_records`): no frame is decoded twice. Only a log that lacks
a stream is decoded to its end, and that log is refused, not replayed. The decoded prefix
is held in memory up to :data:`MAX_PREFIX_RECORDS` frames; past that it is dropped and the
replay decodes the log again from its start (a log whose velocity first comes after
hours of telemetry).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from glmav_observer.ingest.framing import FrameCounters, TlogRecord, iter_tlog
from glmav_observer.ingest.logfiles.streams import LogError, UnsupportedLogError
from glmav_observer.ingest.pipeline import FIELDS_READ

#: What the estimator needs from a vehicle: (what, the messages that give it).
TLOG_NEEDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("attitude", ("ATTITUDE",)),
    ("IMU data", ("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU")),
    ("velocity measurement", ("LOCAL_POSITION_NED",)),
)
_NEED_OF: dict[str, int] = {name: k for k, (_, names) in enumerate(TLOG_NEEDS) for name in names}
_ALL = frozenset(range(len(TLOG_NEEDS)))
#: Decoded frames the scan keeps for the replay: 1.5 kB each (measured on an ArduPilot
#: tlog), at most 150 MB: 10 times the longest prefix in tests/data (10,023 frames)
MAX_PREFIX_RECORDS = 100_000


@dataclass
class TlogScan:
    """What :func:`scan_tlog` found: the needs each system id met, and how far it read."""

    data: bytes = field(repr=False)
    #: bytes decoded before the scan stopped (``size_bytes`` when it read to the end)
    scanned_bytes: int = 0
    frames_ok: int = 0
    #: per system id, the indices (into :data:`TLOG_NEEDS`) of the needs it met
    needs_met: dict[int, set[int]] = field(default_factory=dict)
    counters: FrameCounters = field(default_factory=FrameCounters)
    #: the frames decoded so far (None: more than MAX_PREFIX_RECORDS, dropped) and the
    #: decoder, paused where the scan stopped
    _prefix: list[TlogRecord] | None = field(default_factory=list, repr=False)
    _rest: Iterator[TlogRecord] | None = field(default=None, repr=False)

    @property
    def size_bytes(self) -> int:
        return len(self.data)

    def replay_records(self) -> tuple[Iterator[TlogRecord], FrameCounters]:
        """Every frame of the log in order, and the counters the decoding fills (once: the
        frames the scan decoded, then the rest of the log from where it stopped)."""
        prefix, rest = self._prefix, self._rest
        self._prefix, self._rest = None, None
        if prefix is None or rest is None:  # dropped (or already replayed): decode again
            self.counters = FrameCounters()
            return iter_tlog(self.data, self.counters, FIELDS_READ), self.counters
        return itertools.chain(prefix, rest), self.counters

    @property
    def complete_vehicle(self) -> int | None:
        """A system id that sent everything the estimator needs (None: no vehicle did)."""
        return next((s for s, met in sorted(self.needs_met.items()) if met == _ALL), None)

    def missing(self) -> str:
        """What the log lacks, named with the messages looked for ("" when nothing)."""
        if self.complete_vehicle is not None:
            return ""
        # the vehicle that came closest (most needs met, then the lowest system id)
        best = max(sorted(self.needs_met.items()), key=lambda kv: len(kv[1]), default=None)
        met = best[1] if best is not None else set()
        lacking = [f"{what} ({_either(names)})" for k, (what, names) in enumerate(TLOG_NEEDS)
                   if k not in met]  # fmt: skip
        where = f" from vehicle {best[0]}" if best is not None and len(self.needs_met) > 1 else ""
        return ", no ".join(lacking) + where


def _either(names: tuple[str, ...]) -> str:
    """``A``, ``A or B``, ``A, B or C``."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def scan_tlog(data: bytes) -> TlogScan:
    """Decode ``data`` (a tlog image) until one vehicle has sent all the estimator needs."""
    scan = TlogScan(data)
    needs = scan.needs_met
    # framed for the service's replay: the messages no ingest reads a field of header-only
    records = iter_tlog(data, scan.counters, FIELDS_READ)
    scan._rest = records
    for rec in records:
        scan.frames_ok += 1
        if scan._prefix is not None:
            scan._prefix.append(rec)
            if len(scan._prefix) > MAX_PREFIX_RECORDS:
                scan._prefix = None
        k = _NEED_OF.get(rec.msg.get_type())
        if k is None:
            continue
        met = needs.setdefault(rec.msg.get_srcSystem(), set())
        if k not in met:
            met.add(k)
            if met == _ALL:
                scan.scanned_bytes = rec.offset
                return scan
    scan.scanned_bytes = len(data)
    scan._rest = iter(())  # read to the end: nothing left to decode
    return scan


def check_tlog(path: str | Path) -> TlogScan:
    """Refuse a tlog the estimator cannot use, before anything is replayed or written.

    Raises :class:`LogError` for a file in which no frame decodes ("nothing could be read
    as MAVLink") and :class:`UnsupportedLogError` for a log that lacks a stream
    (:data:`TLOG_NEEDS`); returns the scan otherwise."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise LogError(f"{path}: cannot read ({err.strerror})") from err
    scan = scan_tlog(data)
    if scan.frames_ok == 0:
        counts = ", ".join(f"{k}={v}" for k, v in scan.counters.as_dict().items())
        raise LogError(
            f"{path}: nothing could be read as MAVLink ({len(data)} bytes, 0 frames decoded"
            f"{': ' + counts if counts else ''})"
        )
    missing = scan.missing()
    if missing:
        raise UnsupportedLogError(path, missing)
    return scan
