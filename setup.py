"""Build of the compiled per-sample core (Cython); everything else is in pyproject.toml.

The per-sample path (rotation, held inputs and IMU integrals, the despiker, the bank's
closed-form step) is Cython compiled to C: there is one implementation of each, and
`pip install` builds it. A machine without a C compiler gets a message that says what
is missing instead of a compiler's traceback (docs/deployment.md, "Building").
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

#: (module, source): the compiled modules. Each .pyx has a .pyi beside it for the type
#: checker and a .pxd where other compiled modules cimport its C functions.
MODULES = [
    ("glmav_observer.rotation", "service/glmav_observer/rotation.pyx"),
    ("glmav_observer.ingest.fastframe", "service/glmav_observer/ingest/fastframe.pyx"),
    ("glmav_observer.ingest.udp_drain", "service/glmav_observer/ingest/udp_drain.pyx"),
    ("glmav_observer.estimation.inputs", "service/glmav_observer/estimation/inputs.pyx"),
    ("glmav_observer.estimation.despike", "service/glmav_observer/estimation/despike.pyx"),
    ("glmav_observer.estimation.bank_core", "service/glmav_observer/estimation/bank_core.pyx"),
    ("glmav_observer.estimation.imu_window", "service/glmav_observer/estimation/imu_window.pyx"),
    ("glmav_observer.estimation.fdi_kernels", "service/glmav_observer/estimation/fdi_kernels.pyx"),
    ("glmav_observer.estimation.aero.rows", "service/glmav_observer/estimation/aero/rows.pyx"),
    ("glmav_sitl.dynamics.rhs", "sim_bridge/glmav_sitl/dynamics/rhs.pyx"),
    ("glmav_sitl.control.controller", "sim_bridge/glmav_sitl/control/controller.pyx"),
    ("glmav_sitl.mavlink.frame", "sim_bridge/glmav_sitl/mavlink/frame.pyx"),
    ("glmav_sitl.fleet_send", "sim_bridge/glmav_sitl/fleet_send.pyx"),
    ("glmav_sitl.sensors.models", "sim_bridge/glmav_sitl/sensors/models.pyx"),
]

#: The pure-Python modules on the per-message path of a replay, a service and a fleet
#: worker, compiled by Cython as they are written. Python's semantics are kept (an
#: annotation is not a C type; division, indexing and overflow as in Python): the .py is
#: still the one implementation, the type checker's and the tracebacks' source, and the
#: replays are bit-identical; the interpreter's dispatch is what goes (docs/benchmarks/
#: bench_replay.md). glmav_observer/_compiled.py runs a source instead of its compiled copy
#: when the two differ (an edit not rebuilt yet). Left out: start-up, command-line and
#: end-of-run code, the numpy oracle (estimation/observer.py), and estimation/fdi_change.py
#: (Cython 3.3 emits C that does not compile for its tuple annotations; it runs once per
#: isolation).
PY_MODULES = [
    f"glmav_observer.{m}"
    for m in (
        "app",
        "app_replay",
        "app_sinks",
        "evaluation",
        "frames",
        "reads",
        "records",
        "estimation.aero.aided",
        "estimation.aero.control",
        "estimation.aero.drift_rate",
        "estimation.aero.model",
        "estimation.aero.symmetry",
        "estimation.aiding",
        "estimation.bank",
        "estimation.drift",
        "estimation.fdi",
        "estimation.fdi_axis",
        "estimation.fdi_reference",
        "estimation.fdi_types",
        "estimation.gain",
        "estimation.gps_bridge",
        "estimation.imu_filter",
        "estimation.imu_monitor",
        "estimation.observability",
        "estimation.outputs",
        "estimation.reasons",
        "estimation.seed",
        "estimation.selection",
        "estimation.streams",
        "estimation.vehicle",
        "fleet.latency",
        "fleet.routing",
        "fleet.worker_process",
        "ingest.clock",
        "ingest.convert",
        "ingest.framing",
        "ingest.link_budget",
        "ingest.links",
        "ingest.pipeline",
        "ingest.rates",
        "ingest.samples",
        "publish.file_sink",
        "publish.mavlink_out",
        "publish.schema",
        "publish.sink",
        "publish.zenoh_sink",
    )
]

#: Where the build records the SHA-256 of each compiled source (read by
#: glmav_observer/_compiled.py), next to the compiled glmav_observer package.
SOURCES_RECORD = "_compiled_sources.json"


def _py_source(module: str) -> str:
    return "service/" + module.replace(".", "/") + ".py"


#: -O2 without floating-point contraction: the C code rounds each operation as Python
#: did (no fused multiply-add), so the golden replays hold to the last bit or two.
CFLAGS = ["-O2", "-ffp-contract=off", "-fno-fast-math"]
#: no debug information in the built modules (-S): Python's own flags add -g, which makes
#: the 60 modules 51 MB; the symbols stay (py-spy --native and perf still name functions)
LDFLAGS = ["-Wl,-S"]

HELP = """
glmav-observer: building its compiled core failed.

It needs a C compiler and the Python headers:
  Debian/Ubuntu:  apt-get install gcc python3-dev
  Fedora/RHEL:    dnf install gcc python3-devel
  Alpine:         apk add gcc musl-dev python3-dev
  macOS:          xcode-select --install
or install a prebuilt wheel (`python -m build` makes one on a machine that has them).
The compiler said: {err}
"""


class BuildExt(build_ext):
    """build_ext that turns a missing compiler into a message saying what to install."""

    def finalize_options(self) -> None:
        super().finalize_options()
        if self.parallel is None:  # pip passes no -j: one compiler per core
            self.parallel = os.cpu_count() or 1

    def run(self) -> None:
        try:
            super().run()
        except Exception as err:  # CompileError, LinkError, a missing gcc: say what to do
            sys.stderr.write(HELP.format(err=err))
            raise SystemExit(1) from err
        # only once every module is built: a failed build leaves the old record, whose
        # hashes no longer match the edited sources, so those run interpreted
        package_dir = Path(self.get_ext_fullpath("glmav_observer.rotation")).parent
        package_dir.mkdir(parents=True, exist_ok=True)
        (package_dir / SOURCES_RECORD).write_text(json.dumps(COMPILED_SHA256, indent=1) + "\n")

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as err:
            sys.stderr.write(HELP.format(err=err))
            raise SystemExit(1) from err


#: module -> SHA-256 of the source cythonize compiled (written by BuildExt.run)
COMPILED_SHA256: dict[str, str] = {}


def _extensions() -> list[Extension]:
    from Cython.Build import cythonize

    for module in PY_MODULES:
        COMPILED_SHA256[module] = hashlib.sha256(Path(_py_source(module)).read_bytes()).hexdigest()
    exts = [
        Extension(name, [src], extra_compile_args=CFLAGS, extra_link_args=LDFLAGS)
        for name, src in MODULES
    ]
    py_exts = [
        Extension(m, [_py_source(m)], extra_compile_args=CFLAGS, extra_link_args=LDFLAGS)
        for m in PY_MODULES
    ]
    return cythonize(
        exts,
        compiler_directives={
            "language_level": "3",
            "boundscheck": False,
            "wraparound": False,
            "cdivision": True,
            "initializedcheck": False,
            "embedsignature": True,
        },
        include_path=["service"],
        quiet=True,
    ) + cythonize(
        py_exts,
        # Python's semantics: annotations are not C types, and the default (checked)
        # indexing and division; binding keeps functions introspectable as Python's
        compiler_directives={"language_level": "3", "annotation_typing": False, "binding": True},
        quiet=True,
    )


setup(ext_modules=_extensions(), cmdclass={"build_ext": BuildExt})
