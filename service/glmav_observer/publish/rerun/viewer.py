"""Viewer processes and where the recording goes: spawn, connect, serve, save.

``open_stream`` opens the Rerun recording stream for a parsed mode and returns it with
what the caller must know: the mode in effect (``spawn`` falls back to ``save`` without
a display), the gRPC and web URLs, and the web viewer process to stop at close.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from glmav_observer.publish.rerun.mode import RerunMode, RerunModeError
from glmav_observer.publish.rerun.savefile import partial_path

if TYPE_CHECKING:
    import rerun as rr

log = logging.getLogger(__name__)

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_FALLBACK_SAVE_PATH = "glmav-observer.rrd"


def rerun_executable() -> str | None:
    """The viewer binary shipped in the rerun-sdk wheel (``rerun_cli/rerun``), else PATH.

    The ``rerun`` console script is a Python wrapper that runs this binary as a child;
    signals sent to the wrapper do not reach the viewer (SIGTERM orphans it, SIGINT kills
    it without finishing its file), so processes this sink starts run the binary itself.
    """
    try:
        import rerun_cli  # type: ignore[import-untyped]  # the wheel's viewer binary, no stubs

        binary = Path(rerun_cli.__file__).with_name("rerun.exe" if os.name == "nt" else "rerun")
        if binary.is_file() and os.access(binary, os.X_OK):
            return str(binary)
    except ImportError:
        pass
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file() and os.access(beside, os.X_OK):
        return str(beside)
    return shutil.which("rerun")


def has_display(env: Mapping[str, str]) -> bool:
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY")) or sys.platform in (
        "darwin",
        "win32",
    )


@dataclass(slots=True)
class Opened:
    """A recording stream with its sinks set, and what the sink reports about it."""

    recording: rr.RecordingStream
    mode: RerunMode
    grpc_url: str | None = None
    web_url: str | None = None
    web_process: subprocess.Popen[bytes] | None = None
    #: ``save``: the temporary file Rerun writes, renamed to the target when complete
    save_partial: Path | None = None


def stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 5.0) -> None:
    """Terminate a process this module started; kill it if it does not exit in time."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def open_stream(
    mode: RerunMode,
    *,
    application_id: str,
    recording_name: str | None,
    environ: Mapping[str, str],
    fallback_save_path: str | None,
    serve_bind: str,
    grpc_port: int,
    web_port: int | None,
    spawn_port: int,
    server_memory_limit: str,
) -> Opened:
    """A recording stream on the vehicle's clock only, sending where ``mode`` says."""
    import rerun as rr

    rec = rr.RecordingStream(application_id)
    rec.set_log_time_enabled(False)  # the vehicle's clock only (vehicle_time)
    rec.set_log_tick_enabled(False)
    if recording_name:
        rec.send_recording_name(recording_name)
    out = Opened(rec, mode)

    if mode.kind == "spawn":
        exe = rerun_executable()
        reason = None
        if not has_display(environ):
            reason = "no DISPLAY or WAYLAND_DISPLAY"
        elif exe is None:
            reason = "no rerun executable found"
        else:
            try:
                rr.spawn(
                    port=spawn_port,
                    recording=rec,
                    executable_path=exe,
                    hide_welcome_screen=True,
                    memory_limit="25%",
                )
                out.grpc_url = f"rerun+http://127.0.0.1:{spawn_port}/proxy"
            except Exception as exc:  # the viewer binary failed to start
                reason = f"spawning the viewer failed: {exc}"
        if reason is not None:
            if fallback_save_path is None:
                raise RerunModeError(f"rerun mode 'spawn': cannot start a viewer ({reason})")
            out.mode = RerunMode("save", fallback_save_path)
            log.warning(
                "rerun: cannot spawn a viewer (%s); saving to %s instead. Open it with: rerun %s",
                reason,
                fallback_save_path,
                fallback_save_path,
            )
    if out.mode.kind == "connect":
        assert out.mode.target is not None
        rec.connect_grpc(out.mode.target)
        out.grpc_url = out.mode.target
    elif out.mode.kind == "serve":
        server = rr.GrpcServerSink(
            bind_ip=serve_bind, port=grpc_port, server_memory_limit=server_memory_limit
        )
        rec.set_sinks(server)
        out.grpc_url = f"rerun+http://{serve_bind}:{grpc_port}/proxy"
        if web_port is not None:
            out.web_process = _serve_web_viewer(serve_bind, web_port, out.grpc_url)
            if out.web_process is not None:
                out.web_url = f"http://{serve_bind}:{web_port}/?url={out.grpc_url}"
        log.info(
            "rerun: serving gRPC at %s%s",
            out.grpc_url,
            f", web viewer at {out.web_url}" if out.web_url else "",
        )
    elif out.mode.kind == "save":
        assert out.mode.target is not None
        Path(out.mode.target).parent.mkdir(parents=True, exist_ok=True)
        # written under a temporary name and renamed once complete (.savefile)
        try:
            out.save_partial = partial_path(out.mode.target)
        except OSError as err:
            raise RerunModeError(f"{out.mode.target}: cannot write: {err.strerror}") from None
        rec.save(str(out.save_partial))
    return out


def _serve_web_viewer(bind: str, port: int, grpc_url: str) -> subprocess.Popen[bytes] | None:
    """The web viewer on ``bind:port``, pointed at ``grpc_url`` (None without the binary).

    The rerun CLI binds the web viewer where told (``--bind``); ``rr.serve_web_viewer``
    (0.41) always binds 0.0.0.0, so the CLI hosts it here.
    """
    exe = rerun_executable()
    if exe is None:
        log.warning("rerun: no rerun executable found; the web viewer is not served")
        return None
    return subprocess.Popen(
        [exe, "--serve-web", "--bind", bind, "--web-viewer-port", str(port), grpc_url],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
