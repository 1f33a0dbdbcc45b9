"""Configuration checks of the Zenoh sink: JSON5 files, the embedded default, decimation,
error messages (no sessions)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import zenoh

from glmav_observer.publish.schema import DEFAULT_DECIMATION, KINDS
from glmav_observer.publish.zenoh_config import (
    EMBEDDED_DEFAULT_JSON5,
    ZenohConfigError,
    check_decimation,
    clean_zenoh_error,
    load_zenoh_config,
)

REPO = Path(__file__).resolve().parents[4]
CONFIG_DIR = REPO / "configs" / "zenoh"


def _get(config: Any, key: str) -> Any:
    return json.loads(config.get_json(key))


def test_decimation_defaults_and_errors() -> None:
    assert check_decimation(None) == DEFAULT_DECIMATION == dict.fromkeys(KINDS, 1)
    assert check_decimation({"velocity": 5, "truth": 0})["velocity"] == 5
    for bad, message in [
        ({"speed": 1}, "unknown key kind 'speed'"),
        ({"health": -1}, r"decimation.health: must be an integer in \[0, 10000\].*got -1"),
        ({"truth": 10_001}, r"decimation.truth: must be an integer in \[0, 10000\].*got 10001"),
        ({"active": 2.5}, "decimation.active: must be .*got 2.5"),
        ({"active": True}, "decimation.active: must be .*got True"),
    ]:
        with pytest.raises(ZenohConfigError, match=message):
            check_decimation(bad)


def test_one_decimation_check_for_the_file_the_sink_and_the_schema() -> None:
    """[zenoh.decimation], the sink's mapping and the published config's schema accept the
    same kinds and the same values (one definition: publish/schema.py)."""
    from glmav_observer.config import ConfigError, load_config, parse_config
    from glmav_observer.publish.schema import CONFIG_SCHEMA, MAX_DECIMATION, validate

    assert load_config(None).zenoh.decimation == check_decimation(None)
    for kind in KINDS:
        for every in (0, 7, MAX_DECIMATION):
            parsed = parse_config({"zenoh": {"decimation": {kind: every}}}).zenoh.decimation
            assert parsed == check_decimation({kind: every})
            published = {
                "schema": CONFIG_SCHEMA,
                "service_id": "s",
                "prefix": "glmav",
                "zenoh_config": None,
                "decimation": parsed,
                "rates_hz": load_config(None).zenoh.reads().to_dict(),
                "config": {},
            }
            assert validate(published) == []
            assert validate({**published, "decimation": {**parsed, kind: -1}}) != []
        for every in (-1, MAX_DECIMATION + 1):
            with pytest.raises(ConfigError, match=rf"zenoh.decimation.{kind}: must be"):
                parse_config({"zenoh": {"decimation": {kind: every}}})
            with pytest.raises(ZenohConfigError, match=rf"decimation.{kind}: must be"):
                check_decimation({kind: every})


def test_shipped_configs_parse_and_keep_multicast_where_documented() -> None:
    names = sorted(p.name for p in CONFIG_DIR.glob("*.json5"))
    assert names == [
        "acl-router.json5",
        "acl-service-client.json5",
        "client-router.json5",
        "client-tls.json5",
        "peer-lan.json5",
        "peer-local.json5",
        "router-tls.json5",
        "router.json5",
    ]
    for name in names:
        config, shown = load_zenoh_config(CONFIG_DIR / name)
        assert shown == str(CONFIG_DIR / name)
        multicast = _get(config, "scouting/multicast/enabled")
        assert multicast is (name == "peer-lan.json5"), name
    acl, _ = load_zenoh_config(CONFIG_DIR / "acl-router.json5")
    assert _get(acl, "access_control/enabled") is True
    assert _get(acl, "access_control/default_permission") == "deny"
    tls, _ = load_zenoh_config(CONFIG_DIR / "router-tls.json5")
    assert _get(tls, "listen/endpoints") == ["tls/0.0.0.0:7447"]
    assert _get(tls, "transport/link/tls/enable_mtls") is True


def test_peer_local_file_equals_the_embedded_default() -> None:
    from_file, _ = load_zenoh_config(CONFIG_DIR / "peer-local.json5")
    embedded, name = load_zenoh_config(None)
    assert name == "<embedded peer-local default>"
    assert str(from_file) == str(embedded)
    assert zenoh.Config.from_json5(EMBEDDED_DEFAULT_JSON5) is not None
    assert _get(embedded, "mode") == "peer"
    assert _get(embedded, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert _get(embedded, "connect/endpoints") == ["tcp/127.0.0.1:7447"]
    assert _get(embedded, "scouting/multicast/enabled") is False


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ('{ mode: "client", connect: { endpoints: [', "expected"),
        ('{ mode: "rooter" }', "unknown variant `rooter`"),
        ("{ listne: {} }", "unknown field `listne`"),
        (
            '{ mode: "client", scouting: { multicast: { enabled: false } } }',
            "needs connect.endpoints",
        ),
        ("[1, 2]", "invalid type"),
    ],
)
def test_bad_files_name_the_file_and_the_problem(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "bad.json5"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ZenohConfigError) as info:
        load_zenoh_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert problem in message
    assert "/root/.cargo" not in message
    assert isinstance(info.value, ValueError)


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(ZenohConfigError, match=r"missing\.json5: cannot read: No such file"):
        load_zenoh_config(tmp_path / "missing.json5")
    binary = tmp_path / "bin.json5"
    binary.write_bytes(b"\xff\xfe{}")
    with pytest.raises(ZenohConfigError, match=r"bin\.json5: not UTF-8"):
        load_zenoh_config(binary)
    with pytest.raises(ZenohConfigError, match="cannot read"):
        load_zenoh_config(tmp_path)  # a directory


def test_clean_zenoh_error_drops_rust_locations() -> None:
    err = "Unable to connect to any of [x]!  at /root/.cargo/git/z/orchestrator.rs:447."
    assert clean_zenoh_error(RuntimeError(err)) == "Unable to connect to any of [x]!"
