"""The Rerun sink: estimates, measurements, truth and health as a Rerun recording.

Modes (the ``--rerun`` flag, ``[rerun] mode`` in the service configuration):

- ``off``: nothing is opened; ``write`` returns at once.
- ``spawn``: start a local viewer (the ``rerun`` binary of the installed wheel) and
  stream to it. On a machine without a display (no ``DISPLAY`` / ``WAYLAND_DISPLAY``)
  or when the viewer cannot be started, the sink falls back to ``save:<fallback path>``
  and says so in the log; :attr:`RerunSink.effective_mode` tells the caller.
- ``connect`` or ``connect:URL``: stream to a running viewer over gRPC
  (``rerun+http://HOST:PORT/proxy``; default ``rerun+http://127.0.0.1:9876/proxy``).
- ``serve``: host a gRPC server that viewers can join late (it buffers up to
  ``server_memory_limit``) bound to ``serve_bind`` (loopback by default), plus the web
  viewer over HTTP on the same interface.
- ``save:PATH``: write an ``.rrd`` file (also what ``replay --rrd PATH`` uses).

Time is the vehicle's clock: every row is on the ``vehicle_time`` timeline (a duration,
``t_boot_s``); the host's clock timelines (``log_time``, ``log_tick``) are disabled.
The parts: :mod:`.paths` (entity paths, names, colours), :mod:`.blueprint` (layout and
static styles), :mod:`.buffer` (records to columns), :mod:`.send` (the sender thread,
``rr.send_columns``), :mod:`.viewer` (viewer processes, where the stream goes).
"""

from __future__ import annotations

import logging
import subprocess
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from glmav_observer.publish.rerun.buffer import RecordBuffer
from glmav_observer.publish.rerun.mode import RerunMode, RerunModeError, parse_rerun_mode
from glmav_observer.publish.rerun.savefile import disconnect_bounded, finish, flush_file
from glmav_observer.publish.rerun.send import RerunStats, Sender
from glmav_observer.publish.rerun.viewer import (
    DEFAULT_FALLBACK_SAVE_PATH,
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    open_stream,
    stop_process,
)
from glmav_observer.records import CONFIGS, Record

if TYPE_CHECKING:
    import rerun as rr

log = logging.getLogger(__name__)


class RerunSink:
    """A :class:`~glmav_observer.publish.sink.Sink` that logs records to a Rerun recording.

    Build it with :func:`open_rerun_sink`. ``recording`` None means ``off``. ``configs``:
    the bank's configuration names in bank order (``records.CONFIGS``).
    """

    def __init__(
        self,
        recording: rr.RecordingStream | None,
        *,
        mode: RerunMode,
        configs: Sequence[str] = CONFIGS,
        decimation: int = 1,
        flush_period_s: float = 0.5,
        batch_rows: int = 20_000,
        max_queued_batches: int = 64,
        truth_max_gap_s: float = 0.1,
        truth_timeout_s: float = 1.0,
        arming_timeout_s: float = 5.0,
        web_process: subprocess.Popen[bytes] | None = None,
        grpc_url: str | None = None,
        web_url: str | None = None,
        requested_mode: RerunMode | None = None,
        save_partial: Path | None = None,
    ) -> None:
        if decimation < 1:
            raise ValueError(f"rerun decimation must be >= 1, got {decimation}")
        if not configs or len(set(configs)) != len(configs) or "active" in configs:
            raise ValueError(
                f"rerun configs must be distinct configuration names, not 'active', got {configs!r}"
            )
        self.mode = mode
        self.requested_mode = requested_mode or mode
        self.grpc_url = grpc_url
        self.web_url = web_url
        self.configs = tuple(configs)
        self.stats = RerunStats()
        self._rec = recording
        self._live = mode.live
        self._web_process = web_process
        self._save_partial = save_partial
        self._buffer = RecordBuffer(
            self.configs,
            live=mode.live,
            decimation=decimation,
            flush_period_s=flush_period_s,
            batch_rows=batch_rows,
            truth_max_gap_s=truth_max_gap_s,
            truth_timeout_s=truth_timeout_s,
            arming_timeout_s=arming_timeout_s,
        )
        self._lock = threading.Lock()
        self._closed = False
        self._sender: Sender | None = None
        if recording is not None:
            self._sender = Sender(
                recording,
                self.configs,
                self.stats,
                live=mode.live,
                max_queued_batches=max_queued_batches,
            )

    @property
    def effective_mode(self) -> str:
        """The mode in use (``save:PATH`` after a spawn fell back, for example)."""
        return str(self.mode)

    def queued_batches(self) -> int:
        """Batches waiting for the sender thread (bounded by ``max_queued_batches``)."""
        return 0 if self._sender is None else self._sender.qsize()

    def write(self, record: Record) -> None:
        """Buffer one record; hand what is due to the sender thread (never waits on a
        viewer in live modes)."""
        if self._sender is None:
            return
        with self._lock:
            if self._closed:
                return
            self.stats.records += 1
            for batch in self._buffer.add(record):
                self._sender.submit(batch)
            self.stats.error_rows_without_truth = self._buffer.error_rows_without_truth

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Send everything buffered and wait until the sender thread has handed it to Rerun.

        Returns False when the sender did not drain within ``timeout_s`` (a stuck viewer).
        """
        if self._sender is None:
            return True
        with self._lock:
            for batch in self._buffer.flush(final=False):
                self._sender.submit(batch)
            self.stats.error_rows_without_truth = self._buffer.error_rows_without_truth
        return self._sender.drain(timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Flush, finish the file or stream, stop the sender thread and the web viewer.

        ``save``: the file is renamed to its path only if it reads back whole; otherwise
        :class:`~glmav_observer.publish.rerun.savefile.RrdSaveError` (after the rest is
        closed), and no file that looks whole is left (``.savefile``)."""
        if self._closed:
            return
        rec, sender = self._rec, self._sender
        write_error: str | None = None
        if rec is not None and sender is not None:
            with self._lock:
                for batch in self._buffer.flush(final=True):
                    sender.submit(batch)
                self.stats.error_rows_without_truth = self._buffer.error_rows_without_truth
                self._closed = True
            # a file always drains: wait for it; a viewer may be gone: bounded wait
            stopped = sender.stop(timeout_s if self._live else None)
            if not stopped:
                log.warning("rerun: the viewer did not take the data within %.0f s", timeout_s)
            elif self._save_partial is not None:
                # a file: flushed while it grows; after a failed write, a bounded disconnect
                write_error = flush_file(rec, self._save_partial)
                if write_error is not None:
                    disconnect_bounded(rec)
                else:
                    rec.disconnect()
            else:
                # a gone viewer: rerun's flush raises after the timeout, and its disconnect
                # waits up to 5 s more for a last connection attempt, then drops the data
                try:
                    rec.flush(timeout_sec=min(timeout_s, 2.0))
                except Exception as err:
                    log.warning("rerun: flush at close failed: %s", err)
                rec.disconnect()
        self._closed = True
        self._rec = None
        if self._web_process is not None:
            stop_process(self._web_process)
            self._web_process = None
        log.info("rerun sink closed (%s): %s", self.mode, self.stats)
        partial, self._save_partial = self._save_partial, None
        if partial is not None and self.mode.target is not None:
            finish(partial, self.mode.target, write_error)

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_rerun_sink(
    mode: str,
    *,
    configs: Sequence[str] = CONFIGS,
    decimation: int = 1,
    serve_bind: str = "127.0.0.1",
    application_id: str = "glmav-observer",
    recording_name: str | None = None,
    fallback_save_path: str | None = DEFAULT_FALLBACK_SAVE_PATH,
    grpc_port: int = DEFAULT_GRPC_PORT,
    web_port: int | None = DEFAULT_WEB_PORT,
    spawn_port: int = DEFAULT_GRPC_PORT,
    server_memory_limit: str = "512MiB",
    flush_period_s: float = 0.5,
    batch_rows: int = 20_000,
    max_queued_batches: int = 64,
    arming_timeout_s: float = 5.0,
    environ: Mapping[str, str] | None = None,
) -> RerunSink:
    """Open the Rerun sink for ``mode`` (see the module docstring); RerunModeError if bad.

    ``configs`` the bank's configuration names, in bank order. ``decimation`` (live
    modes) logs every Nth estimator update. ``serve``: the gRPC server on
    ``serve_bind:grpc_port``, the web viewer on ``serve_bind:web_port`` (None: no web
    viewer). ``spawn`` without a usable display falls back to
    ``save:fallback_save_path`` (None: raise RerunModeError instead).
    ``flush_period_s`` is the live flush period in vehicle time; ``batch_rows`` the
    rows per vehicle buffered between flushes in ``save`` mode; ``max_queued_batches``
    bounds the batches waiting for the sender thread (live modes drop beyond it).
    ``arming_timeout_s``: warn in the event log when fault detection has not armed on an
    axis that long after its warm-up began.
    """
    import os

    parsed = parse_rerun_mode(mode)
    if decimation < 1:
        raise RerunModeError(f"rerun decimation must be >= 1, got {decimation}")
    common: dict[str, Any] = {
        "configs": configs,
        "decimation": decimation,
        "flush_period_s": flush_period_s,
        "batch_rows": batch_rows,
        "max_queued_batches": max_queued_batches,
        "arming_timeout_s": arming_timeout_s,
    }
    if parsed.kind == "off":
        return RerunSink(None, mode=parsed, **common)
    opened = open_stream(
        parsed,
        application_id=application_id,
        recording_name=recording_name,
        environ=os.environ if environ is None else environ,
        fallback_save_path=fallback_save_path,
        serve_bind=serve_bind,
        grpc_port=grpc_port,
        web_port=web_port,
        spawn_port=spawn_port,
        server_memory_limit=server_memory_limit,
    )
    return RerunSink(
        opened.recording,
        mode=opened.mode,
        requested_mode=parsed,
        web_process=opened.web_process,
        grpc_url=opened.grpc_url,
        web_url=opened.web_url,
        save_partial=opened.save_partial,
        **common,
    )
