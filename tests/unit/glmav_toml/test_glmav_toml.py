"""One way to read and check TOML for the service and the simulator (glmav_toml)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from glmav_observer.config import load_config
from glmav_sitl.scenario import load_sitl_config
from glmav_toml import REQUIRED, ConfigError, TableReader, load_toml, one_of, within


def test_service_and_simulator_refuse_a_bad_value_the_same_way(tmp_path: Path) -> None:
    service = tmp_path / "service.toml"
    service.write_text("[fdi]\nwarmup_s = 0.5\n", encoding="utf-8")
    sitl = tmp_path / "sitl.toml"
    sitl.write_text("[imu]\naccel_noise_density = -1.0\n", encoding="utf-8")
    with pytest.raises(ConfigError) as a:
        load_config(service)
    with pytest.raises(ConfigError) as b:
        load_sitl_config(sitl)
    assert (a.value.file, a.value.key) == (str(service), "fdi.warmup_s")
    assert str(a.value) == f"{service}: fdi.warmup_s: must be in [1, 600], got 0.5"
    assert (b.value.file, b.value.key) == (str(sitl), "imu.accel_noise_density")
    assert str(b.value) == f"{sitl}: imu.accel_noise_density: must be in [0, 1000], got -1.0"


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        (None, "file not found"),
        ("a = [", "not valid TOML"),
        (b"\xff\xfe", "not UTF-8 text (byte 0: 0xff)"),
    ],
)
def test_unreadable_files_name_the_file(
    tmp_path: Path, text: str | bytes | None, reason: str
) -> None:
    p = tmp_path / "x.toml"
    if isinstance(text, bytes):
        p.write_bytes(text)
    elif text is not None:
        p.write_text(text, encoding="utf-8")
    for load in (load_toml, load_config, load_sitl_config):
        with pytest.raises(ConfigError, match=f"^{p}: -: ") as e:
            load(p)
        assert e.value.reason.startswith(reason)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"\xef\xbb\xbf[service]\n", "starts with a UTF-8 byte order mark (BOM)"),
        # 100,000 levels: tomllib's recursion raised RecursionError (a traceback); 33: the
        # limit is 32 (the project's files nest 3 deep)
        (
            b"x = " + b"[" * 100_000 + b"]" * 100_000 + b"\n",
            "arrays or tables nested deeper than 32",
        ),
        (b"x = " + b"[" * 33 + b"]" * 33 + b"\n", "arrays or tables nested deeper than 32"),
        (
            b"x = " + b"{a = " * 33 + b"1" + b"}" * 33 + b"\n",
            "arrays or tables nested deeper than 32",
        ),
        (b"# " + b"x" * 1_000_000 + b"\n", "1,000,003 bytes: larger than 1,000,000: refused"),
    ],
)
def test_odd_files_are_refused_with_the_reason(tmp_path: Path, content: bytes, reason: str) -> None:
    p = tmp_path / "x.toml"
    p.write_bytes(content)
    for load in (load_toml, load_config, load_sitl_config):
        with pytest.raises(ConfigError, match=f"^{p}: -: ") as e:
            load(p)
        assert e.value.reason.startswith(reason), e.value.reason


def test_32_levels_are_read(tmp_path: Path) -> None:
    p = tmp_path / "x.toml"
    p.write_text("x = " + "[" * 32 + "1" + "]" * 32 + "\n", encoding="utf-8")
    depth, x = 0, load_toml(p)["x"]
    while isinstance(x, list):
        depth, x = depth + 1, x[0]
    assert (depth, x) == (32, 1)


def test_a_directory_is_refused_as_not_a_regular_file(tmp_path: Path) -> None:
    """(/dev/zero and a FIFO, which blocked or filled the memory, are run as processes
    with bounds in tests/integration/reliability/test_odd_inputs.py.)"""
    d = tmp_path / "dir.toml"
    d.mkdir()
    for load in (load_toml, load_config, load_sitl_config):
        with pytest.raises(ConfigError) as e:
            load(d)
        assert e.value.reason == "is a directory, not a regular file: refused"


def test_reader_types_ranges_defaults_and_unknown_keys() -> None:
    r = TableReader("f.toml", {"n": 3, "x": 2, "flag": True, "v": [1, 2.5], "t": {"k": "b"}})
    assert r.get("n", int, REQUIRED, within(1, 10)) == 3
    assert r.get("x", float, 0.0) == 2.0 and isinstance(r.get("x", float, 0.0), float)
    assert r.get("absent", float, 7.5) == 7.5
    assert r.vector("v", 2) == (1.0, 2.5)
    t = r.sub("t")
    assert t.get("k", str, REQUIRED, one_of("a", "b")) == "b"
    t.done()
    with pytest.raises(ConfigError, match=r"^f\.toml: flag: unknown key \(known: "):
        r.done()
    cases = [
        (lambda: r.get("flag", int), "flag: expected an integer, got True"),
        (lambda: r.get("n", int, REQUIRED, within(5, 9)), "n: must be in [5, 9], got 3"),
        (lambda: r.get("missing", float), "missing: missing"),
        (lambda: r.vector("v", 3), "v: expected a list of 3 numbers, got [1, 2.5]"),
        (lambda: r.vector("v", 2, check=within(0, 2)), "v[1]: must be in [0, 2], got 2.5"),
        (lambda: t.get("k", str, REQUIRED, one_of("a")), "t.k: must be one of a, got 'b'"),
        (lambda: TableReader("f", {"x": float("nan")}).get("x", float), "x: must be finite"),
    ]
    for call, message in cases:
        with pytest.raises(ConfigError) as e:
            call()
        assert str(e.value).split(": ", 1)[1].startswith(message), str(e.value)


def test_glmav_toml_imports_neither_package() -> None:
    """MAVLink stays the only contract: the shared reader depends on neither side."""
    code = (
        "import sys, glmav_toml; "
        "print(sorted(m for m in sys.modules if m.startswith(('glmav_observer', 'glmav_sitl'))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], check=True, capture_output=True, text=True, timeout=60
    ).stdout
    assert out.strip() == "[]"
