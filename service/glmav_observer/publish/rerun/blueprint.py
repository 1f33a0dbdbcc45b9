"""The layout (blueprint) and the static styling of each vehicle's entities."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from glmav_observer.publish.rerun.paths import (
    ACTIVE,
    AXIS_COLORS,
    BODY_AXES,
    COLORS,
    TIMELINE,
    WIDTH_ACTIVE,
    WIDTH_CONFIG,
    WIDTH_TRUTH,
    active_path,
    axis_paths,
    config_colors,
    config_label,
    error_path,
    estimate_path,
    health_path,
    lost_axis_legend,
    measurement_path,
    status_path,
    truth_path,
    world_vehicle_path,
)
from glmav_observer.records import CONFIGS, NED_AXES

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

#: Airframe half sizes (m) in FRD: body diameter D = 0.08, length l = 0.30 (design.md).
BODY_HALF_SIZES_M = (0.04, 0.04, 0.15)
AXIS_STATE_TITLE = (
    "axis state (-1 warm-up: fault detection not armed, 0 ok, 1 suspect, 2 recovering, 3 faulty)"
)


def build_blueprint(sysids: Sequence[int], configs: Sequence[str] = CONFIGS) -> rrb.Blueprint:
    """The layout, built once per set of vehicles (one tab per vehicle).

    Per vehicle: an overview (u, v, w of every configuration with the active estimate,
    the measurement and the truth; the status document (active configuration, each
    axis's state, fault-detection arming); the 3D pose with velocity arrows; residuals,
    test ratios and the state of the isolation), the NED components, the errors against
    truth and the health tab (axis states, lost-axis sigma, event log).
    """
    import rerun.blueprint as rrb

    def series(name: str, paths: Sequence[str]) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=name, origin="/", contents=list(paths))

    tabs: list[rrb.Container] = []
    for sysid in sysids:
        sources = [estimate_path(sysid), measurement_path(sysid), truth_path(sysid)]

        def axis_view(frame: str, axis: str, sources: list[str] = sources) -> rrb.TimeSeriesView:
            return series(f"{axis} ({frame}, m/s)", [f"{s}/{frame}/{axis}" for s in sources])

        h = health_path(sysid)
        overview = rrb.Horizontal(
            rrb.Vertical(*(axis_view("v_body", a) for a in BODY_AXES), name="body velocity"),
            rrb.Vertical(
                rrb.TextDocumentView(name="status", origin=status_path(sysid)),
                rrb.Spatial3DView(
                    name="pose (NED) and velocity",
                    origin="/world",
                    contents=["/world", f"{world_vehicle_path(sysid)}/**"],
                ),
                series("residual (m/s)", [f"{h}/residual"]),
                series("test ratio (>1 fails)", [f"{h}/test_ratio"]),
                series(
                    f"state: active config ({lost_axis_legend(configs)}), "
                    "isolated axis (0 none, 1 n, 2 e, 3 d)",
                    [f"{h}/state"],
                ),
                row_shares=[2, 3, 2, 2, 2],
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
                rrb.TextDocumentView(name="status", origin=status_path(sysid)),
                series(AXIS_STATE_TITLE, [f"{h}/axis_state"]),
                series(
                    "dead-reckoned sigma (m/s)",
                    [
                        f"{active_path(sysid)}/sigma_lost_mps",
                        f"{active_path(sysid)}/sigma_ned_mps",
                    ],
                ),
                row_shares=[1, 2, 2],
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


def log_styles(rec: rr.RecordingStream, sysid: int, configs: Sequence[str] = CONFIGS) -> None:
    """Static names, colours and widths of one vehicle's series, and its 3D entities.

    The configurations are named with the axis they have lost (``c1 (d lost)``); the
    active estimate, their last instance, is wider than every other line of its plots
    (paths.WIDTH_ACTIVE).
    """
    import rerun as rr

    # the configurations then the active estimate: the instances of the estimate and
    # error entities
    style = rr.SeriesLines(
        names=[*(config_label(c) for c in configs), ACTIVE],
        colors=[*config_colors(configs), COLORS[ACTIVE]],
        widths=[WIDTH_CONFIG] * len(configs) + [WIDTH_ACTIVE],
    )
    for p in axis_paths(estimate_path(sysid)) + axis_paths(error_path(sysid)):
        rec.log(p, style, static=True)
    meas_style = rr.SeriesPoints(
        names="measurement", colors=COLORS["measurement"], marker_sizes=1.5
    )
    for p in axis_paths(measurement_path(sysid)):
        rec.log(p, meas_style, static=True)
    truth_style = rr.SeriesLines(names="truth", colors=COLORS["truth"], widths=WIDTH_TRUTH)
    for p in axis_paths(truth_path(sysid)):
        rec.log(p, truth_style, static=True)
    h = health_path(sysid)
    axis_style = rr.SeriesLines(names=list(NED_AXES), colors=list(AXIS_COLORS))
    for kind in ("residual", "test_ratio", "axis_state"):
        rec.log(f"{h}/{kind}", axis_style, static=True)
    rec.log(
        f"{h}/state",
        rr.SeriesLines(
            names=["active config", "isolated axis"], colors=[COLORS[ACTIVE], (255, 0, 255)]
        ),
        static=True,
    )
    rec.log(
        f"{active_path(sysid)}/sigma_lost_mps",
        rr.SeriesLines(names="sigma lost axis", colors=COLORS[ACTIVE]),
        static=True,
    )
    for a in NED_AXES:  # every dead-reckoned axis: GPS lost, a silent stream (drift)
        rec.log(
            f"{active_path(sysid)}/sigma_ned_mps/{a}",
            rr.SeriesLines(names=f"sigma {a} (dead-reckoned)"),
            static=True,
        )
    # NED earth frame = Rerun's FRD axes (x north/forward, y east/right, z down)
    rec.log("/world", rr.ViewCoordinates.FRD, static=True)
    w = world_vehicle_path(sysid)
    rec.log(
        f"{w}/body",
        rr.Boxes3D(half_sizes=[BODY_HALF_SIZES_M], colors=[(200, 200, 200)], labels=[f"{sysid}"]),
        static=True,
    )
    for name in (ACTIVE, "truth"):
        rec.log(
            f"{w}/velocity/{name}",
            rr.Arrows3D.from_fields(colors=[COLORS[name]], radii=[0.01]),
            static=True,
        )
