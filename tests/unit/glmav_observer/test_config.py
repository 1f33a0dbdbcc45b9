"""configs/service.toml: the shipped file equals the defaults; bad values name file, key, reason."""

from __future__ import annotations

from pathlib import Path

import pytest

from glmav_observer.cli import main
from glmav_observer.config import ConfigError, load_config, parse_config
from glmav_observer.reads import READS_LIVE_DEFAULT

REPO = Path(__file__).resolve().parents[3]


def test_shipped_file_documents_the_defaults() -> None:
    shipped = load_config(REPO / "configs" / "service.toml")
    defaults = load_config(None)
    assert shipped.ingest == defaults.ingest
    assert shipped.estimation == defaults.estimation
    assert shipped.zenoh == defaults.zenoh
    assert shipped.rerun == defaults.rerun
    assert shipped.mavlink_out == defaults.mavlink_out
    assert shipped.mavlink_out.enabled is False  # MAVLink output: opt-in
    assert shipped.zenoh.enabled is True  # serve publishes on Zenoh unless told not to (#28)
    assert shipped.zenoh.reads() == READS_LIVE_DEFAULT  # built only at the consumers' rates
    assert shipped.rerun.mode == "off"


@pytest.mark.parametrize(
    ("doc", "key", "reason"),
    [
        ({"fdi": {"bias_threshold_mps": -1.0}}, "fdi.bias_threshold_mps", r"must be in \(0, 100\]"),
        ({"fdi": {"k_isolate": "3"}}, "fdi.k_isolate", "expected an integer"),
        ({"fdi": {"warmup_s": 0.5}}, "fdi.warmup_s", r"must be in \[1, 600\]"),
        (
            {"estimation": {"e_form": "approx"}},
            "estimation.e_form",
            "must be one of exact, small_angle",
        ),
        ({"estimation": {"gama_full": 3.0}}, "estimation.gama_full", "unknown key"),
        ({"rates": {"hz": {"FOO": 10.0}}}, "rates.hz.FOO", "unknown message"),
        ({"ingest": {"raw_imu": {"sysid": {"300": {}}}}}, "ingest.raw_imu.sysid.300", "1..255"),
        ({"rerun": {"mode": "tv"}}, "rerun.mode", "expected off, spawn"),
        ({"service": {"out": "x.txt"}}, "service.out", ".csv or .jsonl"),
        ({"ingest": {"max_vehicles": True}}, "ingest.max_vehicles", "integer"),
        ({"mavlink_out": {"component_id": 190}}, "mavlink_out.component_id", "ground station"),
        ({"mavlink_out": {"system_id": 255}}, "mavlink_out.system_id", "255 is a GCS"),
        ({"mavlink_out": {"enabled": True}}, "mavlink_out.link", "required when"),
        ({"mavlink_out": {"rate_hz": 0.0}}, "mavlink_out.rate_hz", r"in \(0, 1000\]"),
        ({"mavlink_out": {"odometri": True}}, "mavlink_out.odometri", "unknown key"),
    ],
)
def test_bad_values_name_file_key_and_reason(doc: dict, key: str, reason: str) -> None:
    with pytest.raises(ConfigError, match=reason) as info:
        parse_config(doc, "my.toml")
    assert info.value.file == "my.toml"
    assert info.value.key == key


def test_per_vehicle_raw_imu_scale() -> None:
    cfg = parse_config({"ingest": {"raw_imu": {"sysid": {"2": {"accel_mps2_per_lsb": 0.5}}}}})
    assert cfg.ingest.raw_imu_by_sysid[2].accel_mps2_per_lsb == 0.5
    assert cfg.ingest.raw_imu_by_sysid[2].gyro_radps_per_lsb == 1e-3  # default kept


def test_cli_exit_code_2_on_bad_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[fdi]\nk_isolate = 0\n", encoding="utf-8")
    log = tmp_path / "x.tlog"
    log.write_bytes(b"")
    assert main(["replay", str(log), "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "fdi.k_isolate" in err and "must be in [1, 10000]" in err
    broken = tmp_path / "broken.toml"
    broken.write_text("[fdi\n", encoding="utf-8")
    assert main(["serve", "--config", str(broken)]) == 2
    assert "not valid TOML" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("doc", "key", "reason"),
    [
        # issue 18.5: each of these passed validation and failed later (or never)
        ({"ingest": {"reorder_window_s": 1e9}}, "ingest.reorder_window_s", r"\[0, 1\]"),
        (
            {"service": {"udp_receive_buffer_bytes": 9223372036854775807}},
            "service.udp_receive_buffer_bytes",
            r"\[4096, 1073741824\]",
        ),
        ({"rerun": {"serve_bind": "not an ip"}}, "rerun.serve_bind", "must be an IP address"),
        ({"service": {"id": "a b/c"}}, "service.id", "1 to 64 characters"),
        ({"zenoh": {"prefix": "glmav/**"}}, "zenoh.prefix", "no wildcards"),
        ({"zenoh": {"encoding": "cbor"}}, "zenoh.encoding", "must be one of 'json', 'msgpack'"),
        ({"ingest": {"max_vehicles": 100_000}}, "ingest.max_vehicles", r"\[1, 254\]"),
        ({"ingest": {"confirm_samples": 0}}, "ingest.confirm_samples", r"\[1, 1000\]"),
        ({"rates": {"hz": {"ATTITUDE": 1e6}}}, "rates.hz.ATTITUDE", r"\[0, 1000\], or -1"),
        ({"rates": {"mode": "always"}}, "rates.mode", "must be one of request, observe"),
        ({"rates": {"retry_s": 10.0, "retry_max_s": 5.0}}, "rates.retry_max_s", ">= retry_s"),
        ({"rates": {"link_bytes_per_s": -1.0}}, "rates.link_bytes_per_s", r"\[0, 1e\+09\]"),
        ({"rates": {"link_budget_fraction": 0.0}}, "rates.link_budget_fraction", r"\(0, 1\]"),
        ({"estimation": {"gamma_full": 1e12}}, "estimation.gamma_full", r"\(0, 1000\]"),
        ({"fdi": {"k_isolate": 10**9}}, "fdi.k_isolate", r"\[1, 10000\]"),
        ({"zenoh": {"decimation": {"health": -1}}}, "zenoh.decimation.health", r"\[0, 10000\]"),
        # issue 28: the rates the Zenoh sink reads (and the estimators build)
        ({"zenoh": {"rates": {"active": -5.0}}}, "zenoh.rates.active", "number of Hz >= 0.01"),
        ({"zenoh": {"rates": {"full": "all"}}}, "zenoh.rates.full", r"\"every\""),
        ({"zenoh": {"rates": {"velocity": 10.0}}}, "zenoh.rates.velocity", "unknown"),
    ],
)
def test_every_value_has_a_range(doc: dict, key: str, reason: str) -> None:
    with pytest.raises(ConfigError, match=reason) as info:
        parse_config(doc, "my.toml")
    assert info.value.key == key


def test_every_generic_field_has_a_range() -> None:
    """A new numeric field of the clock, the estimator or the FDI must get a range in
    config._BOUNDS (or loading the defaults fails loudly, naming it)."""
    cfg = parse_config({})
    assert cfg.ingest.clock.confirm_forward_s == 1.0
    assert cfg.ingest.rates_min_hz == {
        "ATTITUDE": 10.0,
        "HIGHRES_IMU": 50.0,
        "LOCAL_POSITION_NED": 5.0,
        "SIM_STATE": 0.0,
    }


def test_zenoh_rates_read_every_and_numbers_and_full_rate_overrides() -> None:
    cfg = parse_config({"zenoh": {"rates": {"active": "every", "c1": 0, "health": 2.5}}})
    reads = cfg.zenoh.reads()
    assert reads.rate("active") == float("inf") and reads.rate("c1") == 0.0
    assert reads.rate("health") == 2.5 and reads.rate("full") == 10.0  # the default kept
    assert cfg.effective()["zenoh"]["rates_hz"]["active"] == "every"  # JSON has no inf
    full = parse_config({"zenoh": {"full_rate": True, "rates": {"c1": 0}}})
    assert all(r == float("inf") for r in full.zenoh.reads().rates_hz.values())


def test_link_capacity_settings() -> None:
    """Issue 29.6: ``[rates] link_bytes_per_s`` and ``link_budget_fraction``."""
    cfg = parse_config({"rates": {"link_bytes_per_s": 5760.0, "link_budget_fraction": 0.25}})
    assert cfg.ingest.link_bytes_per_s == 5760.0 and cfg.ingest.link_budget_fraction == 0.25
    default = parse_config({})
    assert default.ingest.link_bytes_per_s is None and default.ingest.link_budget_fraction == 0.5
