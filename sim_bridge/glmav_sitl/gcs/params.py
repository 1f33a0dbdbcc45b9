"""The simulator's MAVLink parameters: what a ground station reads and sets (PARAM_* protocol).

Every parameter is a MAV_PARAM_TYPE_REAL32 (integers such as an axis number are sent as
floats, so MAVProxy and MAVSDK read the same value whatever their int encoding). Three
groups:

- ``VEH_*``: the vehicle file's values (``vehicle/glmav.toml``), read-only. A PARAM_SET is
  answered with the unchanged value and a STATUSTEXT saying why.
- ``SIM_*``: sensor noise and fault injection, settable at run time.
- flight parameters named as PX4 names them so that MAVSDK's helpers work
  (``MIS_TAKEOFF_ALT`` for ``set_takeoff_altitude``, ``RTL_RETURN_ALT``,
  ``MPC_XY_VEL_MAX`` for ``set_maximum_speed``), plus ``MPC_LAND_SPEED`` and
  ``COM_OF_LOSS_T`` (offboard setpoint timeout).

A value outside a parameter's range is refused the same way as a read-only one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from glmav_sitl.params import VehicleParams

#: vehicle-file key -> parameter name (16 characters at most, MAVLink's limit)
VEHICLE_PARAM_NAMES: dict[str, str] = {
    "m": "VEH_M",
    "rho": "VEH_RHO",
    "g": "VEH_G",
    "alpha": "VEH_ALPHA",
    "beta": "VEH_BETA",
    "sigma": "VEH_SIGMA",
    "omega1_nominal": "VEH_OMEGA1_NOM",
    "omega2_nominal": "VEH_OMEGA2_NOM",
    "gamma1": "VEH_GAMMA1",
    "gamma2": "VEH_GAMMA2",
    "d": "VEH_D",
    "ixx": "VEH_IXX",
    "iyy": "VEH_IYY",
    "izz": "VEH_IZZ",
    "body_diameter": "VEH_BODY_DIAM",
    "body_length": "VEH_BODY_LEN",
    "cx": "VEH_CX",
    "cy": "VEH_CY",
    "cz": "VEH_CZ",
    "swash_limit": "VEH_SWASH_LIM",
    "swash_time_constant": "VEH_SWASH_TAU",
    "downwash_hover": "VEH_DOWNWASH",
    "motor_time_constant": "VEH_MOTOR_TAU",
    "omega_max": "VEH_OMEGA_MAX",
}

#: SIM_VFLT_KIND values (the scenario files' fault kinds)
FAULT_KIND_CODES: dict[int, str] = {1: "bias", 2: "freeze", 3: "dropout", 4: "noise"}
#: SIM_VFLT_AXIS values (0 = no fault)
FAULT_AXIS_CODES: dict[int, str] = {1: "n", 2: "e", 3: "d"}


@dataclass
class Param:
    name: str
    value: float
    lo: float
    hi: float
    description: str
    writable: bool = True
    integer: bool = False


class ParamError(ValueError):
    """A refused PARAM_SET (the message is sent to the ground station as STATUSTEXT)."""


class ParamTable:
    """An ordered table of parameters; ``on_change(name, value)`` runs after each accepted set."""

    def __init__(self, params: list[Param], on_change: Callable[[str, float], None]) -> None:
        self._params = list(params)
        self._by_name = {p.name: i for i, p in enumerate(self._params)}
        if len(self._by_name) != len(self._params):
            raise ValueError("duplicate parameter names")
        for p in self._params:
            if len(p.name) > 16:
                raise ValueError(f"parameter name {p.name!r} is longer than 16 characters")
        self._on_change = on_change

    def __len__(self) -> int:
        return len(self._params)

    def __iter__(self) -> Iterator[Param]:
        return iter(self._params)

    def index(self, name: str) -> int:
        return self._by_name[name]

    def at(self, index: int) -> Param:
        return self._params[index]

    def get(self, name: str) -> float:
        return self._params[self._by_name[name]].value

    def find(self, name: str) -> Param | None:
        i = self._by_name.get(name)
        return None if i is None else self._params[i]

    def set(self, name: str, value: float) -> Param:
        """Set ``name`` to ``value`` or raise :class:`ParamError` naming the reason."""
        p = self.find(name)
        if p is None:
            raise ParamError(f"{name}: no such parameter")
        if not p.writable:
            raise ParamError(f"{name}: read-only (the vehicle file's value)")
        if not math.isfinite(value) or not p.lo <= value <= p.hi:
            raise ParamError(f"{name}: {value:g} outside [{p.lo:g}, {p.hi:g}]")
        if p.integer and value != round(value):
            raise ParamError(f"{name}: {value:g} is not a whole number")
        p.value = float(value)
        self._on_change(name, p.value)
        return p


def default_params(
    vehicle: VehicleParams,
    *,
    velocity_sigma_mps: float,
    max_speed_mps: float,
    on_change: Callable[[str, float], None],
) -> ParamTable:
    """The simulator's parameter table (see the module docstring)."""
    ps = [
        Param(
            VEHICLE_PARAM_NAMES[k],
            float(getattr(vehicle, k)),
            -math.inf,
            math.inf,
            f"vehicle file: {k}",
            writable=False,
        )
        for k in VEHICLE_PARAM_NAMES
    ]
    ps += [
        Param(
            "SIM_VEL_SIGMA",
            velocity_sigma_mps,
            0.0,
            5.0,
            "LOCAL_POSITION_NED velocity white noise per axis, m/s",
        ),
        Param(
            "SIM_VFLT_AXIS",
            0.0,
            0.0,
            3.0,
            "velocity fault axis: 0 off, 1 n, 2 e, 3 d",
            integer=True,
        ),
        Param(
            "SIM_VFLT_KIND",
            1.0,
            1.0,
            4.0,
            "fault kind: 1 bias, 2 freeze, 3 dropout, 4 noise",
            integer=True,
        ),
        Param("SIM_VFLT_MAG", 1.0, -20.0, 20.0, "bias (m/s) or noise sigma (m/s)"),
        Param(
            "SIM_VFLT_START",
            -1.0,
            -1.0,
            1e6,
            "fault start, s since boot (-1: when SIM_VFLT_AXIS is set)",
        ),
        Param("SIM_VFLT_LEN", 0.0, 0.0, 1e6, "fault duration, s (0: until SIM_VFLT_AXIS = 0)"),
        Param("MIS_TAKEOFF_ALT", 10.0, 1.0, 100.0, "takeoff altitude above home, m"),
        Param("MPC_TKO_SPEED", 2.0, 0.5, 5.0, "climb speed of a takeoff, m/s"),
        Param("RTL_RETURN_ALT", 15.0, 2.0, 100.0, "return altitude above home, m"),
        Param("MPC_LAND_SPEED", 0.7, 0.2, 3.0, "descent speed when landing, m/s"),
        Param("MPC_XY_VEL_MAX", max_speed_mps, 0.5, 20.0, "horizontal speed limit, m/s"),
        Param("COM_OF_LOSS_T", 1.0, 0.1, 10.0, "offboard setpoint timeout (then HOLD), s"),
    ]
    return ParamTable(ps, on_change)
