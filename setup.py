"""Build of the compiled per-sample core (Cython); everything else is in pyproject.toml.

The per-sample path (rotation, held inputs and IMU integrals, the despiker, the bank's
closed-form step) is Cython compiled to C: there is one implementation of each, and
`pip install` builds it. A machine without a C compiler gets a message that says what
is missing instead of a compiler's traceback (docs/deployment.md, "Building").
"""

from __future__ import annotations

import sys

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

#: -O2 without floating-point contraction: the C code rounds each operation as Python
#: did (no fused multiply-add), so the golden replays hold to the last bit or two.
CFLAGS = ["-O2", "-ffp-contract=off", "-fno-fast-math"]

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

    def run(self) -> None:
        try:
            super().run()
        except Exception as err:  # CompileError, LinkError, a missing gcc: say what to do
            sys.stderr.write(HELP.format(err=err))
            raise SystemExit(1) from err

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as err:
            sys.stderr.write(HELP.format(err=err))
            raise SystemExit(1) from err


def _extensions() -> list[Extension]:
    from Cython.Build import cythonize

    exts = [Extension(name, [src], extra_compile_args=CFLAGS) for name, src in MODULES]
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
    )


setup(ext_modules=_extensions(), cmdclass={"build_ext": BuildExt})
