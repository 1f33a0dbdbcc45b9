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

Time is the vehicle's clock: every row is on the ``vehicle_time`` timeline (a
duration, ``t_boot_s``); the host's clock timelines (``log_time``, ``log_tick``) are
disabled. Entity paths follow the pipeline (see ``docs/rerun.md``)::

    /vehicle/<sysid>/ingest/measurement/{v_ned/{n,e,d}, v_body/{u,v,w}}
    /vehicle/<sysid>/bank/{v_ned/{n,e,d}, v_body/{u,v,w}}   4 instances: full, c1, c2, c3
    /vehicle/<sysid>/active/{v_ned/..., v_body/..., sigma_lost_mps}
    /vehicle/<sysid>/truth/{v_ned/..., v_body/...}
    /vehicle/<sysid>/error/{v_ned/..., v_body/...}  estimate - truth, 5 instances: the bank, active
    /vehicle/<sysid>/health/{residual, test_ratio, axis_state}   3 instances: n, e, d
    /vehicle/<sysid>/health/state     2 instances: active configuration, isolated axis
    /vehicle/<sysid>/health/events    TextLog: isolations, recoveries, switches
    /world/vehicle/<sysid>            Transform3D (measured position, held attitude)
    /world/vehicle/<sysid>/body       the airframe (static box, FRD)
    /world/vehicle/<sysid>/velocity/{active,truth}   Arrows3D in the body frame

Logging is columnar: rows are buffered per group of entities that share time stamps
and sent as one Arrow record batch per group (one Rerun chunk per entity). A chunk
costs ~50-100 µs whatever its rows, so the configurations of the bank are instances of
one entity per axis (one line each in the plot) rather than entities of their own. Live modes
flush every ``flush_period_s`` of vehicle time and log every ``decimation``-th
velocity record per configuration; ``save`` flushes every ``batch_rows`` rows and
logs everything. All Rerun calls run on one sender thread behind a bounded queue:
``write`` never waits on a viewer. In live modes a full queue drops the batch (counted
in :attr:`RerunSink.stats`); in ``save`` mode it waits (a file does not go away).
"""

from __future__ import annotations

import functools
import logging
import math
import os
import queue
import shutil
import subprocess
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from glmav_observer.estimation.observer import e_exact
from glmav_observer.records import (
    CONFIGS,
    NED_AXES,
    HealthRecord,
    MeasurementRecord,
    Record,
    TruthRecord,
    VelocityRecord,
)

if TYPE_CHECKING:
    import pyarrow as pa  # type: ignore[import-untyped]  # no stubs; not in the mypy overrides
    import rerun as rr
    import rerun.blueprint as rrb

log = logging.getLogger(__name__)

#: The timeline every row is logged on: the vehicle's boot clock (a duration).
TIMELINE = "vehicle_time"
BODY_AXES: tuple[str, str, str] = ("u", "v", "w")
#: The estimate streams: the bank's configurations and the selected one.
ESTIMATES: tuple[str, ...] = (*CONFIGS, "active")
DEFAULT_CONNECT_URL = "rerun+http://127.0.0.1:9876/proxy"
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_FALLBACK_SAVE_PATH = "glmav-observer.rrd"
_URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")

#: Series colours (RGB): one per estimate stream, measurement and truth.
COLORS: dict[str, tuple[int, int, int]] = {
    "full": (31, 119, 180),
    "c1": (255, 127, 14),
    "c2": (44, 160, 44),
    "c3": (148, 103, 189),
    "active": (214, 39, 40),
    "measurement": (160, 160, 160),
    "truth": (240, 228, 66),
}
#: Colours of the n, e, d instances of the health series.
AXIS_COLORS: tuple[tuple[int, int, int], ...] = ((228, 26, 28), (55, 126, 184), (77, 175, 74))
#: Encodings of the state series (a scalar per state so that the viewer plots steps).
ACTIVE_CONFIG_INDEX: dict[str, int] = {c: i for i, c in enumerate(CONFIGS)}
ISOLATED_AXIS_INDEX: dict[str | None, int] = {None: 0, "n": 1, "e": 2, "d": 3}
AXIS_STATE_INDEX: dict[str, int] = {
    "warmup": -1,
    "ok": 0,
    "suspect": 1,
    "recovering": 2,
    "faulty": 3,
}

#: Airframe half sizes (m) in FRD: body diameter D = 0.08, length l = 0.30 (design.md).
_BODY_HALF_SIZES_M = (0.04, 0.04, 0.15)


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


# --------------------------------------------------------------------------- entity paths


def vehicle_path(sysid: int) -> str:
    return f"/vehicle/{sysid}"


def bank_path(sysid: int) -> str:
    """The bank's estimates: each axis entity has one instance per configuration (CONFIGS)."""
    return f"{vehicle_path(sysid)}/bank"


def active_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/active"


def measurement_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/ingest/measurement"


def truth_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/truth"


def error_path(sysid: int) -> str:
    """Estimate − truth: each axis entity has one instance per estimate (ESTIMATES)."""
    return f"{vehicle_path(sysid)}/error"


def health_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/health"


def world_vehicle_path(sysid: int) -> str:
    return f"/world/vehicle/{sysid}"


# --------------------------------------------------------------------------- blueprint


def build_blueprint(sysids: Sequence[int]) -> rrb.Blueprint:
    """The layout, built once per set of vehicles (one tab per vehicle).

    Per vehicle: an overview (u, v, w of every configuration with the measurement and
    the truth; the 3D pose with velocity arrows; residuals, test ratios and the state
    of the isolation), the NED components, the errors against truth and the event log.
    """
    import rerun.blueprint as rrb

    def series(name: str, paths: Sequence[str]) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=name, origin="/", contents=list(paths))

    tabs: list[rrb.Container] = []
    for sysid in sysids:
        sources = [bank_path(sysid), active_path(sysid), measurement_path(sysid), truth_path(sysid)]

        def axis_view(frame: str, axis: str, sources: list[str] = sources) -> rrb.TimeSeriesView:
            return series(f"{axis} ({frame}, m/s)", [f"{s}/{frame}/{axis}" for s in sources])

        h = health_path(sysid)
        overview = rrb.Horizontal(
            rrb.Vertical(*(axis_view("v_body", a) for a in BODY_AXES), name="body velocity"),
            rrb.Vertical(
                rrb.Spatial3DView(
                    name="pose (NED) and velocity",
                    origin="/world",
                    contents=["/world", f"{world_vehicle_path(sysid)}/**"],
                ),
                series("residual (m/s)", [f"{h}/residual"]),
                series("test ratio (>1 fails)", [f"{h}/test_ratio"]),
                series(
                    "state: active config (0 full,1 c1,2 c2,3 c3), isolated axis (0 none,1 n,2 e,3 d)",
                    [f"{h}/state"],
                ),
                row_shares=[3, 2, 2, 2],
            ),
            column_shares=[3, 2],
            name="overview",
        )
        ned = rrb.Vertical(*(axis_view("v_ned", a) for a in NED_AXES), name="NED velocity")
        errors = rrb.Grid(
            *(
                series(f"error {a} ({frame}, m/s)", [f"{error_path(sysid)}/{frame}/{a}"])
                for frame, axes in (("v_body", BODY_AXES), ("v_ned", NED_AXES))
                for a in axes
            ),
            grid_columns=3,
            name="errors vs truth",
        )
        health = rrb.Horizontal(
            rrb.Vertical(
                series(
                    "axis state (-1 warm-up,0 ok,1 suspect,2 recovering,3 faulty)",
                    [f"{h}/axis_state"],
                ),
                series("lost-axis sigma (m/s)", [f"{active_path(sysid)}/sigma_lost_mps"]),
            ),
            rrb.TextLogView(name="events", origin=f"{h}/events"),
            name="health",
        )
        tabs.append(rrb.Tabs(overview, ned, errors, health, name=f"vehicle {sysid}"))
    root: rrb.Container = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs)
    return rrb.Blueprint(
        root,
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="following"),
        auto_views=False,
    )


# --------------------------------------------------------------------------- pure math


def quaternion_xyzw(euler_rad: Sequence[float]) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of the ZYX rotation E (13) (``estimation.observer.e_exact``)."""
    phi, theta, psi = (0.5 * a for a in euler_rad)
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return (
        sf * ct * cp - cf * st * sp,
        cf * st * cp + sf * ct * sp,
        cf * ct * sp - sf * st * cp,
        cf * ct * cp + sf * st * sp,
    )


def interpolate_truth(
    t_est_s: npt.ArrayLike,
    t_truth_s: npt.ArrayLike,
    v_truth: npt.ArrayLike,
    *,
    max_gap_s: float,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Truth at estimate times by linear interpolation between bracketing truth samples.

    ``t_truth_s`` ascending (N,), ``v_truth`` (N, k). Returns ``(ok, v)``: ``ok[i]`` is
    True when ``t_est_s[i]`` lies within [t_truth[0], t_truth[-1]] and the bracketing
    samples are at most ``max_gap_s`` apart (no interpolation across a truth dropout);
    ``v[ok]`` the interpolated truth (rows with ``ok`` False are NaN).
    """
    t_e = np.asarray(t_est_s, dtype=np.float64)
    t_t = np.asarray(t_truth_s, dtype=np.float64)
    v_t = np.asarray(v_truth, dtype=np.float64)
    if v_t.ndim == 1:
        v_t = v_t[:, None]
    out = np.full((len(t_e), v_t.shape[1]), np.nan)
    ok = np.zeros(len(t_e), dtype=bool)
    if len(t_t) == 0 or len(t_e) == 0:
        return ok, out
    hi = np.searchsorted(t_t, t_e, side="left")  # first truth sample at or after t_est
    exact = (hi < len(t_t)) & (t_t[np.minimum(hi, len(t_t) - 1)] == t_e)
    inside = (hi > 0) & (hi < len(t_t))
    lo = np.clip(hi - 1, 0, len(t_t) - 1)
    hi_c = np.clip(hi, 0, len(t_t) - 1)
    gap = t_t[hi_c] - t_t[lo]
    inside &= gap <= max_gap_s
    ok = inside | exact
    w = np.where(gap > 0, (t_e - t_t[lo]) / np.where(gap > 0, gap, 1.0), 0.0)
    interp = v_t[lo] + w[:, None] * (v_t[hi_c] - v_t[lo])
    interp[exact] = v_t[hi_c[exact]]
    out[ok] = interp[ok]
    return ok, out


# --------------------------------------------------------------------------- buffers


@dataclass(slots=True)
class _Group:
    """Scalar entities that share time stamps; ``widths[i]`` instances for ``paths[i]``.

    A row is a flat tuple of ``sum(widths)`` floats, entity after entity.
    """

    paths: list[str]
    widths: list[int]
    t: list[float] = field(default_factory=list)
    rows: list[Sequence[float]] = field(default_factory=list)

    def append(self, t_s: float, values: Sequence[float]) -> None:
        self.t.append(t_s)
        self.rows.append(values)

    def take(self) -> _Batch:
        t, rows = self.t, self.rows
        self.t, self.rows = [], []
        values = np.asarray(rows, dtype=np.float64).reshape(len(t), sum(self.widths))
        return _split(self.paths, self.widths, t, values)


#: (time stamps, [(entity path, values (rows, instances))]): one Arrow batch.
_Batch = tuple[list[float], list[tuple[str, npt.NDArray[np.float64]]]]


def _split(
    paths: Sequence[str], widths: Sequence[int], t: list[float], values: npt.NDArray[np.float64]
) -> _Batch:
    cols: list[tuple[str, npt.NDArray[np.float64]]] = []
    j = 0
    for path, k in zip(paths, widths, strict=True):
        cols.append((path, values[:, j : j + k]))
        j += k
    return t, cols


def _axis_paths(root: str) -> list[str]:
    """The six axis entities of a velocity: body u, v, w then NED n, e, d."""
    return [f"{root}/v_body/{a}" for a in BODY_AXES] + [f"{root}/v_ned/{a}" for a in NED_AXES]


_N_EST = len(ESTIMATES)
_EST_INDEX = {e: i for i, e in enumerate(ESTIMATES)}


@dataclass(slots=True)
class _Vehicle:
    sysid: int
    groups: dict[str, _Group]
    # the estimates of one update (full, c1, c2, c3, active) x (u, v, w, n, e, d), NaN if absent
    cur_t: float | None = None
    cur: list[float] = field(default_factory=lambda: [math.nan] * (_N_EST * 6))
    cur_keep: bool = True
    n_updates: int = 0
    est_t: list[float] = field(default_factory=list)
    est_rows: list[list[float]] = field(default_factory=list)
    pend_t: list[float] = field(default_factory=list)
    pend_rows: list[list[float]] = field(default_factory=list)
    pose_t: list[float] = field(default_factory=list)
    pose_rows: list[tuple[float, ...]] = field(default_factory=list)
    truth_t: list[float] = field(default_factory=list)
    truth_v: list[tuple[float, ...]] = field(default_factory=list)
    seen_truth: bool = False
    active_v_body: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    truth_v_body: tuple[float, float, float] | None = None
    t_flush_s: float | None = None
    t_last_s: float = -math.inf
    rows_buffered: int = 0
    active_config: str | None = None
    faults: frozenset[tuple[str, str, float]] = frozenset()


def _new_vehicle(sysid: int) -> _Vehicle:
    h = health_path(sysid)
    groups = {
        "sigma_lost": _Group([f"{active_path(sysid)}/sigma_lost_mps"], [1]),
        "meas_ned": _Group([f"{measurement_path(sysid)}/v_ned/{a}" for a in NED_AXES], [1] * 3),
        "meas_body": _Group([f"{measurement_path(sysid)}/v_body/{a}" for a in BODY_AXES], [1] * 3),
        "truth": _Group(_axis_paths(truth_path(sysid)), [1] * 6),
        "health": _Group(
            [f"{h}/residual", f"{h}/test_ratio", f"{h}/axis_state", f"{h}/state"], [3, 3, 3, 2]
        ),
    }
    return _Vehicle(sysid=sysid, groups=groups)


@dataclass(slots=True)
class RerunStats:
    """Counters of what the sink did (all since it was opened)."""

    records: int = 0
    rows_logged: int = 0
    batches_sent: int = 0
    batches_dropped: int = 0
    rows_dropped: int = 0
    error_rows_without_truth: int = 0
    send_errors: int = 0


_INDEX_FIELD_META = {b"rerun:kind": b"index", b"rerun:index_name": TIMELINE.encode()}


#: A component column: (entity path, component, values). ``values`` (rows, k):
#: for ``Scalars:scalars`` k instances per row (list<double>); for a vector component
#: one instance per row of k float32 (list<fixed_size_list<float32, k>>).
_Column = tuple[str, str, npt.NDArray[np.float64]]

#: component -> (archetype, component type) of the components this sink writes
_COMPONENTS: dict[str, tuple[str, str]] = {
    "Scalars:scalars": ("rerun.archetypes.Scalars", "rerun.components.Scalar"),
    "Transform3D:translation": ("rerun.archetypes.Transform3D", "rerun.components.Translation3D"),
    "Transform3D:quaternion": ("rerun.archetypes.Transform3D", "rerun.components.RotationQuat"),
    "Arrows3D:vectors": ("rerun.archetypes.Arrows3D", "rerun.components.Vector3D"),
}


@functools.lru_cache(maxsize=1024)
def _schema(columns: tuple[tuple[str, str, int], ...]) -> pa.Schema:
    """The batch schema for (entity path, component, width) columns (cached: fixed per group)."""
    import pyarrow as pa

    fields = [pa.field(TIMELINE, pa.duration("ns"), nullable=False, metadata=_INDEX_FIELD_META)]
    for path, component, width in columns:
        archetype, component_type = _COMPONENTS[component]
        if component == "Scalars:scalars":
            dtype = pa.list_(pa.float64())
        else:
            dtype = pa.list_(pa.list_(pa.field("item", pa.float32(), nullable=False), width))
        meta = {
            b"rerun:kind": b"data",
            b"rerun:archetype": archetype.encode(),
            b"rerun:component": component.encode(),
            b"rerun:component_type": component_type.encode(),
            b"rerun:entity_path": path.encode(),
        }
        fields.append(pa.field(f"{path}:{component}", dtype, metadata=meta))
    return pa.schema(fields)


def record_batch(t_s: Sequence[float], columns: Sequence[_Column]) -> pa.RecordBatch:
    """One Arrow batch: the ``vehicle_time`` index and component columns of many entities.

    Rerun splits it into one chunk per entity (``rr.send_record_batch``): one call instead
    of one ``send_columns`` per entity, at about a third of the cost.
    """
    import pyarrow as pa

    n = len(t_s)
    t_ns = np.rint(np.asarray(t_s, dtype=np.float64) * 1e9).astype(np.int64)
    schema = _schema(tuple((path, comp, v.shape[1]) for path, comp, v in columns))
    arrays: list[pa.Array] = [pa.array(t_ns, type=pa.duration("ns"))]
    for (_, comp, values), fld in zip(columns, list(schema)[1:], strict=True):
        k = values.shape[1]
        if comp == "Scalars:scalars":
            offsets = pa.array(np.arange(0, k * n + 1, k, dtype=np.int32))
            flat = pa.array(np.ascontiguousarray(values, dtype=np.float64).reshape(-1))
        else:
            offsets = pa.array(np.arange(n + 1, dtype=np.int32))
            items = pa.array(np.ascontiguousarray(values, dtype=np.float32).reshape(-1))
            flat = pa.FixedSizeListArray.from_arrays(items, type=fld.type.value_type)
        arrays.append(pa.ListArray.from_arrays(offsets, flat, type=fld.type))
    return pa.RecordBatch.from_arrays(arrays, schema=schema)


def _scalars(cols: Sequence[tuple[str, npt.NDArray[np.float64]]]) -> list[_Column]:
    return [(path, "Scalars:scalars", values) for path, values in cols]


# --------------------------------------------------------------------------- the sink

_Job = Callable[["rr.RecordingStream"], int]


class RerunSink:
    """A :class:`~glmav_observer.publish.sink.Sink` that logs records to a Rerun recording.

    Build it with :func:`open_rerun_sink`. ``recording`` None means ``off``.
    """

    def __init__(
        self,
        recording: rr.RecordingStream | None,
        *,
        mode: RerunMode,
        decimation: int = 1,
        flush_period_s: float = 0.5,
        batch_rows: int = 20_000,
        max_queued_batches: int = 64,
        truth_max_gap_s: float = 0.1,
        truth_timeout_s: float = 1.0,
        web_process: subprocess.Popen[bytes] | None = None,
        grpc_url: str | None = None,
        web_url: str | None = None,
        requested_mode: RerunMode | None = None,
    ) -> None:
        if decimation < 1:
            raise ValueError(f"rerun decimation must be >= 1, got {decimation}")
        self.mode = mode
        self.requested_mode = requested_mode or mode
        self.grpc_url = grpc_url
        self.web_url = web_url
        self.stats = RerunStats()
        self._rec = recording
        self._live = mode.live
        self._decimation = decimation if mode.live else 1
        self._flush_period_s = flush_period_s
        self._batch_rows = batch_rows
        self._truth_max_gap_s = truth_max_gap_s
        self._truth_timeout_s = truth_timeout_s
        self._web_process = web_process
        self._vehicles: dict[int, _Vehicle] = {}
        self._lock = threading.Lock()
        self._closed = False
        self._queue: queue.Queue[_Job | None] = queue.Queue(maxsize=max_queued_batches)
        self._thread: threading.Thread | None = None
        if recording is not None:
            self._thread = threading.Thread(
                target=self._sender, name="rerun-sender", args=(recording,), daemon=True
            )
            self._thread.start()

    @property
    def effective_mode(self) -> str:
        """The mode in use (``save:PATH`` after a spawn fell back, for example)."""
        return str(self.mode)

    # ------------------------------------------------------------------ write side

    def write(self, record: Record) -> None:
        """Buffer one record; hand full buffers to the sender thread (never waits on a viewer
        in live modes)."""
        if self._rec is None:
            return
        with self._lock:
            if self._closed:
                return
            self.stats.records += 1
            veh = self._vehicles.get(record.sysid)
            if veh is None:
                veh = self._add_vehicle(record.sysid)
            t = record.t_boot_s
            if isinstance(record, VelocityRecord):
                self._on_velocity(veh, record)
            elif isinstance(record, MeasurementRecord):
                self._on_measurement(veh, record)
            elif isinstance(record, TruthRecord):
                self._on_truth(veh, record)
            elif isinstance(record, HealthRecord):
                self._on_health(veh, record)
            veh.t_last_s = max(veh.t_last_s, t)
            if veh.t_flush_s is None:
                veh.t_flush_s = t
            if self._live:
                due = t - veh.t_flush_s >= self._flush_period_s
            else:
                due = veh.rows_buffered >= self._batch_rows
            if due or veh.rows_buffered >= 4 * self._batch_rows:
                self._flush_vehicle(veh, final=False)
                veh.t_flush_s = t

    def _on_velocity(self, veh: _Vehicle, r: VelocityRecord) -> None:
        i = _EST_INDEX.get(r.config)
        if i is None:
            return
        if i == _N_EST - 1:  # active
            veh.active_v_body = r.v_body_mps
        if r.t_boot_s != veh.cur_t:  # a new estimator update: the previous one is complete
            self._commit_update(veh)
            veh.cur_t = r.t_boot_s
            veh.cur_keep = veh.n_updates % self._decimation == 0  # live: every Nth update
            veh.n_updates += 1
        if not veh.cur_keep:
            return
        veh.cur[6 * i : 6 * i + 6] = (*r.v_body_mps, *r.v_ned_mps)
        if i == _N_EST - 1 and r.sigma_lost_mps is not None:
            veh.groups["sigma_lost"].append(r.t_boot_s, (r.sigma_lost_mps,))
            veh.rows_buffered += 1

    def _commit_update(self, veh: _Vehicle) -> None:
        if veh.cur_t is None or not veh.cur_keep:
            return
        row = veh.cur
        veh.cur = [math.nan] * (_N_EST * 6)
        veh.est_t.append(veh.cur_t)
        veh.est_rows.append(row)
        veh.rows_buffered += 1
        if veh.seen_truth:
            veh.pend_t.append(veh.cur_t)
            veh.pend_rows.append(row)
        veh.cur_t = None

    def _on_measurement(self, veh: _Vehicle, r: MeasurementRecord) -> None:
        t = r.t_boot_s
        veh.groups["meas_ned"].append(t, r.v_ned_mps)
        veh.rows_buffered += 1
        euler = r.euler_rad
        if euler is not None and all(math.isfinite(a) for a in euler):
            # v_body = E^T y: the measured NED velocity in body axes with the held attitude (13)
            v_body = e_exact(euler).T @ np.asarray(r.v_ned_mps, dtype=np.float64)
            veh.groups["meas_body"].append(t, tuple(float(x) for x in v_body))
            if all(math.isfinite(x) for x in r.position_ned_m):
                truth_v = veh.truth_v_body or (math.nan, math.nan, math.nan)
                veh.pose_t.append(t)
                veh.pose_rows.append(
                    (*r.position_ned_m, *quaternion_xyzw(euler), *veh.active_v_body, *truth_v)
                )

    def _on_truth(self, veh: _Vehicle, r: TruthRecord) -> None:
        values = (*r.v_body_mps, *r.v_ned_mps)
        veh.groups["truth"].append(r.t_boot_s, values)
        veh.rows_buffered += 1
        veh.truth_t.append(r.t_boot_s)
        veh.truth_v.append(values)
        veh.truth_v_body = r.v_body_mps
        veh.seen_truth = True

    def _on_health(self, veh: _Vehicle, r: HealthRecord) -> None:
        isolated = r.isolated_faults[-1].axis if r.isolated_faults else None
        values = (
            *r.residual_ned_mps,
            *r.test_ratio,
            *(float(AXIS_STATE_INDEX.get(r.axis_state.get(a, "ok"), -1)) for a in NED_AXES),
            float(ACTIVE_CONFIG_INDEX.get(r.active_config, -1)),
            float(ISOLATED_AXIS_INDEX[isolated]),
        )
        veh.groups["health"].append(r.t_boot_s, values)
        veh.rows_buffered += 1
        faults = frozenset((str(f.axis), f.kind, f.t_detect_s) for f in r.isolated_faults)
        events: list[tuple[str, str]] = []
        for axis, kind, t_detect in sorted(faults - veh.faults, key=lambda f: f[2]):
            events.append((f"fault isolated on axis {axis} ({kind}) at {t_detect:.3f} s", "WARN"))
        for axis, kind, _ in sorted(veh.faults - faults):
            events.append((f"axis {axis} ({kind}) no longer isolated", "INFO"))
        if r.active_config != veh.active_config:
            if veh.active_config is not None or r.active_config != "full":
                events.append(
                    (f"active configuration {veh.active_config} -> {r.active_config}", "INFO")
                )
            veh.active_config = r.active_config
        veh.faults = faults
        if events:
            path = f"{health_path(r.sysid)}/events"
            self._submit(_text_job(path, r.t_boot_s, events), rows=len(events))

    # ------------------------------------------------------------------ flushing

    def _add_vehicle(self, sysid: int) -> _Vehicle:
        veh = _new_vehicle(sysid)
        self._vehicles[sysid] = veh
        self._submit(_setup_job(sysid, sorted(self._vehicles)), rows=0, block=True, never_drop=True)
        return veh

    def _flush_vehicle(self, veh: _Vehicle, *, final: bool) -> None:
        if final:
            self._commit_update(veh)
        batches: list[_Batch] = [g.take() for g in veh.groups.values() if g.t]
        if veh.est_t:
            est = np.asarray(veh.est_rows, dtype=np.float64).reshape(-1, _N_EST, 6)
            bank = est[:, : len(CONFIGS), :].transpose(0, 2, 1)  # (rows, axis, config)
            cols = [(p, bank[:, j, :]) for j, p in enumerate(_axis_paths(bank_path(veh.sysid)))]
            cols += [
                (p, est[:, -1, j : j + 1])
                for j, p in enumerate(_axis_paths(active_path(veh.sysid)))
            ]
            batches.append((veh.est_t, cols))
            veh.est_t, veh.est_rows = [], []
        err = self._errors(veh, final=final)
        if err is not None:
            batches.append(err)
        pose_t, pose_rows = veh.pose_t, veh.pose_rows
        veh.pose_t, veh.pose_rows = [], []
        n_rows = veh.rows_buffered
        veh.rows_buffered = 0
        if not batches and not pose_t:
            return
        self._submit(_data_job(veh.sysid, batches, pose_t, pose_rows), rows=n_rows)

    def _errors(self, veh: _Vehicle, *, final: bool) -> _Batch | None:
        """est − truth at estimate times, truth linearly interpolated (interpolate_truth).

        Rows later than the last truth sample wait for the next one (unless ``final``, or
        truth has been silent for ``truth_timeout_s``: then they are dropped and counted).
        """
        if not veh.truth_t or not veh.pend_t:
            return None
        t_truth = np.asarray(veh.truth_t)
        t_last_truth = veh.truth_t[-1]
        t, rows = veh.pend_t, veh.pend_rows
        t_arr = np.asarray(t)
        ok, v_ref = interpolate_truth(
            t_arr, t_truth, np.asarray(veh.truth_v), max_gap_s=self._truth_max_gap_s
        )
        out: _Batch | None = None
        if ok.any():
            est = np.asarray(rows, dtype=np.float64).reshape(-1, _N_EST, 6)[ok]
            err = (est - v_ref[ok][:, None, :]).transpose(0, 2, 1)  # (rows, axis, estimate)
            cols = [(p, err[:, j, :]) for j, p in enumerate(_axis_paths(error_path(veh.sysid)))]
            out = (t_arr[ok].tolist(), cols)
        waiting = t_arr > t_last_truth
        stale = veh.t_last_s - t_last_truth > self._truth_timeout_s
        if final or stale:
            self.stats.error_rows_without_truth += int((~ok).sum())
            veh.pend_t, veh.pend_rows = [], []
        else:
            self.stats.error_rows_without_truth += int((~ok & ~waiting).sum())
            idx = np.flatnonzero(waiting)
            veh.pend_t = [t[i] for i in idx]
            veh.pend_rows = [rows[i] for i in idx]
        # keep the truth samples that bracket rows still waiting or still to come (the
        # update in progress, then later ones): from the last one <= the oldest such row
        oldest = veh.t_last_s if veh.cur_t is None else min(veh.cur_t, veh.t_last_s)
        if veh.pend_t:
            oldest = min(oldest, veh.pend_t[0])
        keep_from = max(int(np.searchsorted(t_truth, oldest, side="right")) - 1, 0)
        veh.truth_t = veh.truth_t[keep_from:]
        veh.truth_v = veh.truth_v[keep_from:]
        return out

    def _submit(
        self, job: _Job, *, rows: int, block: bool = False, never_drop: bool = False
    ) -> None:
        if self._live and not never_drop and not block:
            try:
                self._queue.put_nowait(job)
            except queue.Full:
                self.stats.batches_dropped += 1
                self.stats.rows_dropped += rows
                if (
                    self.stats.batches_dropped in (1, 10, 100)
                    or self.stats.batches_dropped % 1000 == 0
                ):
                    log.warning(
                        "rerun: viewer not keeping up, dropped %d batches (%d rows) so far",
                        self.stats.batches_dropped,
                        self.stats.rows_dropped,
                    )
                return
        else:
            try:
                self._queue.put(job, timeout=None if not self._live else 1.0)
            except queue.Full:
                self.stats.batches_dropped += 1
                self.stats.rows_dropped += rows
                return
        self.stats.rows_logged += rows

    def _sender(self, rec: rr.RecordingStream) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            try:
                job(rec)
                self.stats.batches_sent += 1
            except Exception:
                self.stats.send_errors += 1
                log.exception("rerun: logging a batch failed; carrying on")

    # ------------------------------------------------------------------ close

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Send everything buffered and wait until the sender thread has handed it to Rerun.

        Returns False when the sender did not drain within ``timeout_s`` (a stuck viewer).
        """
        if self._rec is None:
            return True
        with self._lock:
            for veh in self._vehicles.values():
                self._commit_update(veh)  # the update in progress too (call between updates)
                self._flush_vehicle(veh, final=False)
        done = threading.Event()

        def marker(_rec: rr.RecordingStream) -> int:
            done.set()
            return 0

        self._submit(marker, rows=0, block=True, never_drop=True)
        return done.wait(timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Flush, finish the file or stream, stop the sender thread and the web viewer."""
        if self._closed:
            return
        rec = self._rec
        if rec is not None:
            with self._lock:
                for veh in self._vehicles.values():
                    self._flush_vehicle(veh, final=True)
                self._closed = True
            try:
                self._queue.put(None, timeout=timeout_s if self._live else None)
            except queue.Full:
                log.warning("rerun: sender queue full at close; dropping what is queued")
            if self._thread is not None:
                # a file always drains: wait for it; a viewer may be gone: bounded wait
                self._thread.join(timeout_s if self._live else None)
                if self._thread.is_alive():
                    log.warning("rerun: the viewer did not take the data within %.0f s", timeout_s)
            if self._thread is None or not self._thread.is_alive():
                # a gone viewer: rerun's flush raises after the timeout, and its disconnect
                # waits up to 5 s more for a last connection attempt, then drops the data
                try:
                    rec.flush(timeout_sec=min(timeout_s, 2.0) if self._live else 600.0)
                except Exception:
                    log.warning("rerun: flush at close failed", exc_info=True)
                rec.disconnect()
        self._closed = True
        self._rec = None
        if self._web_process is not None:
            self._web_process.terminate()
            try:
                self._web_process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._web_process.kill()
                self._web_process.wait()
            self._web_process = None
        log.info("rerun sink closed (%s): %s", self.mode, self.stats)

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- jobs


def _text_job(path: str, t_s: float, events: list[tuple[str, str]]) -> _Job:
    def job(rec: rr.RecordingStream) -> int:
        import rerun as rr

        rec.set_time(TIMELINE, duration=t_s)
        for text, level in events:
            rec.log(path, rr.TextLog(text, level=level))
        return len(events)

    return job


def _setup_job(sysid: int, all_sysids: list[int]) -> _Job:
    """Static styling of one vehicle's entities, and the blueprint for all vehicles so far."""

    def job(rec: rr.RecordingStream) -> int:
        import rerun as rr

        bank_style = rr.SeriesLines(
            names=list(CONFIGS), colors=[COLORS[c] for c in CONFIGS], widths=[1.5] * len(CONFIGS)
        )
        for p in _axis_paths(bank_path(sysid)):
            rec.log(p, bank_style, static=True)
        for p in _axis_paths(active_path(sysid)):
            rec.log(
                p, rr.SeriesLines(names="active", colors=COLORS["active"], widths=2.5), static=True
            )
        err_style = rr.SeriesLines(names=list(ESTIMATES), colors=[COLORS[e] for e in ESTIMATES])
        for p in _axis_paths(error_path(sysid)):
            rec.log(p, err_style, static=True)
        meas_style = rr.SeriesPoints(
            names="measurement", colors=COLORS["measurement"], marker_sizes=1.5
        )
        for p in _axis_paths(measurement_path(sysid)):
            rec.log(p, meas_style, static=True)
        for p in _axis_paths(truth_path(sysid)):
            rec.log(
                p, rr.SeriesLines(names="truth", colors=COLORS["truth"], widths=2.0), static=True
            )
        h = health_path(sysid)
        axis_style = rr.SeriesLines(names=list(NED_AXES), colors=list(AXIS_COLORS))
        for kind in ("residual", "test_ratio", "axis_state"):
            rec.log(f"{h}/{kind}", axis_style, static=True)
        rec.log(
            f"{h}/state",
            rr.SeriesLines(
                names=["active config", "isolated axis"], colors=[COLORS["active"], (255, 0, 255)]
            ),
            static=True,
        )
        rec.log(
            f"{active_path(sysid)}/sigma_lost_mps",
            rr.SeriesLines(names="sigma lost axis", colors=COLORS["active"]),
            static=True,
        )
        # NED earth frame = Rerun's FRD axes (x north/forward, y east/right, z down)
        rec.log("/world", rr.ViewCoordinates.FRD, static=True)
        w = world_vehicle_path(sysid)
        rec.log(
            f"{w}/body",
            rr.Boxes3D(
                half_sizes=[_BODY_HALF_SIZES_M], colors=[(200, 200, 200)], labels=[f"{sysid}"]
            ),
            static=True,
        )
        rec.log(
            f"{w}/velocity/active",
            rr.Arrows3D.from_fields(colors=[COLORS["active"]], radii=[0.01]),
            static=True,
        )
        rec.log(
            f"{w}/velocity/truth",
            rr.Arrows3D.from_fields(colors=[COLORS["truth"]], radii=[0.01]),
            static=True,
        )
        rec.send_blueprint(build_blueprint(all_sysids))
        return 0

    return job


def _data_job(
    sysid: int,
    batches: list[_Batch],
    pose_t: list[float],
    pose_rows: list[tuple[float, ...]],
) -> _Job:
    def job(rec: rr.RecordingStream) -> int:
        import rerun as rr

        n = 0
        for t, cols in batches:
            rr.send_record_batch(record_batch(t, _scalars(cols)), recording=rec)
            n += len(t)
        if pose_t:
            p = np.asarray(pose_rows, dtype=np.float64)
            w = world_vehicle_path(sysid)
            pose: list[_Column] = [
                (w, "Transform3D:translation", p[:, 0:3]),
                (w, "Transform3D:quaternion", p[:, 3:7]),
            ]
            for name, sl in (("active", slice(7, 10)), ("truth", slice(10, 13))):
                ok = np.isfinite(p[:, sl]).all(axis=1)
                if ok.all():
                    pose.append((f"{w}/velocity/{name}", "Arrows3D:vectors", p[:, sl]))
                elif ok.any():  # rows without a value yet: a batch of their own
                    arrow: list[_Column] = [(f"{w}/velocity/{name}", "Arrows3D:vectors", p[ok, sl])]
                    t_ok = np.asarray(pose_t)[ok].tolist()
                    rr.send_record_batch(record_batch(t_ok, arrow), recording=rec)
            rr.send_record_batch(record_batch(pose_t, pose), recording=rec)
            n += len(pose_t)
        return n

    return job


# --------------------------------------------------------------------------- factory


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


def _has_display(env: Mapping[str, str]) -> bool:
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY")) or sys.platform in (
        "darwin",
        "win32",
    )


def open_rerun_sink(
    mode: str,
    *,
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
    environ: Mapping[str, str] | None = None,
) -> RerunSink:
    """Open the Rerun sink for ``mode`` (see the module docstring); RerunModeError if bad.

    ``decimation`` (live modes) logs every Nth velocity record per configuration.
    ``serve``: the gRPC server on ``serve_bind:grpc_port``, the web viewer on
    ``serve_bind:web_port`` (None: no web viewer). ``spawn`` without a usable display
    falls back to ``save:fallback_save_path`` (None: raise RerunModeError instead).
    ``flush_period_s`` is the live flush period in vehicle time; ``batch_rows`` the
    rows per vehicle buffered between flushes in ``save`` mode; ``max_queued_batches``
    bounds the batches waiting for the sender thread (live modes drop beyond it).
    """
    parsed = parse_rerun_mode(mode)
    if decimation < 1:
        raise RerunModeError(f"rerun decimation must be >= 1, got {decimation}")
    common: dict[str, Any] = {
        "decimation": decimation,
        "flush_period_s": flush_period_s,
        "batch_rows": batch_rows,
        "max_queued_batches": max_queued_batches,
    }
    if parsed.kind == "off":
        return RerunSink(None, mode=parsed, **common)

    import rerun as rr

    rec = rr.RecordingStream(application_id)
    rec.set_log_time_enabled(False)  # the vehicle's clock only (vehicle_time)
    rec.set_log_tick_enabled(False)
    if recording_name:
        rec.send_recording_name(recording_name)
    env = os.environ if environ is None else environ
    effective = parsed
    web_process: subprocess.Popen[bytes] | None = None
    grpc_url: str | None = None
    web_url: str | None = None

    if parsed.kind == "spawn":
        exe = rerun_executable()
        reason = None
        if not _has_display(env):
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
                grpc_url = f"rerun+http://127.0.0.1:{spawn_port}/proxy"
            except Exception as exc:  # the viewer binary failed to start
                reason = f"spawning the viewer failed: {exc}"
        if reason is not None:
            if fallback_save_path is None:
                raise RerunModeError(f"rerun mode 'spawn': cannot start a viewer ({reason})")
            effective = RerunMode("save", fallback_save_path)
            log.warning(
                "rerun: cannot spawn a viewer (%s); saving to %s instead. Open it with: rerun %s",
                reason,
                fallback_save_path,
                fallback_save_path,
            )
    if effective.kind == "connect":
        assert effective.target is not None
        rec.connect_grpc(effective.target)
        grpc_url = effective.target
    elif effective.kind == "serve":
        server = rr.GrpcServerSink(
            bind_ip=serve_bind, port=grpc_port, server_memory_limit=server_memory_limit
        )
        rec.set_sinks(server)
        grpc_url = f"rerun+http://{serve_bind}:{grpc_port}/proxy"
        if web_port is not None:
            exe = rerun_executable()
            if exe is None:
                log.warning("rerun: no rerun executable found; the web viewer is not served")
            else:
                # The rerun CLI binds the web viewer where told (--bind); rr.serve_web_viewer
                # (0.41) always binds 0.0.0.0, so the CLI hosts it here.
                web_process = subprocess.Popen(
                    [
                        exe,
                        "--serve-web",
                        "--bind",
                        serve_bind,
                        "--web-viewer-port",
                        str(web_port),
                        grpc_url,
                    ],
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
                web_url = f"http://{serve_bind}:{web_port}/?url={grpc_url}"
        log.info(
            "rerun: serving gRPC at %s%s", grpc_url, f", web viewer at {web_url}" if web_url else ""
        )
    elif effective.kind == "save":
        assert effective.target is not None
        Path(effective.target).parent.mkdir(parents=True, exist_ok=True)
        rec.save(effective.target)
    return RerunSink(
        rec,
        mode=effective,
        requested_mode=parsed,
        web_process=web_process,
        grpc_url=grpc_url,
        web_url=web_url,
        **common,
    )


# --------------------------------------------------------------------------- reading back


def read_recording(
    path: str | Path,
) -> dict[str, dict[str, list[Any]]]:
    """Read an ``.rrd`` back: entity path -> component -> values, with ``"vehicle_time"``.

    For each entity, ``out[path]["vehicle_time"]`` holds the vehicle time of each temporal
    row in seconds and ``out[path][component]`` the row values as Python lists
    (e.g. ``"Scalars:scalars"`` -> ``[[1.0], ...]``), rows sorted by time; static rows are
    under ``out[path]["static:" + component]``. For tests, notebooks and checks.
    """
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list[Any]]] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        entity = out.setdefault(chunk.entity_path, {})
        names = [n for n in batch.schema.names if not n.startswith("rerun.controls")]
        if chunk.is_static:
            for name in names:
                entity.setdefault(f"static:{name}", []).extend(batch.column(name).to_pylist())
            continue
        if TIMELINE not in names:
            continue
        t_ns = batch.column(TIMELINE).cast("int64").to_pylist()
        for name in names:
            values = (
                [t * 1e-9 for t in t_ns] if name == TIMELINE else batch.column(name).to_pylist()
            )
            entity.setdefault(name, []).extend(values)
    for entity in out.values():
        if TIMELINE in entity:
            order = sorted(range(len(entity[TIMELINE])), key=entity[TIMELINE].__getitem__)
            for name, values in entity.items():
                if not name.startswith("static:") and len(values) == len(order):
                    entity[name] = [values[i] for i in order]
    return out
