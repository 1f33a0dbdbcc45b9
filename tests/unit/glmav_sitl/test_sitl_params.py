"""Loading and validation of the vehicle parameter file."""

from __future__ import annotations

from pathlib import Path

import pytest

from glmav_sitl.config import data_path, packaged_files
from glmav_sitl.params import load_vehicle_params
from glmav_sitl.scenario import scenario_names
from glmav_toml import ConfigError

REPO = Path(__file__).resolve().parents[3]


def test_the_packaged_files_are_the_only_copies() -> None:
    """One copy of each simulator file: the package's (glmav-sitl files lists them);
    configs/ holds the service's files only."""
    shipped = {p.relative_to(data_path()) for p in packaged_files()}
    assert Path("sitl.toml") in shipped and Path("vehicle", "glmav.toml") in shipped
    assert len([p for p in shipped if p.parts[0] == "scenarios"]) == len(scenario_names())
    copies = [p for p in shipped if (REPO / "configs" / p).exists()]
    assert copies == [], f"second copies in configs/: {copies}"


def test_default_vehicle_loads_with_design_values() -> None:
    p = load_vehicle_params()
    assert (p.m, p.alpha, p.beta, p.gamma1, p.gamma2) == (0.2, 2.99e-5, 2.21e-5, 1e-6, -9.025e-7)
    assert (p.ixx, p.izz, p.swash_limit, p.downwash_hover) == (1.2e-3, 2e-4, 0.26, 5.8)


def _write(tmp_path: Path, old: str, new: str) -> Path:
    text = data_path("vehicle", "glmav.toml").read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        (
            'm = { value = 0.200, unit = "kg"',
            'm = { value = 0.200, unit = "g"',
            r"m\.unit: expected unit 'kg'",
        ),
        (
            "m = { value = 0.200",
            "m = { value = -0.2",
            r"m\.value: must be in \(0, 100\] kg, got -0\.2",
        ),
        ("m = { value = 0.200", 'm = { value = "heavy"', r"m\.value: expected a number"),
        (
            "sigma = { value = 1.0",
            "sigma = { value = 0.5",
            r"sigma\.value: must be in \[0\.8, 1\] -, got 0\.5",
        ),
        (
            "gamma2 = { value = -9.025e-7",
            "gamma2 = { value = 9.025e-7",
            r"gamma2\.value: .*opposite",
        ),
        ('source = "ISA sea level"', 'source = ""', r"rho\.source"),
        ("rho = {", "rhoo = {", r"rhoo: unknown key \(known: "),
        ("rho = {", "rho = [", r"not valid TOML"),
    ],
)
def test_bad_vehicle_file_names_file_key_and_reason(
    tmp_path: Path, old: str, new: str, match: str
) -> None:
    path = _write(tmp_path, old, new)
    with pytest.raises(ConfigError, match=match) as e:
        load_vehicle_params(path)
    assert str(path) in str(e.value)


def test_missing_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        load_vehicle_params(tmp_path / "nope.toml")


def test_files_command_prints_the_packaged_paths(capsys: pytest.CaptureFixture[str]) -> None:
    from glmav_sitl.cli import main

    assert main(["files"]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(p) for p in packaged_files()]
    assert str(data_path("sitl.toml")) in printed and len(printed) == len(scenario_names()) + 2


def test_no_test_folder_shadows_the_packages() -> None:
    """pytest runs with --import-mode=importlib: no test folder is put on sys.path, so the
    folders named after the packages (tests/unit/glmav_sitl, ...) never become namespace
    packages hiding them, and importlib.resources finds the real package's data."""
    import importlib.resources
    import importlib.util
    import sys

    tests = (REPO / "tests").resolve()
    on_path = {Path(p).resolve() for p in sys.path if p and Path(p).resolve().is_relative_to(tests)}
    assert on_path <= {tests / "support"}, on_path  # the kit's root, if the install adds it
    for name in ("glmav_sitl", "glmav_observer", "benchmarks"):
        spec = importlib.util.find_spec(name)
        assert spec is not None and spec.origin is not None, name  # a namespace has no origin
        assert not Path(spec.origin).resolve().is_relative_to(tests), spec.origin
    shipped = importlib.resources.files("glmav_sitl").joinpath("data", "sitl.toml")
    assert shipped.read_bytes() == data_path("sitl.toml").read_bytes()
