"""Vehicle parameters of the GLMAV model (paper section 2), loaded from TOML.

Each entry of ``glmav_sitl/data/vehicle/glmav.toml`` is an inline table
``key = { value = ..., unit = "...", source = "..." }``. Loading checks that every
known key is present, that its unit is exactly the expected one, that the value is a
finite number within a physical range, and that a source is given; anything else
raises :class:`~glmav_toml.ConfigError` naming the file, key and reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from glmav_sitl.config import data_path
from glmav_toml import REQUIRED, Check, TableReader, load_toml, within

DEFAULT_VEHICLE = "vehicle/glmav.toml"

# key -> (expected unit, low, high, low bound open)
_SPEC: dict[str, tuple[str, float, float, bool]] = {
    "m": ("kg", 0.0, 100.0, True),
    "rho": ("kg/m^3", 0.0, 2.0, True),
    "g": ("m/s^2", 0.0, 30.0, True),
    "alpha": ("N*s^2", 0.0, 1e-2, True),
    "beta": ("N*s^2", 0.0, 1e-2, True),
    "sigma": ("-", 0.8, 1.0, False),
    "omega1_nominal": ("rad/s", 0.0, 5000.0, True),
    "omega2_nominal": ("rad/s", 0.0, 5000.0, True),
    "gamma1": ("N*m*s^2", -1e-2, 1e-2, False),
    "gamma2": ("N*m*s^2", -1e-2, 1e-2, False),
    "d": ("m", 0.0, 5.0, False),
    "ixx": ("kg*m^2", 0.0, 10.0, True),
    "iyy": ("kg*m^2", 0.0, 10.0, True),
    "izz": ("kg*m^2", 0.0, 10.0, True),
    "body_diameter": ("m", 0.0, 5.0, True),
    "body_length": ("m", 0.0, 5.0, True),
    "cx": ("-", 0.0, 5.0, False),
    "cy": ("-", 0.0, 5.0, False),
    "cz": ("-", 0.0, 5.0, False),
    "swash_limit": ("rad", 0.0, 0.8, True),
    "swash_time_constant": ("s", 0.0, 1.0, True),
    "downwash_hover": ("m/s", 0.0, 100.0, False),
    "motor_time_constant": ("s", 0.0, 5.0, True),
    "omega_max": ("rad/s", 0.0, 10000.0, True),
}


@dataclass(frozen=True)
class VehicleParams:
    """The GLMAV's physical parameters, SI units (see ``docs/model.md``).

    Frames: body FRD, earth NED. The rotor hub O2 lies ``d`` above the centre of mass
    G, i.e. at ``(0, 0, -d)`` in body axes.
    """

    m: float  # kg
    rho: float  # kg/m^3
    g: float  # m/s^2
    alpha: float  # N s^2, upper rotor thrust coefficient, eq. (5)
    beta: float  # N s^2, lower rotor thrust coefficient, eq. (5)
    sigma: float  # -, coaxial loss factor, eq. (5)
    omega1_nominal: float  # rad/s, upper rotor speed for thrust = weight (no download)
    omega2_nominal: float  # rad/s, lower rotor speed for thrust = weight (no download)
    gamma1: float  # N m s^2, yaw coefficient of the upper rotor, eq. (10)
    gamma2: float  # N m s^2, yaw coefficient of the lower rotor, eq. (10)
    d: float  # m, G to lower hub O2, eq. (10)
    ixx: float  # kg m^2
    iyy: float  # kg m^2
    izz: float  # kg m^2
    body_diameter: float  # m, D of eq. (7)
    body_length: float  # m, l of eq. (7)
    cx: float  # -
    cy: float  # -
    cz: float  # -
    swash_limit: float  # rad, |delta_cx|, |delta_cy| <= limit
    swash_time_constant: float  # s, first-order servo lag of the swash-plate
    downwash_hover: float  # m/s, rotor downwash speed at the body in hover (momentum theory)
    motor_time_constant: float  # s, first-order rotor speed lag
    omega_max: float  # rad/s, rotor speed ceiling

    @property
    def side_area_m2(self) -> float:
        """S of the x and y axes in eq. (7): the cylinder's side, l * D."""
        return self.body_length * self.body_diameter

    @property
    def top_area_m2(self) -> float:
        """S of the z axis in eq. (7): the disc pi D^2 / 4."""
        return math.pi * self.body_diameter**2 / 4.0

    def replace(self, **changes: float) -> VehicleParams:
        d = {k: getattr(self, k) for k in _SPEC}
        d.update(changes)
        return VehicleParams(**d)


def vehicle_params_from_dict(raw: dict[str, Any], path: str | Path) -> VehicleParams:
    """Validate the parsed TOML ``raw`` (see module docstring) into :class:`VehicleParams`."""
    r = TableReader(path, raw)
    r.expect(_SPEC)  # an unknown (misspelt) parameter first: it would hide as "missing"
    values: dict[str, float] = {}
    for key, (unit, lo, hi, lo_open) in _SPEC.items():
        if not r.has(key):
            raise r.error(key, "missing")
        if not isinstance(raw[key], dict):
            raise r.error(key, "expected an inline table {value, unit, source}")
        entry = r.sub(key)
        values[key] = entry.get("value", float, REQUIRED, _in_range(unit, lo, hi, lo_open))
        entry.get("unit", str, REQUIRED, _is_unit(unit))
        entry.get("source", str, REQUIRED, _stated)
        entry.done()
    if values["gamma1"] * values["gamma2"] > 0.0:
        raise r.error(
            "gamma2.value", "gamma1 and gamma2 must have opposite signs (contra-rotation)"
        )
    return VehicleParams(**values)


def _in_range(unit: str, lo: float, hi: float, lo_open: bool) -> Check:
    """The range of a parameter, in its unit."""
    in_range = within(lo, hi, lo_open=lo_open)

    def check(x: float) -> str | None:
        reason = in_range(x)
        return None if reason is None else f"{reason} {unit}"

    return check


def _is_unit(unit: str) -> Check:
    return lambda u: None if u == unit else f"expected unit {unit!r}"


def _stated(source: str) -> str | None:
    return None if source.strip() else "a source or 'estimate: reasoning' is required"


def load_vehicle_params(path: str | Path | None = None) -> VehicleParams:
    """Load and validate a vehicle file (default: the packaged ``vehicle/glmav.toml``)."""
    p = Path(path) if path is not None else data_path(*DEFAULT_VEHICLE.split("/"))
    return vehicle_params_from_dict(load_toml(p), p)
