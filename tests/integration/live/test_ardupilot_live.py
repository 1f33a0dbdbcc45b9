"""The service live on ArduPilot's own SITL (issue 29, item 7): a default-configured
ArduCopter quad, ``glmav-observer serve`` as a second client on SERIAL1
(``tcp:127.0.0.1:5762``), one flight of the project's driver
(``scripts/ardupilot_sitl/fly.py``): the 66 s velocity pattern flown clean, then again with
the GPS switched off for 10 s (``SIM_GPS1_ENABLE=0``), home, LAND, and a reboot
(MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN) with 30 s recorded after the new boot's first
LOCAL_POSITION_NED.

Needs an ArduPilot checkout with ``build/sitl/bin/arducopter`` built
(scripts/ardupilot_sitl/README.md) in ``ARDUPILOT``; selected without it, it fails saying so.
CI does not run it: its machines reach only the package registries, and ArduPilot's
source (a git checkout with submodules, then a waf build) is not on any of them.
About 6 minutes of real time (SITL runs at speed-up 1), so it is marked ``live`` and left
out of the default run:

    ARDUPILOT=/path/to/ardupilot python -m pytest -q -n0 -m live tests/integration/live

Everything is judged in vehicle time (``time_boot_ms``) from the service's own records
(``--out live.jsonl``: velocity, truth = SIM_STATE, measurement = LOCAL_POSITION_NED,
health) and the driver's tlog and sidecar (fault windows, GPS_RAW_INT, the reboot).
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from glmav_observer.evaluation import errors_against_truth, rmse

#: the flight takes about 6 min of real time (8 on a loaded machine); the suite's 300 s
#: default timeout does not fit it
FLIGHT_TIMEOUT_S = 1500
pytestmark = [pytest.mark.live, pytest.mark.timeout(FLIGHT_TIMEOUT_S + 120)]

ROOT = Path(__file__).resolve().parents[3]
FLY = ROOT / "scripts" / "ardupilot_sitl" / "fly.py"
OBS = str(Path(sys.executable).with_name("glmav-observer"))
ARDUPILOT = os.environ.get("ARDUPILOT")
#: the velocity pattern (fly.py PATTERN_LOOP_S) is flown twice; the GPS loss is the second
#: loop's 25-35 s (fly.py FAULTS["gps_off"], shifted by one loop)
LOOP_S = 66.0
#: after the loss the bounds look 10 s further (issue 29, "Bounds")
AFTER_LOSS_S = 10.0
#: GPS_RAW_INT fix types below 3D
FIX_3D = 3


def _ardupilot_binary() -> Path | None:
    if not ARDUPILOT:
        return None
    b = Path(ARDUPILOT) / "build" / "sitl" / "bin" / "arducopter"
    return b if b.is_file() else None


def _free_instance() -> int:
    """A SITL instance whose TCP ports (5760 + 10 N .. 5763 + 10 N) are free on loopback."""
    for n in range(10):
        ok = True
        for port in range(5760 + 10 * n, 5764 + 10 * n):
            with socket.socket() as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    ok = False
        if ok:
            return n
    raise RuntimeError("no free SITL instance (ports 5760-5853 all taken)")


@dataclass
class LiveFlight:
    """What one live flight produced, in vehicle time."""

    sidecar: dict[str, Any]
    records: list[dict[str, Any]]
    #: GPS_RAW_INT (t_boot_s, fix_type, satellites) from the driver's tlog, boot 1 only
    gps: list[tuple[float, int, int]] = field(default_factory=list)

    def boot1(self) -> list[dict[str, Any]]:
        """The service's records before the reboot (its time_boot goes back)."""
        out: list[dict[str, Any]] = []
        t_max = -1.0
        for r in self.records:
            if r["t_boot_s"] < t_max - 5.0:
                break
            t_max = max(t_max, r["t_boot_s"])
            out.append(r)
        return out

    def after_reboot(self) -> list[dict[str, Any]]:
        return self.records[len(self.boot1()) :]

    def series(self, schema: str, config: str | None, t0: float, t1: float) -> tuple[Any, Any]:
        rows = [
            r
            for r in self.boot1()
            if r["schema"] == schema
            and (config is None or r.get("config") == config)
            and t0 <= r["t_boot_s"] < t1
        ]
        rows.sort(key=lambda r: r["t_boot_s"])
        t = np.array([r["t_boot_s"] for r in rows], dtype=float)
        v = np.array(
            [[r["v_ned_mps_n"], r["v_ned_mps_e"], r["v_ned_mps_d"]] for r in rows], dtype=float
        ).reshape(-1, 3)
        return t, v

    def rmse(self, what: str, t0: float, t1: float) -> tuple[float, float, float]:
        """RMSE against truth of ``what`` ("full", "active" or "autopilot") over [t0, t1)."""
        tt, vt = self.series("glmav.truth/1", None, t0 - 1.0, t1 + 1.0)
        if what == "autopilot":
            t, v = self.series("glmav.measurement/1", None, t0, t1)
        else:
            t, v = self.series("glmav.velocity/1", what, t0, t1)
        _, err = errors_against_truth(t, v, tt, vt)
        r = rmse(err)
        assert r is not None, f"no {what} samples against truth in [{t0:.1f}, {t1:.1f}) s"
        return r

    def isolations(self, t0: float, t1: float) -> set[tuple[str, str, float]]:
        """Velocity isolations (axis, kind, t_detect_s) detected in [t0, t1), from the
        health records (accelerometer events excluded: axis "body")."""
        out: set[tuple[str, str, float]] = set()
        for r in self.boot1():
            if r["schema"] != "glmav.health/1":
                continue
            for f in r.get("isolated_faults") or []:
                if f["axis"] != "body" and t0 <= f["t_detect_s"] < t1:
                    out.add((f["axis"], f["kind"], round(f["t_detect_s"], 3)))
        return out

    @property
    def pattern_start_s(self) -> float:
        return float(self.sidecar["pattern_window_time_boot_ms"][0]) / 1e3

    @property
    def loss_s(self) -> tuple[float, float]:
        (f,) = self.sidecar["faults"]
        return f["start_time_boot_ms"] / 1e3, f["end_time_boot_ms"] / 1e3


def _gps_from_tlog(tlog: Path) -> list[tuple[float, int, int]]:
    """GPS_RAW_INT of the first boot, stamped with the latest time_boot_ms before it (the
    service's clock does the same for untimed messages)."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tlog))
    t_s = 0.0
    out: list[tuple[float, int, int]] = []
    while (m := log.recv_match()) is not None:
        tb = getattr(m, "time_boot_ms", None)
        if tb is not None:
            if tb * 1e-3 < t_s - 5.0:
                break  # the reboot
            t_s = max(t_s, tb * 1e-3)
        if m.get_type() == "GPS_RAW_INT":
            out.append((t_s, int(m.fix_type), int(m.satellites_visible)))
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> LiveFlight:
    if _ardupilot_binary() is None:
        # selected on purpose (-m live) without what it flies: a failure that says so,
        # never a skip that reads as a pass
        pytest.fail(
            "ARDUPILOT is not set to an ArduPilot checkout with build/sitl/bin/arducopter "
            "(scripts/ardupilot_sitl/README.md builds one)",
            pytrace=False,
        )
    out = tmp_path_factory.mktemp("live")
    n = _free_instance()
    jsonl = out / "live.jsonl"
    serve = [
        OBS,
        "serve",
        "--link",
        f"tcp:127.0.0.1:{5762 + 10 * n}",
        "--out",
        str(jsonl),
        "--rerun",
        "off",
        "--no-zenoh",
        "--workers",
        "1",
    ]
    cmd = [
        sys.executable,
        str(FLY),
        "--name",
        "live",
        "--vehicle",
        "quad",
        "--fault",
        "gps_off",
        "--pattern-loops",
        "2",
        "--fault-shift-s",
        str(LOOP_S),
        "--pattern-s",
        str(2 * LOOP_S + 14.0),
        "--reboot-after",
        "--after-reboot-s",
        "30",
        "--instance",
        str(n),
        "--sitl-timeout-s",
        "1200",
        "--outdir",
        str(out),
        "--attach",
        shlex.join(serve),
    ]
    env = {**os.environ, "RUNS": str(out / "runs")}
    with (out / "fly.log").open("w") as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
        try:
            proc.wait(FLIGHT_TIMEOUT_S)
        except BaseException:
            # SIGINT: the driver's own clean-up stops the service and SITL it started
            proc.send_signal(signal.SIGINT)
            proc.wait(60)
            raise
    sidecar = json.loads((out / "live.json").read_text())
    assert proc.returncode == 0 and sidecar["result"] == "ok", (
        f"the flight failed ({sidecar['result']}); log: {out / 'fly.log'}"
    )
    records = [json.loads(line) for line in jsonl.read_text().splitlines() if line.strip()]
    f = LiveFlight(sidecar, records, _gps_from_tlog(out / "live.tlog"))
    print(f"\nlive flight in {out}: {len(records)} records")
    return f


def _fmt(v: tuple[float, float, float]) -> str:
    return "/".join(f"{x:.3f}" for x in v)


def test_clean_pattern_as_good_as_the_autopilot(flight: LiveFlight) -> None:
    """The first loop of the pattern (no fault): ``full`` within 1.1x the autopilot's own
    EKF velocity RMSE per axis and within 0.05/0.05/0.03 m/s (issue 29's bounds: the
    estimate rests on the autopilot's velocity, so it can only add its own IMU integration
    error; 10 % leaves room for the EKF's and SITL's scheduling jitter, which differ run to
    run by a few mm/s)."""
    t0 = flight.pattern_start_s
    t1 = min(flight.loss_s[0], t0 + LOOP_S)
    full = flight.rmse("full", t0, t1)
    ap = flight.rmse("autopilot", t0, t1)
    print(f"clean [{t0:.1f}, {t1:.1f}) s: full {_fmt(full)} autopilot {_fmt(ap)} m/s")
    for axis, (a, b, cap) in enumerate(zip(full, ap, (0.05, 0.05, 0.03), strict=True)):
        assert a <= 1.1 * b, f"axis {'ned'[axis]}: full {_fmt(full)} > 1.1x autopilot {_fmt(ap)}"
        assert a <= cap, f"axis {'ned'[axis]}: full {_fmt(full)} above 0.05/0.05/0.03"


def test_no_isolation_on_the_clean_pattern(flight: LiveFlight) -> None:
    t0 = flight.pattern_start_s
    iso = flight.isolations(0.0, flight.loss_s[0])
    print(f"isolations before the GPS loss (pattern from {t0:.1f} s): {sorted(iso)}")
    assert iso == set()


def test_gps_loss_flagged_within_1_s_of_the_first_evidence(flight: LiveFlight) -> None:
    """The first evidence: GPS_RAW_INT without a 3D fix after the GPS was switched off.
    North and east must be flagged dead-reckoned in the active record (``dead_reckoned_axes``:
    unaided, docs/field-failures.md; or isolated, or the configuration's lost axis)
    within 1 s of it."""
    t_on, t_off = flight.loss_s
    t_ev = next((t for t, fix, _ in flight.gps if t >= t_on and fix < FIX_3D), None)
    assert t_ev is not None, "GPS_RAW_INT never lost its fix during the GPS loss"
    iso = sorted(i for i in flight.isolations(t_on, t_off + AFTER_LOSS_S) if i[0] in "ne")
    flagged = sorted(
        r["t_boot_s"]
        for r in flight.boot1()
        if r["schema"] == "glmav.velocity/1"
        and r.get("config") == "active"
        and (
            r.get("lost_axis") in ("n", "e") or {"n", "e"} <= set(r.get("dead_reckoned_axes") or ())
        )
        and t_on <= r["t_boot_s"] < t_off + AFTER_LOSS_S
    )
    first = min([i[2] for i in iso] + flagged[:1], default=None)
    delay = None if first is None else first - t_ev
    print(
        f"GPS off at {t_on:.2f} s, no fix at {t_ev:.2f} s (+{t_ev - t_on:.2f} s); "
        f"n and e first flagged at {first} (delay {delay}); isolations {iso}"
    )
    assert delay is not None, "the GPS loss was never flagged"
    assert delay <= 1.0


@pytest.mark.parametrize("phase", ["during", "after"])
def test_gps_loss_estimate_no_worse_than_the_autopilot(flight: LiveFlight, phase: str) -> None:
    """The published estimate (``active``) against the autopilot's own velocity, during the
    10 s loss and the 10 s after it, per axis (issue 29: never worse than the autopilot)."""
    t_on, t_off = flight.loss_s
    t0, t1 = (t_on, t_off) if phase == "during" else (t_off, t_off + AFTER_LOSS_S)
    act = flight.rmse("active", t0, t1)
    ap = flight.rmse("autopilot", t0, t1)
    print(f"GPS loss {phase} [{t0:.1f}, {t1:.1f}) s: active {_fmt(act)} autopilot {_fmt(ap)}")
    for axis in range(3):
        assert act[axis] <= ap[axis], f"axis {'ned'[axis]}: {_fmt(act)} > {_fmt(ap)}"


def test_estimates_resume_within_3_s_of_the_reboot(flight: LiveFlight) -> None:
    """After MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: the service's first estimate of the new boot
    within 3 s of the autopilot's first LOCAL_POSITION_NED (as the driver, with its rates
    set at once, received it)."""
    first_lpn_s = flight.sidecar["reboot"]["first_lpn_time_boot_ms"] / 1e3
    est = sorted(
        r["t_boot_s"]
        for r in flight.after_reboot()
        if r["schema"] == "glmav.velocity/1" and r.get("config") == "active"
    )
    print(f"reboot: first LOCAL_POSITION_NED {first_lpn_s:.2f} s, first estimate {est[:1]}")
    assert est, "no estimate after the reboot"
    assert est[0] - first_lpn_s <= 3.0
