"""Golden replays: what the service decided and estimated on fixed logs, kept in the repo
(``tests/data/golden/``) so that a refactor of the estimator shows any change it makes.

One case is one log replayed through the service with the default configuration (a
MAVLink ``.tlog`` through :func:`glmav_testkit.fault_replay.replay_cases`, with velocity
faults injected for the fault cases; a ``.ulg`` or dataflash ``.BIN`` through
:func:`glmav_observer.app_replay.replay_flight_log`). Its golden holds, for one vehicle
(the lowest system id that produced estimates):

- every decision: the estimator's fault events (``FaultEvent.to_dict()``) and switch
  events (``SwitchEvent.to_dict()``), as the service's summary publishes them;
- the ``full``, ``active`` and ``aided`` velocity records, decimated to 10 Hz by
  :func:`decimate`, as columns (time, NED velocity, health, lost axis, σ of the lost axis).

Files are gzip'd JSON: Python writes floats with ``repr``, which reads back to the same
double, so a golden compares bit for bit when nothing changed.

    python -m glmav_testkit.golden --update [--only NAME ...]   # re-baseline (README)
    python -m glmav_testkit.golden [--only NAME ...]            # compare only, write nothing
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from glmav_observer.records import NED_AXES, Record, VelocityRecord
from glmav_testkit import REPO_ROOT
from glmav_testkit.fault_replay import LogResult, RecordCollector, VelocityFault, replay_cases

DATA = REPO_ROOT / "tests" / "data"
GOLDEN_DIR = DATA / "golden"
#: The golden's layout; a change of layout is a re-baseline of every file.
FORMAT = 1
#: Decimation of the velocity records kept (:func:`decimate`).
RATE_HZ = 10.0
#: The estimate streams kept (``VelocityRecord.config``).
STREAMS = ("full", "active", "aided")
#: Injected faults last this long (as in the corpus tests and benchmarks/corpus.py).
FAULT_LENGTH_S = 10.0


# ---------------------------------------------------------------------- the cases
@dataclass(frozen=True, slots=True)
class GoldenCase:
    """One golden replay: ``log`` relative to tests/data, ``faults`` injected (tlogs only);
    ``sysid`` the vehicle kept (None: the lowest that produced estimates)."""

    name: str
    log: str
    faults: tuple[VelocityFault, ...] = ()
    sysid: int | None = None

    @property
    def path(self) -> Path:
        return DATA / self.log

    @property
    def is_tlog(self) -> bool:
        return ".tlog" in self.path.name

    @property
    def golden_path(self) -> Path:
        return GOLDEN_DIR / f"{self.name}.json.gz"


def _fault_case(log: str, axis: int, kind: Any, t_on_s: float, size_mps: float) -> GoldenCase:
    f = VelocityFault(axis, kind, t_on_s, t_on_s + FAULT_LENGTH_S, size_mps)
    size = f"_{size_mps:g}" if kind in ("bias", "noise") else ""
    return GoldenCase(
        f"{log}__{kind}{size}_{NED_AXES[axis]}_{t_on_s:g}s",
        f"ardupilot_sitl/{log}.tlog.xz",
        (f,),
    )


_ARDUPILOT = (
    "a_quad_wind",
    "b_quad_gps_off",
    "c_quad_acc_bias",
    "d_quad_gps_noise",
    "e_quad_vib",
    "f_coax_clean",
    "g_heli_clean",
    "h_quad_gps_glitch",
)

#: Every case, the cases of one log together (a replay shares the log's prefix among them).
#: The injected faults: each kind on a different axis and flight, onsets spread over the
#: flight pattern (quad and coax fly it over 53.6-133.7 s, heli over 74.3-154.3 s).
CASES: tuple[GoldenCase, ...] = (
    *(GoldenCase(n, f"ardupilot_sitl/{n}.tlog.xz") for n in _ARDUPILOT),
    _fault_case("a_quad_wind", 1, "bias", 70.0, 0.5),
    _fault_case("a_quad_wind", 0, "noise", 112.0, 0.5),
    _fault_case("f_coax_clean", 0, "freeze", 88.0, 0.0),
    _fault_case("f_coax_clean", 2, "bias", 60.0, 1.0),
    _fault_case("g_heli_clean", 2, "nan", 125.0, 0.0),
    # a disarmed vehicle that sends no LOCAL_POSITION_NED: no estimate, no decision (and,
    # kept so, its golden says a refactor still makes none from attitude and IMU alone)
    GoldenCase("ardusub_2023-04-18", "real-tlogs/ardusub_2023-04-18.tlog.xz", sysid=1),
    GoldenCase("ardusub_small", "real-tlogs/ardusub_small.tlog.xz"),
    GoldenCase("glmav_sitl_fault_noise", "glmav_sitl/glmav_sitl_fault_noise.tlog.xz"),
    GoldenCase("px4_sitl_trimmed", "public-logs/px4_sitl_trimmed.ulg.gz"),
    GoldenCase("arducopter_sitl_trimmed", "public-logs/arducopter_sitl_trimmed.BIN.gz"),
)
CASES_BY_NAME = {c.name: c for c in CASES}


# ---------------------------------------------------------------------- decimation
def decimate(records: Iterable[VelocityRecord], rate_hz: float = RATE_HZ) -> list[VelocityRecord]:
    """The records kept at ``rate_hz``, per stream (``sysid``, ``config``) independently,
    in record order: a record is kept if it is its stream's first or its time is at or
    after the stream's ``next_due``; after keeping one at time t,
    ``next_due = (math.floor(t * rate_hz) + 1) / rate_hz``.

    This is the same rule the service's record builder (``estimation/outputs.py``) uses
    to build a stream's records only when they are due, so a golden at 10 Hz and the
    service publishing at 10 Hz keep the same instants.
    """
    next_due: dict[tuple[int, str], float] = {}
    kept: list[VelocityRecord] = []
    for r in records:
        key = (r.sysid, r.config)
        due = next_due.get(key)
        if due is None or r.t_boot_s >= due:
            kept.append(r)
            next_due[key] = (math.floor(r.t_boot_s * rate_hz) + 1) / rate_hz
    return kept


class GoldenCollector(RecordCollector):
    """The replay's sink: the evaluation series (:class:`RecordCollector`) and every
    ``full``/``active``/``aided`` record whole, in publication order."""

    def __init__(self) -> None:
        super().__init__()
        self.records: list[VelocityRecord] = []

    def write(self, record: Record) -> None:
        super().write(record)
        if isinstance(record, VelocityRecord) and record.config in STREAMS:
            self.records.append(record)

    def first_sysid(self) -> int | None:
        """The lowest system id with estimates (``fault_replay.replay``'s vehicle)."""
        return min((r.sysid for r in self.records), default=None)


# ---------------------------------------------------------------------- replay -> golden
def _columns(records: Sequence[VelocityRecord]) -> dict[str, dict[str, list[Any]]]:
    out: dict[str, dict[str, list[Any]]] = {}
    for config in STREAMS:
        rs = [r for r in records if r.config == config]
        out[config] = {
            "t_boot_s": [r.t_boot_s for r in rs],
            **{
                f"v_ned_mps_{a}": [float(r.v_ned_mps[i]) for r in rs]
                for i, a in enumerate(NED_AXES)
            },
            "health": [r.health for r in rs],
            "lost_axis": [r.lost_axis for r in rs],
            "sigma_lost_mps": [
                None if r.sigma_lost_mps is None else float(r.sigma_lost_mps) for r in rs
            ],
        }
    return out


def _golden(
    case: GoldenCase,
    collector: GoldenCollector,
    sysid: int,
    faults: list[dict[str, Any]],
    switches: list[dict[str, Any]],
) -> dict[str, Any]:
    records = decimate((r for r in collector.records if r.sysid == sysid), RATE_HZ)
    return {
        "format": FORMAT,
        "case": case.name,
        "log": case.log,
        "injected": [
            {
                "axis": f.axis_name,
                "kind": f.kind,
                "t_on_s": f.t_on_s,
                "t_off_s": f.t_off_s,
                "size_mps": f.size_mps,
            }
            for f in case.faults
        ],
        "sysid": sysid,
        "rate_hz": RATE_HZ,
        "faults": faults,
        "switches": switches,
        "estimates": _columns(records),
    }


def _from_log_result(case: GoldenCase, r: LogResult) -> dict[str, Any]:
    collector = r.collector
    assert isinstance(collector, GoldenCollector)
    sysid = case.sysid if case.sysid is not None else collector.first_sysid()
    if sysid is None:
        raise ValueError(f"{case.name}: no vehicle produced estimates")
    return _golden(
        case,
        collector,
        sysid,
        [f.to_dict() for f in r.fault_events],
        [s.to_dict() for s in r.switch_events],
    )


def _replay_flight_log(case: GoldenCase) -> dict[str, Any]:
    from glmav_observer.app_replay import replay_flight_log
    from glmav_observer.config import ServiceConfig

    collector = GoldenCollector()
    with tempfile.TemporaryDirectory(prefix="glmav-golden-") as tmp:
        log = Path(tmp) / case.path.name.removesuffix(".gz")  # the reader goes by suffix
        log.write_bytes(gzip.decompress(case.path.read_bytes()))
        summary = replay_flight_log(log, ServiceConfig(), [collector])
    sysid = case.sysid if case.sysid is not None else collector.first_sysid()
    if sysid is None:
        raise ValueError(f"{case.name}: no vehicle produced estimates")
    vehicle = summary.service.vehicles[sysid]
    return _golden(case, collector, sysid, list(vehicle.faults), list(vehicle.switches))


def replay_group(cases: Sequence[GoldenCase]) -> Iterator[tuple[GoldenCase, dict[str, Any]]]:
    """(case, fresh golden) for cases of one log, replayed once: a tlog's cases share the
    replay before the first fault's onset (``replay_cases``, equal to separate replays
    bit for bit)."""
    if not cases:
        return
    log = cases[0].path
    if any(c.path != log or c.sysid != cases[0].sysid for c in cases):
        raise ValueError("replay_group: cases of one log (and vehicle) only")
    if not cases[0].is_tlog:
        for c in cases:
            yield c, _replay_flight_log(c)
        return
    results = replay_cases(
        log, [c.faults for c in cases], sysid=cases[0].sysid, collector_type=GoldenCollector
    )
    for c, r in zip(cases, results, strict=True):
        yield c, _from_log_result(c, r)


def groups(cases: Iterable[GoldenCase] = CASES) -> dict[str, list[GoldenCase]]:
    """The cases by log (``GoldenCase.log``), in :data:`CASES` order."""
    out: dict[str, list[GoldenCase]] = {}
    for c in cases:
        out.setdefault(c.log, []).append(c)
    return out


def replay(case: GoldenCase) -> dict[str, Any]:
    """One case's fresh golden (alone: :func:`replay_group` shares a log's prefix)."""
    return next(replay_group([case]))[1]


# ---------------------------------------------------------------------- files
def save(golden: dict[str, Any], path: Path) -> None:
    """gzip'd JSON, floats by ``repr`` (exact), the same bytes for the same golden."""
    text = json.dumps(golden, separators=(",", ":"), allow_nan=True) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as gz:
        gz.write(text.encode())


def load(path: Path) -> dict[str, Any]:
    golden: dict[str, Any] = json.loads(gzip.decompress(path.read_bytes()))
    return golden


# ---------------------------------------------------------------------- comparison
#: differences listed per field before the rest are only counted
MAX_LISTED = 5


def _same_float(a: float | None, b: float | None, tol: float) -> bool:
    if a is None or b is None:
        return a is b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b or abs(a - b) <= tol


def _diff_float(a: float | None, b: float | None) -> float:
    """|a - b| (inf when one is missing or NaN and the other is not, 0 when both are)."""
    if a is None or b is None:
        return 0.0 if a is b else math.inf
    if math.isnan(a) or math.isnan(b):
        return 0.0 if math.isnan(a) and math.isnan(b) else math.inf
    return abs(a - b)


#: event fields that are floats other than times (compared within the tolerance given)
_EVENT_FLOATS = {"jump_mps"}
_EVENT_VECTORS = {"bias_body_mps2", "bias_sigma_mps2"}


def _event_diff(
    what: str, i: int, expected: dict[str, Any], actual: dict[str, Any], tol: float
) -> list[str]:
    out = []
    for key in sorted(expected.keys() | actual.keys()):
        e, a = expected.get(key), actual.get(key)
        if key in _EVENT_FLOATS:
            ok = _same_float(e, a, tol)
        elif key in _EVENT_VECTORS and e is not None and a is not None:
            ok = len(e) == len(a) and all(_same_float(x, y, tol) for x, y in zip(e, a, strict=True))
        else:
            ok = e == a  # kinds, axes, configurations, reasons; times exactly
        if not ok and key in _EVENT_FLOATS:
            out.append(f"{key}: golden {e!r}, now {a!r} (|diff| {_diff_float(e, a):.3g} > {tol:g})")
        elif not ok:
            out.append(f"{key}: golden {e!r}, now {a!r}")
    if not out:
        return []
    return [f"{what}[{i}] ({_event_label(expected)}): " + "; ".join(out)]


def _event_label(ev: dict[str, Any]) -> str:
    if "kind" in ev:
        return f"{ev['kind']} on {ev['axis']} at t = {ev['t_detect_s']!r} s"
    return (
        f"{ev.get('from')} -> {ev.get('to')} ({ev.get('reason')}) at t = {ev.get('t_boot_s')!r} s"
    )


def compare_decisions(
    expected: dict[str, Any], actual: dict[str, Any], *, jump_tol_mps: float
) -> list[str]:
    """Differences of the fault and switch events, as readable lines (empty: identical).

    Kinds, axes, configurations, reasons and times must be equal; ``jump_mps`` and an
    accelerometer event's ``bias_body_mps2`` within ``jump_tol_mps``."""
    out: list[str] = []
    for what in ("faults", "switches"):
        e, a = expected[what], actual[what]
        for i, (x, y) in enumerate(zip(e, a, strict=False)):
            out += _event_diff(what, i, x, y, jump_tol_mps)
        if len(e) != len(a):
            out.append(f"{what}: golden has {len(e)} events, now {len(a)}")
            longer, label = (e, "missing now") if len(e) > len(a) else (a, "new")
            out += [
                f"  {what}[{i}] {label}: {longer[i]}"
                for i in range(min(len(e), len(a)), len(longer))
            ]
    return out


_FLOAT_COLUMNS = ("v_ned_mps_n", "v_ned_mps_e", "v_ned_mps_d", "sigma_lost_mps")
_EXACT_COLUMNS = ("t_boot_s", "health", "lost_axis")


def compare_estimates(
    expected: dict[str, Any], actual: dict[str, Any], *, tol_mps: float
) -> list[str]:
    """Differences of the decimated estimates, as readable lines (empty: the same).

    Per stream: the same record times, health and lost-axis strings (exactly), velocity
    and σ of the lost axis within ``tol_mps``. A stream whose times differ is reported
    by its first differing row only (the rows after it are not comparable)."""
    out: list[str] = []
    e_all, a_all = expected["estimates"], actual["estimates"]
    for config in sorted(e_all.keys() | a_all.keys()):
        if config not in e_all or config not in a_all:
            out.append(f"{config}: stream {'missing now' if config in e_all else 'new'}")
            continue
        e, a = e_all[config], a_all[config]
        te, ta = e["t_boot_s"], a["t_boot_s"]
        if te != ta:
            k = next((i for i, (x, y) in enumerate(zip(te, ta, strict=False)) if x != y), None)
            where = (
                f"first at row {k}: golden t = {te[k]!r} s, now {ta[k]!r} s"
                if k is not None
                else f"the shorter ends at row {min(len(te), len(ta))}"
            )
            out.append(
                f"{config}: record times differ ({len(te)} rows golden, {len(ta)} now; {where})"
            )
            continue
        for col in _EXACT_COLUMNS[1:]:
            bad = [i for i, (x, y) in enumerate(zip(e[col], a[col], strict=True)) if x != y]
            out += [
                f"{config}: {col} at t = {te[i]!r} s (row {i}): golden {e[col][i]!r}, now {a[col][i]!r}"
                for i in bad[:MAX_LISTED]
            ]
            if len(bad) > MAX_LISTED:
                out.append(f"{config}: {col}: {len(bad) - MAX_LISTED} more rows differ")
        for col in _FLOAT_COLUMNS:
            diffs = [_diff_float(x, y) for x, y in zip(e[col], a[col], strict=True)]
            bad = [i for i, d in enumerate(diffs) if d > tol_mps]
            out += [
                f"{config}: {col} at t = {te[i]!r} s (row {i}): golden {e[col][i]!r}, "
                f"now {a[col][i]!r} (|diff| {diffs[i]:.3g} > {tol_mps:g})"
                for i in bad[:MAX_LISTED]
            ]
            if len(bad) > MAX_LISTED:
                worst = max(diffs[i] for i in bad)
                out.append(
                    f"{config}: {col}: {len(bad) - MAX_LISTED} more rows differ (largest |diff| {worst:.3g})"
                )
    return out


def compare_settings(expected: dict[str, Any], actual: dict[str, Any]) -> list[str]:
    """Differences of what was replayed: format, case, log, faults injected, vehicle, rate."""
    return [
        f"{k}: golden {expected.get(k)!r}, now {actual.get(k)!r}"
        for k in ("format", "case", "log", "injected", "sysid", "rate_hz")
        if expected.get(k) != actual.get(k)
    ]


def compare(
    expected: dict[str, Any], actual: dict[str, Any], *, tol_mps: float = 1e-9
) -> list[str]:
    """Every difference between two goldens (settings, decisions, estimates), readable."""
    return (
        compare_settings(expected, actual)
        + compare_decisions(expected, actual, jump_tol_mps=tol_mps)
        + compare_estimates(expected, actual, tol_mps=tol_mps)
    )


def max_abs_diff(expected: dict[str, Any], actual: dict[str, Any]) -> float | None:
    """The largest |difference| of velocity or σ over rows at the same times in both
    (None: no stream has the same record times in both)."""
    worst: float | None = None
    for config, e in expected["estimates"].items():
        a = actual["estimates"].get(config)
        if a is None or e["t_boot_s"] != a["t_boot_s"]:
            continue
        worst = 0.0 if worst is None else worst  # a stream at the same times (maybe empty)
        for col in _FLOAT_COLUMNS:
            for x, y in zip(e[col], a[col], strict=True):
                d = _diff_float(x, y)
                worst = d if worst is None or d > worst else worst
    return worst


def decisions(golden: dict[str, Any]) -> int:
    """Fault events plus switch events."""
    return len(golden["faults"]) + len(golden["switches"])


def rows(golden: dict[str, Any]) -> int:
    """Decimated records over the streams kept."""
    return sum(len(s["t_boot_s"]) for s in golden["estimates"].values())


# ---------------------------------------------------------------------- entry point
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m glmav_testkit.golden",
        description="Replay the golden cases; compare with tests/data/golden/ or rewrite it.",
    )
    p.add_argument("--update", action="store_true", help="rewrite the golden files")
    p.add_argument("--only", action="append", metavar="NAME", help="this case only (repeatable)")
    p.add_argument("--list", action="store_true", help="list the cases and exit")
    args = p.parse_args(argv)
    if args.list:
        for c in CASES:
            print(c.name)
        return 0
    unknown = sorted(set(args.only or ()) - CASES_BY_NAME.keys())
    if unknown:
        p.error(f"unknown case(s) {unknown}; --list names them")
    chosen = [c for c in CASES if not args.only or c.name in args.only]
    changed = 0
    print(f"{'case':<42} {'decisions':>9} {'rows':>6} {'max|diff| vs previous':>22}  s")
    for group in groups(chosen).values():
        t0 = time.perf_counter()
        for case, fresh in replay_group(group):
            old = load(case.golden_path) if case.golden_path.exists() else None
            if old is None:
                diff_txt, differences = "(new)", ["new"]
            else:
                differences = compare(old, fresh)
                worst = max_abs_diff(old, fresh)
                diff_txt = "times differ" if worst is None else f"{worst:.3g}"
                if differences and worst == 0.0:
                    diff_txt += " (decisions/times differ)"
            changed += bool(differences)
            dt = time.perf_counter() - t0
            print(
                f"{case.name:<42} {decisions(fresh):>9} {rows(fresh):>6} {diff_txt:>22}  {dt:.1f}"
            )
            t0 = time.perf_counter()
            if args.update:
                save(fresh, case.golden_path)
            elif differences:
                for line in differences[:20]:
                    print(f"    {line}")
    total = sum(c.golden_path.stat().st_size for c in CASES if c.golden_path.exists())
    print(
        f"{changed} of {len(chosen)} cases differ from the previous golden"
        + ("; files rewritten" if args.update else "")
        + f"; golden files {total / 1e6:.2f} MB in {GOLDEN_DIR.relative_to(REPO_ROOT)}"
    )
    return 0 if args.update or not changed else 1


if __name__ == "__main__":
    sys.exit(main())
