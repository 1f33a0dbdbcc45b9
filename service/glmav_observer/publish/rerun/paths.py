"""Entity paths, the timeline, series names and colours of the Rerun recording.

Paths follow the pipeline (``docs/rerun.md`` lists them with their instances). The
configurations of the bank are the names the sink is given (``configurations.CONFIGS`` by
default), in bank order: nothing here assumes how many there are.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from glmav_observer.configurations import LOST_AXIS_OF_CONFIG, NED_AXES

#: The timeline every row is logged on: the vehicle's boot clock (a duration).
TIMELINE = "vehicle_time"
BODY_AXES: tuple[str, str, str] = ("u", "v", "w")
ACTIVE = "active"

Rgb = tuple[int, int, int]

#: Series colours (RGB): the paper's configurations, the selected estimate, measurement, truth.
COLORS: dict[str, Rgb] = {
    "full": (31, 119, 180),
    "c1": (255, 127, 14),
    "c2": (44, 160, 44),
    "c3": (148, 103, 189),
    ACTIVE: (214, 39, 40),
    "measurement": (160, 160, 160),
    "truth": (240, 228, 66),
}
#: Colours of further configurations (a name not in COLORS), in the order they are given.
EXTRA_COLORS: tuple[Rgb, ...] = (
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
    (188, 189, 34),
    (127, 127, 127),
)
#: Colours of the n, e, d instances of the health series.
AXIS_COLORS: tuple[Rgb, ...] = ((228, 26, 28), (55, 126, 184), (77, 175, 74))

#: Line widths (UI points). The selected estimate coincides with one of the bank's lines
#: and with the truth. It is the last instance of the estimate entities (drawn after the
#: configurations) and wider than every other line, so that whatever the viewer draws over
#: it, a band of it shows on both sides.
WIDTH_CONFIG = 1.5
WIDTH_TRUTH = 1.5
WIDTH_ACTIVE = 4.0

#: Encodings of the state series (a scalar per state so that the viewer plots steps).
#: The isolated fault: 0 none, then the NED axes (1 n, 2 e, 3 d), then the accelerometer.
ISOLATED_AXIS_INDEX: dict[str | None, int] = {
    None: 0,
    **{a: i + 1 for i, a in enumerate(NED_AXES)},
    "body": len(NED_AXES) + 1,
}
AXIS_STATE_INDEX: dict[str, int] = {
    "warmup": -1,
    "ok": 0,
    "suspect": 1,
    "recovering": 2,
    "faulty": 3,
}


def config_index(configs: Sequence[str]) -> dict[str, int]:
    """The scalar plotted for the active configuration: its index in ``configs``."""
    return {c: i for i, c in enumerate(configs)}


def config_colors(configs: Sequence[str]) -> list[Rgb]:
    """One colour per configuration: COLORS, then EXTRA_COLORS for other names."""
    out: list[Rgb] = []
    extra = iter(EXTRA_COLORS * (1 + len(configs) // len(EXTRA_COLORS)))
    for c in configs:
        out.append(COLORS[c] if c in COLORS else next(extra))
    return out


def config_label(config: str, lost_axis_of: Mapping[str, str | None] = LOST_AXIS_OF_CONFIG) -> str:
    """The series name of a configuration: ``c1 (d lost)``, or the name when nothing is lost."""
    lost = lost_axis_of.get(config)
    return f"{config} ({lost} lost)" if lost else config


def lost_axis_legend(
    configs: Sequence[str], lost_axis_of: Mapping[str, str | None] = LOST_AXIS_OF_CONFIG
) -> str:
    """``0 full, 1 c1 (d lost), ...``: the encoding of the active-configuration series."""
    return ", ".join(f"{i} {config_label(c, lost_axis_of)}" for i, c in enumerate(configs))


def vehicle_path(sysid: int) -> str:
    return f"/vehicle/{sysid}"


def estimate_path(sysid: int) -> str:
    """The estimates: each axis entity has one instance per configuration of the bank, then
    the active estimate (one chunk per axis and flush for all of them; drawn last)."""
    return f"{vehicle_path(sysid)}/estimate"


def active_path(sysid: int) -> str:
    """The active estimate's own series (``sigma_lost_mps``)."""
    return f"{vehicle_path(sysid)}/{ACTIVE}"


def measurement_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/ingest/measurement"


def truth_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/truth"


def error_path(sysid: int) -> str:
    """Estimate − truth: each axis entity has one instance per estimate (configurations, active)."""
    return f"{vehicle_path(sysid)}/error"


def health_path(sysid: int) -> str:
    return f"{vehicle_path(sysid)}/health"


def status_path(sysid: int) -> str:
    """A Markdown document: the active configuration, each axis's state, fault-detection arming."""
    return f"{health_path(sysid)}/status"


def world_vehicle_path(sysid: int) -> str:
    return f"/world/vehicle/{sysid}"


def axis_paths(root: str) -> list[str]:
    """The six axis entities of a velocity: body u, v, w then NED n, e, d."""
    return [f"{root}/v_body/{a}" for a in BODY_AXES] + [f"{root}/v_ned/{a}" for a in NED_AXES]
