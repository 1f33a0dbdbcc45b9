"""End to end: a SITL flight recorded to a tlog, ``glmav-observer replay --rrd``, read back.

The simulator flies ``fault-bias`` (a 1 m/s bias on the east velocity measurement from
20 s); the replay writes the records both as JSON lines (``--out``) and as a Rerun
recording (``--rrd``). The recording must hold the same numbers as the JSON lines, on
the vehicle's clock, under the documented entity paths.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from glmav_observer.configurations import CONFIGS, LOST_AXIS_OF_CONFIG
from glmav_observer.publish.rerun import (
    ISOLATED_AXIS_INDEX,
    TIMELINE,
    read_recording,
)

BIN = Path(sys.executable).parent
# Times pass through int64 nanoseconds; JSON keeps floats exactly (shortest repr).
T_TOL_S = 1e-9


def _col(rows: list[dict[str, object]], key: str) -> list[float]:
    return [math.nan if r[key] is None else float(r[key]) for r in rows]  # type: ignore[arg-type]


@pytest.mark.timeout(240)
def test_replay_rrd_holds_the_records(tmp_path: Path) -> None:
    tlog, rrd, jsonl = tmp_path / "f.tlog", tmp_path / "f.rrd", tmp_path / "f.jsonl"
    sitl = [str(BIN / "glmav-sitl"), "run", "--scenario", "fault-bias", "--duration", "24"]
    subprocess.run([*sitl, "--speed", "max", "--seed", "3", "--tlog", str(tlog)], check=True)
    replay = [str(BIN / "glmav-observer"), "replay", str(tlog), "--no-progress"]
    subprocess.run([*replay, "--rrd", str(rrd), "--out", str(jsonl)], check=True)

    rows = [json.loads(line) for line in jsonl.read_text().splitlines()]
    by_schema: dict[str, list[dict[str, object]]] = {}
    for r in rows:
        key = r["schema"] if r["schema"] != "glmav.velocity/1" else f"velocity/{r['config']}"
        by_schema.setdefault(key, []).append(r)
    rec = read_recording(rrd)
    assert {
        chunk.timeline_names[0] for chunk in RrdReader(rrd).stream() if chunk.timeline_names
    } == {TIMELINE}

    # the estimates: per axis one entity, instance i = CONFIGS[i], exactly the records' values
    bank_u = rec["/vehicle/1/estimate/v_body/u"]
    full = by_schema["velocity/full"]
    assert len(bank_u[TIMELINE]) == len(full)
    np.testing.assert_allclose(bank_u[TIMELINE], _col(full, "t_boot_s"), rtol=0, atol=T_TOL_S)
    for i, config in enumerate(CONFIGS):
        expected = _col(by_schema[f"velocity/{config}"], "v_body_mps_u")
        assert [v[i] for v in bank_u["Scalars:scalars"]] == expected
    active = by_schema["velocity/active"]
    # the active estimate: the last instance, after the configurations
    got_n = [v[-1] for v in rec["/vehicle/1/estimate/v_ned/n"]["Scalars:scalars"]]
    assert got_n == _col(active, "v_ned_mps_n")

    truth = by_schema["glmav.truth/1"]
    got = rec["/vehicle/1/truth/v_body/w"]
    np.testing.assert_allclose(got[TIMELINE], _col(truth, "t_boot_s"), rtol=0, atol=T_TOL_S)
    assert [v[0] for v in got["Scalars:scalars"]] == _col(truth, "v_body_mps_w")
    meas = by_schema["glmav.measurement/1"]
    assert [v[0] for v in rec["/vehicle/1/ingest/measurement/v_ned/e"]["Scalars:scalars"]] == _col(
        meas, "v_ned_mps_e"
    )

    # errors: est - truth interpolated linearly in time between SIM_STATE samples
    err = rec["/vehicle/1/error/v_body/u"]
    t_err = np.asarray(err[TIMELINE])
    t_truth = np.asarray(_col(truth, "t_boot_s"))
    truth_u = np.interp(t_err, t_truth, _col(truth, "v_body_mps_u"))
    # vehicle times are whole microseconds: round both sides to 1 µs to match rows
    full_u = {
        round(t, 6): u
        for t, u in zip(_col(full, "t_boot_s"), _col(full, "v_body_mps_u"), strict=True)
    }
    est_u = np.asarray([full_u[round(float(t), 6)] for t in t_err])
    # the same arithmetic up to round-off of the interpolation weights (~1e-15 relative)
    np.testing.assert_allclose([v[0] for v in err["Scalars:scalars"]], est_u - truth_u, atol=1e-9)
    # every estimate bracketed by truth has its error (truth at 50 Hz from t = 0)
    assert len(t_err) >= len(full) - 10

    # the isolation as the service reported it: active configuration, isolated axis, events
    health = by_schema["glmav.health/1"]
    state = rec["/vehicle/1/health/state"]["Scalars:scalars"]
    assert [s[0] for s in state] == [CONFIGS.index(str(h["active_config"])) for h in health]
    isolated = [
        ISOLATED_AXIS_INDEX[h["isolated_faults"][-1]["axis"] if h["isolated_faults"] else None]  # type: ignore[index]
        for h in health
    ]
    assert [s[1] for s in state] == isolated
    assert max(isolated) == ISOLATED_AXIS_INDEX["e"]  # the injected fault is isolated (east)
    events = rec["/vehicle/1/health/events"]
    texts = [t[0] for t in events["TextLog:text"]]
    # fault detection arms when no axis is in warm-up any more: the first such health record
    armed = next(h for h in health if "warmup" not in [h[f"axis_state.{a}"] for a in "ned"])
    assert texts[0] == "fault detection armed on axis n, e, d"
    assert events[TIMELINE][0] == pytest.approx(float(armed["t_boot_s"]), abs=T_TOL_S)  # type: ignore[arg-type]
    assert not any("not armed" in t for t in texts)  # armed within 5 s (arming_timeout_s)
    first = next(h for h in health if h["isolated_faults"])
    fault = first["isolated_faults"][0]  # type: ignore[index]
    assert texts[1] == f"fault isolated on axis e ({fault['kind']}) at {fault['t_detect_s']:.3f} s"
    lost = LOST_AXIS_OF_CONFIG[str(first["active_config"])]
    assert texts[2] == f"active configuration full -> {first['active_config']} ({lost} lost)"
    assert lost == "e"  # the configuration without the faulty axis
    # the status document at the end: the fault's configuration named with its lost axis
    docs = rec["/vehicle/1/health/status"]["TextDocument:text"]
    assert any(d[0].startswith(f"**active: {first['active_config']} (e lost)**") for d in docs)
    assert len(RrdReader(rrd).blueprints()) == 1
