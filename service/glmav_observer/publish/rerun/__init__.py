"""The Rerun sink as a package: open it with :func:`open_rerun_sink` (``docs/rerun.md``).

Modules: ``mode`` (the ``--rerun`` string, no rerun import), ``paths`` (entity paths,
names, colours), ``blueprint`` (layout, static styles), ``buffer`` (records to columns,
status and events), ``send`` (the sender thread, ``rr.send_columns``), ``viewer``
(viewer processes), ``sink`` (the sink), ``readback`` (an ``.rrd`` read back).
Importing the package does not import rerun; opening a sink does.
"""

from glmav_observer.publish.rerun.blueprint import build_blueprint
from glmav_observer.publish.rerun.mode import RerunMode, RerunModeError, parse_rerun_mode
from glmav_observer.publish.rerun.paths import (
    AXIS_STATE_INDEX,
    COLORS,
    ISOLATED_AXIS_INDEX,
    TIMELINE,
    config_index,
    config_label,
)
from glmav_observer.publish.rerun.readback import read_recording
from glmav_observer.publish.rerun.send import RerunStats
from glmav_observer.publish.rerun.sink import RerunSink, open_rerun_sink
from glmav_observer.publish.rerun.viewer import rerun_executable

__all__ = [
    "AXIS_STATE_INDEX",
    "COLORS",
    "ISOLATED_AXIS_INDEX",
    "TIMELINE",
    "RerunMode",
    "RerunModeError",
    "RerunSink",
    "RerunStats",
    "build_blueprint",
    "config_index",
    "config_label",
    "open_rerun_sink",
    "parse_rerun_mode",
    "read_recording",
    "rerun_executable",
]
