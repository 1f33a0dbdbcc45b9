"""The sinks a configuration and the command line ask for (:func:`open_sinks`: file, Zenoh,
MAVLink out, Rerun; the Zenoh and Rerun modules are imported only when enabled), and the
checks of an output before it is opened (:class:`OutputError`).
"""

from __future__ import annotations

from glmav_observer.config import ServiceConfig
from glmav_observer.configurations import AIDED, CONFIGS
from glmav_observer.publish.file_sink import FileSink
from glmav_observer.publish.output_files import check_output_target
from glmav_observer.publish.sink import Sink


class OutputError(ValueError):
    """An output the user named cannot be written (the message says which and why)."""


def check_tcp_port_free(host: str, port: int, what: str) -> None:
    """:class:`OutputError` if another process listens on ``host:port`` (checked before a
    server that would otherwise start without it and keep running)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # ignore TIME_WAIT only
        try:
            s.bind((host, port))
        except OSError as err:
            raise OutputError(
                f"{what}: {host}:{port} is taken by another process ({err.strerror})"
            ) from None


def describe_outputs(
    config: ServiceConfig, *, out: str | None = None, rerun_mode: str | None = None
) -> list[str]:
    """One line per output :func:`open_sinks` would open (for the log at start): where
    the estimates go and what of them."""
    from glmav_observer.publish.zenoh_keys import alive_key

    lines: list[str] = []
    path = out if out is not None else config.out
    if path:
        lines.append(f"file {path}: every record")
    z = config.zenoh
    if z.enabled:
        session = z.config or "the embedded loopback peer (no router needed)"
        lines.append(
            f"zenoh via {session}: keys {z.prefix}/<sysid>/velocity/<config>, "
            f"{z.prefix}/<sysid>/health, .../measurement, .../truth "
            f"(liveliness {alive_key(z.prefix, config.service_id)}); "
            f"{z.reads().describe()}"
        )
    m = config.mavlink_out
    if m.enabled:
        lines.append(f"mavlink out {m.link}: active at {m.rate_hz:g} Hz, events, health")
    mode = rerun_mode if rerun_mode is not None else config.rerun.mode
    if mode != "off":
        lines.append(f"rerun {mode}: every record")
    return lines


def open_sinks(
    config: ServiceConfig,
    *,
    out: str | None = None,
    zenoh_config: str | None = None,
    zenoh_enabled: bool | None = None,
    rerun_mode: str | None = None,
    recording_name: str | None = None,
    rerun_fallback_save_path: str | None = None,
    zenoh_check_unique: bool = True,
    force: bool = False,
    out_shared: bool = False,
) -> list[Sink]:
    """The sinks asked for by the config and the command line (closed by the caller).

    ``rerun_fallback_save_path``: ``--rerun spawn`` without a display saves there instead
    (None: the Rerun sink's default). ``zenoh_check_unique``: see
    :func:`~glmav_observer.publish.zenoh_sink.open_zenoh_sink`. ``force``: overwrite an
    existing regular file (:mod:`glmav_observer.publish.output_files`); ``out_shared``:
    append to the file ``out`` that other workers share (``serve --workers N``)."""
    sinks: list[Sink] = []
    try:
        path = out if out is not None else config.out
        if path:
            sinks.append(FileSink(path, force=force, shared=out_shared))
        z_on = config.zenoh.enabled if zenoh_enabled is None else zenoh_enabled
        if z_on:
            from glmav_observer.publish.zenoh_sink import open_zenoh_sink

            zcfg = zenoh_config if zenoh_config is not None else (config.zenoh.config or None)
            sinks.append(
                open_zenoh_sink(
                    zcfg,
                    prefix=config.zenoh.prefix,
                    decimation=config.zenoh.decimation,
                    encoding=config.zenoh.encoding,
                    service_id=config.service_id,
                    effective_config=config.effective(),
                    check_unique=zenoh_check_unique,
                    reads=config.zenoh.reads(),
                )
            )
        if config.mavlink_out.enabled:
            from glmav_observer.publish.mavlink_out import MavlinkOutSink

            sinks.append(MavlinkOutSink(config.mavlink_out, signing_key=config.signing_key))
        mode = rerun_mode if rerun_mode is not None else config.rerun.mode
        if mode != "off":
            from glmav_observer.publish.rerun import open_rerun_sink
            from glmav_observer.publish.rerun.viewer import (
                DEFAULT_FALLBACK_SAVE_PATH,
                DEFAULT_GRPC_PORT,
                DEFAULT_WEB_PORT,
            )

            if mode.startswith("save:"):
                check_output_target(mode.removeprefix("save:"), force=force)
            elif mode == "serve":
                for port in (DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT):
                    check_tcp_port_free(config.rerun.serve_bind, port, "--rerun serve")

            sinks.append(
                open_rerun_sink(
                    mode,
                    configs=(*CONFIGS, AIDED) if config.estimation.aero_aiding else CONFIGS,
                    decimation=config.rerun.decimation,
                    serve_bind=config.rerun.serve_bind,
                    recording_name=recording_name,
                    fallback_save_path=rerun_fallback_save_path or DEFAULT_FALLBACK_SAVE_PATH,
                )
            )
    except BaseException:
        for s in sinks:
            s.close()
        raise
    return sinks
