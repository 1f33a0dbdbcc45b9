"""Records to columns: the sink's buffers, with no Rerun calls (the sender sends them).

Rows are buffered per group of entities that share time stamps. A flush turns them into
:class:`Batch` objects of column items (:class:`ScalarRows`, :class:`PoseRows`, ...,
in :mod:`glmav_observer.publish.rerun.items`);
the sender makes one ``rr.send_columns`` call, one Rerun chunk, per entity and item.
A chunk costs about the same whatever its rows, so the configurations of the bank and
the active estimate are instances of one entity per axis (one line each in the plot)
rather than entities of their own, and the flush period (live) or the rows per flush
(save) set the cost.

The estimates of one estimator update (every configuration and the active one, at one
vehicle time) form one row; live modes keep every ``decimation``-th update. Errors
against truth are computed at the estimate times with the truth linearly interpolated
(:func:`glmav_observer.evaluation.interpolate_truth`: the project's one definition of
the error against truth). Health records also give the status document and the
event log: isolations, recoveries, switches, and fault detection arming (an axis leaves
the ``warmup`` state) or not arming within ``arming_timeout_s``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from glmav_observer.configurations import LOST_AXIS_OF_CONFIG
from glmav_observer.evaluation import interpolate_truth
from glmav_observer.frames import e_flat, quaternion_xyzw, rotate_t_flat
from glmav_observer.publish.rerun.items import (
    ArrowRows,
    Batch,
    DocumentRow,
    Item,
    PoseRows,
    ScalarRows,
    Setup,
    TextRows,
)
from glmav_observer.publish.rerun.paths import (
    AXIS_STATE_INDEX,
    BODY_AXES,
    ISOLATED_AXIS_INDEX,
    active_path,
    axis_paths,
    config_index,
    config_label,
    error_path,
    estimate_path,
    health_path,
    measurement_path,
    status_path,
    truth_path,
    world_vehicle_path,
)
from glmav_observer.records import (
    NED_AXES,
    HealthRecord,
    MeasurementRecord,
    Record,
    TruthRecord,
    VelocityRecord,
)

WARMUP = "warmup"

# --------------------------------------------------------------------------- status


def status_markdown(
    r: HealthRecord, configs: Sequence[str], *, unarmed_for_s: float | None = None
) -> str:
    """The status document: active configuration and what it lost, fault detection arming,
    and per NED axis its state and the configuration that does without it.

    ``unarmed_for_s``: fault detection has not armed for that long (then said so).
    """
    lost = LOST_AXIS_OF_CONFIG.get(r.active_config)
    active = f"**active: {config_label(r.active_config)}**"
    if lost:
        active += f", axis {lost} dead-reckoned"
    isolated = ", ".join(f"{f.axis} ({f.kind} at {f.t_detect_s:.3f} s)" for f in r.isolated_faults)
    lines = [active + (f"; isolated: {isolated}" if isolated else "")]
    unarmed = [a for a in NED_AXES if r.axis_state.get(a) == WARMUP]
    if not unarmed:
        lines.append(f"fault detection: armed on {', '.join(NED_AXES)}")
    else:
        why = "warm-up, no vetted reference yet"
        if unarmed_for_s is not None:
            why = f"not armed after {unarmed_for_s:.1f} s: {why} (IMU rate? measurements?)"
        lines.append(f"**fault detection NOT ARMED** on {', '.join(unarmed)} ({why})")
    without = {axis: c for c in configs if (axis := LOST_AXIS_OF_CONFIG.get(c))}
    lines += ["", "| axis | state | configuration without it |", "|---|---|---|"]
    for a in NED_AXES:
        state = r.axis_state.get(a, "?")
        shown = f"**{state}**" if state not in ("ok",) else state
        lines.append(f"| {a} | {shown} | {without.get(a, '-')} |")
    return "\n".join(lines)


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

    def take(self) -> ScalarRows:
        t, rows = self.t, self.rows
        self.t, self.rows = [], []
        values = np.asarray(rows, dtype=np.float64).reshape(len(t), sum(self.widths))
        cols: list[tuple[str, npt.NDArray[np.float64]]] = []
        j = 0
        for path, k in zip(self.paths, self.widths, strict=True):
            cols.append((path, values[:, j : j + k]))
            j += k
        return ScalarRows(np.asarray(t, dtype=np.float64), cols)


@dataclass(slots=True)
class _Vehicle:
    sysid: int
    groups: dict[str, _Group]
    n_est: int  # configurations + active
    # the estimates of one update (configs..., active) x (u, v, w, n, e, d), NaN if absent
    cur: list[float]
    cur_t: float | None = None
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
    unarmed: frozenset[str] | None = None  # axes in warm-up at the last health record
    t_unarmed_since_s: float | None = None
    unarmed_warned: bool = False
    status: str | None = None


class RecordBuffer:
    """Buffers records per vehicle and hands out :class:`Batch` objects to send.

    ``configs``: the bank's configuration names in bank order (the first instances of
    the estimate and error entities; the active estimate is the last). ``live``: flush every ``flush_period_s``
    of vehicle time and keep every ``decimation``-th estimator update; otherwise flush
    every ``batch_rows`` rows and keep everything.
    """

    def __init__(
        self,
        configs: Sequence[str],
        *,
        live: bool,
        decimation: int = 1,
        flush_period_s: float = 0.5,
        batch_rows: int = 20_000,
        truth_max_gap_s: float = 0.1,
        truth_timeout_s: float = 1.0,
        arming_timeout_s: float = 5.0,
    ) -> None:
        self.configs = tuple(configs)
        self._index = {c: i for i, c in enumerate(self.configs)}
        self._n_est = len(self.configs) + 1  # the active estimate last
        self._config_index = config_index(self.configs)
        self._live = live
        self._decimation = decimation if live else 1
        self._flush_period_s = flush_period_s
        self._batch_rows = batch_rows
        self._truth_max_gap_s = truth_max_gap_s
        self._truth_timeout_s = truth_timeout_s
        self._arming_timeout_s = arming_timeout_s
        self._vehicles: dict[int, _Vehicle] = {}
        #: estimates left without bracketing truth (no error row), see _errors
        self.error_rows_without_truth = 0

    # ------------------------------------------------------------------ records

    def add(self, record: Record) -> list[Batch]:
        """Buffer one record; return what is due for sending (often nothing)."""
        out: list[Batch] = []
        veh = self._vehicles.get(record.sysid)
        if veh is None:
            veh = self._new_vehicle(record.sysid)
            out.append(Batch([Setup(record.sysid, sorted(self._vehicles))], 0, keep=True))
        t = record.t_boot_s
        if isinstance(record, VelocityRecord):
            self._on_velocity(veh, record)
        elif isinstance(record, MeasurementRecord):
            self._on_measurement(veh, record)
        elif isinstance(record, TruthRecord):
            self._on_truth(veh, record)
        elif isinstance(record, HealthRecord):
            items = self._on_health(veh, record)
            if items:
                out.append(Batch(items, len(items)))
        veh.t_last_s = max(veh.t_last_s, t)
        if veh.t_flush_s is None:
            veh.t_flush_s = t
        if self._live:
            due = t - veh.t_flush_s >= self._flush_period_s
        else:
            due = veh.rows_buffered >= self._batch_rows
        if due or veh.rows_buffered >= 4 * self._batch_rows:
            batch = self._flush_vehicle(veh, final=False)
            if batch is not None:
                out.append(batch)
            veh.t_flush_s = t
        return out

    def flush(self, *, final: bool) -> list[Batch]:
        """Everything buffered, the estimator update in progress included (call between
        updates). ``final``: estimates still waiting for truth are dropped and counted."""
        out: list[Batch] = []
        for veh in self._vehicles.values():
            self._commit_update(veh)
            batch = self._flush_vehicle(veh, final=final)
            if batch is not None:
                out.append(batch)
        return out

    def _new_vehicle(self, sysid: int) -> _Vehicle:
        h = health_path(sysid)
        groups = {
            "sigma_lost": _Group([f"{active_path(sysid)}/sigma_lost_mps"], [1]),
            "sigma_ned": _Group(
                [f"{active_path(sysid)}/sigma_ned_mps/{a}" for a in NED_AXES], [1] * 3
            ),
            "meas_ned": _Group([f"{measurement_path(sysid)}/v_ned/{a}" for a in NED_AXES], [1] * 3),
            "meas_body": _Group(
                [f"{measurement_path(sysid)}/v_body/{a}" for a in BODY_AXES], [1] * 3
            ),
            "truth": _Group(axis_paths(truth_path(sysid)), [1] * 6),
            "health": _Group(
                [f"{h}/residual", f"{h}/test_ratio", f"{h}/axis_state", f"{h}/state"],
                [3, 3, 3, 2],
            ),
        }
        veh = _Vehicle(
            sysid=sysid, groups=groups, n_est=self._n_est, cur=[math.nan] * (self._n_est * 6)
        )
        self._vehicles[sysid] = veh
        return veh

    def _on_velocity(self, veh: _Vehicle, r: VelocityRecord) -> None:
        if r.config == "active":
            i = self._n_est - 1
            veh.active_v_body = r.v_body_mps
        else:
            j = self._index.get(r.config)
            if j is None:  # a configuration this sink was not given
                return
            i = j
        if r.t_boot_s != veh.cur_t:  # a new estimator update: the previous one is complete
            self._commit_update(veh)
            veh.cur_t = r.t_boot_s
            veh.cur_keep = veh.n_updates % self._decimation == 0  # live: every Nth update
            veh.n_updates += 1
        if not veh.cur_keep:
            return
        veh.cur[6 * i : 6 * i + 6] = (*r.v_body_mps, *r.v_ned_mps)
        if i == self._n_est - 1 and r.sigma_lost_mps is not None:
            veh.groups["sigma_lost"].append(r.t_boot_s, (r.sigma_lost_mps,))
            veh.rows_buffered += 1
        if i == self._n_est - 1 and r.sigma_ned_mps is not None:
            veh.groups["sigma_ned"].append(r.t_boot_s, r.sigma_ned_mps)
            veh.rows_buffered += 1

    def _commit_update(self, veh: _Vehicle) -> None:
        if veh.cur_t is None or not veh.cur_keep:
            return
        row = veh.cur
        veh.cur = [math.nan] * (self._n_est * 6)
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
            v_body = rotate_t_flat(e_flat(*euler), r.v_ned_mps)
            veh.groups["meas_body"].append(t, (v_body[0], v_body[1], v_body[2]))
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

    def _on_health(self, veh: _Vehicle, r: HealthRecord) -> list[Item]:
        t = r.t_boot_s
        isolated = r.isolated_faults[-1].axis if r.isolated_faults else None
        values = (
            *r.residual_ned_mps,
            *r.test_ratio,
            *(float(AXIS_STATE_INDEX.get(r.axis_state.get(a, "ok"), -1)) for a in NED_AXES),
            float(self._config_index.get(r.active_config, -1)),
            float(ISOLATED_AXIS_INDEX[isolated]),
        )
        veh.groups["health"].append(t, values)
        veh.rows_buffered += 1
        events = self._isolation_events(veh, r) + self._arming_events(veh, r)
        items: list[Item] = []
        if events:
            items.append(TextRows(f"{health_path(r.sysid)}/events", t, events))
        status = status_markdown(
            r, self.configs, unarmed_for_s=self._arming_timeout_s if veh.unarmed_warned else None
        )
        if status != veh.status:
            items.append(DocumentRow(status_path(r.sysid), t, status))
            veh.status = status
        return items

    def _isolation_events(self, veh: _Vehicle, r: HealthRecord) -> list[tuple[str, str]]:
        faults = frozenset((str(f.axis), f.kind, f.t_detect_s) for f in r.isolated_faults)
        events: list[tuple[str, str]] = []
        for axis, kind, t_detect in sorted(faults - veh.faults, key=lambda f: f[2]):
            events.append((f"fault isolated on axis {axis} ({kind}) at {t_detect:.3f} s", "WARN"))
        for axis, kind, _ in sorted(veh.faults - faults):
            events.append((f"axis {axis} ({kind}) no longer isolated", "INFO"))
        if r.active_config != veh.active_config:
            if veh.active_config is not None or r.active_config != "full":
                text = f"active configuration {veh.active_config} -> {r.active_config}"
                lost = LOST_AXIS_OF_CONFIG.get(r.active_config)
                events.append((f"{text} ({lost} lost)" if lost else text, "INFO"))
            veh.active_config = r.active_config
        veh.faults = faults
        return events

    def _arming_events(self, veh: _Vehicle, r: HealthRecord) -> list[tuple[str, str]]:
        """Fault detection arms on an axis when it leaves ``warmup``; say so, and warn once
        when some axis has not armed ``arming_timeout_s`` after it started warming up."""
        t = r.t_boot_s
        unarmed = frozenset(a for a in NED_AXES if r.axis_state.get(a) == WARMUP)
        before = veh.unarmed
        events: list[tuple[str, str]] = []
        if before is not None:
            armed_now = sorted(before - unarmed, key=NED_AXES.index)
            if armed_now:
                events.append((f"fault detection armed on axis {', '.join(armed_now)}", "INFO"))
            back = sorted(unarmed - before, key=NED_AXES.index)
            if back:
                events.append(
                    (f"fault detection not armed on axis {', '.join(back)} (warm-up)", "WARN")
                )
        if unarmed and (before is None or not before):
            veh.t_unarmed_since_s = t
            veh.unarmed_warned = False
        if not unarmed:
            veh.t_unarmed_since_s = None
            veh.unarmed_warned = False
        elif (
            not veh.unarmed_warned
            and veh.t_unarmed_since_s is not None
            and t - veh.t_unarmed_since_s >= self._arming_timeout_s
        ):
            veh.unarmed_warned = True
            axes = ", ".join(a for a in NED_AXES if a in unarmed)
            events.append(
                (
                    f"fault detection not armed after {self._arming_timeout_s:.1f} s on axis "
                    f"{axes}: no vetted reference (too slow an IMU or missing measurements?)",
                    "WARN",
                )
            )
        veh.unarmed = unarmed
        return events

    # ------------------------------------------------------------------ flushing

    def _flush_vehicle(self, veh: _Vehicle, *, final: bool) -> Batch | None:
        if final:
            self._commit_update(veh)
        items: list[Item] = [g.take() for g in veh.groups.values() if g.t]
        if veh.est_t:
            est = np.asarray(veh.est_rows, dtype=np.float64).reshape(-1, self._n_est, 6)
            by_axis = est.transpose(0, 2, 1)  # (rows, axis, configurations then active)
            paths = axis_paths(estimate_path(veh.sysid))
            cols = [(p, by_axis[:, j, :]) for j, p in enumerate(paths)]
            items.append(ScalarRows(np.asarray(veh.est_t, dtype=np.float64), cols))
            veh.est_t, veh.est_rows = [], []
        err = self._errors(veh, final=final)
        if err is not None:
            items.append(err)
        if veh.pose_t:
            items += _pose_items(world_vehicle_path(veh.sysid), veh.pose_t, veh.pose_rows)
            veh.pose_t, veh.pose_rows = [], []
        n_rows = veh.rows_buffered
        veh.rows_buffered = 0
        if not items:
            return None
        return Batch(items, n_rows)

    def _errors(self, veh: _Vehicle, *, final: bool) -> ScalarRows | None:
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
        out: ScalarRows | None = None
        if ok.any():
            est = np.asarray(rows, dtype=np.float64).reshape(-1, self._n_est, 6)[ok]
            err = (est - v_ref[ok][:, None, :]).transpose(0, 2, 1)  # (rows, axis, estimate)
            cols = [(p, err[:, j, :]) for j, p in enumerate(axis_paths(error_path(veh.sysid)))]
            out = ScalarRows(t_arr[ok], cols)
        waiting = t_arr > t_last_truth
        stale = veh.t_last_s - t_last_truth > self._truth_timeout_s
        if final or stale:
            self.error_rows_without_truth += int((~ok).sum())
            veh.pend_t, veh.pend_rows = [], []
        else:
            self.error_rows_without_truth += int((~ok & ~waiting).sum())
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


def _pose_items(w: str, pose_t: list[float], pose_rows: list[tuple[float, ...]]) -> list[Item]:
    """The pose and the velocity arrows; rows before an arrow has a value are left out of it."""
    p = np.asarray(pose_rows, dtype=np.float64)
    t = np.asarray(pose_t, dtype=np.float64)
    items: list[Item] = [PoseRows(w, t, p[:, 0:3], p[:, 3:7])]
    for name, sl in (("active", slice(7, 10)), ("truth", slice(10, 13))):
        ok = np.isfinite(p[:, sl]).all(axis=1)
        if ok.any():
            items.append(ArrowRows(f"{w}/velocity/{name}", t[ok], p[ok, sl]))
    return items
