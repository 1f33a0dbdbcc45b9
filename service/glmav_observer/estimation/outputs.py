"""The records one vehicle's estimator publishes, built from its state, and their pacing.

Per IMU-driven step, when due: one :class:`~glmav_observer.records.VelocityRecord` per
configuration (its lost axis dead-reckoned, with σ since that configuration's start) and
one for ``active``; per measurement a ``MeasurementRecord``; per truth sample a
``TruthRecord``; a ``HealthRecord`` every 1/``health_rate_hz`` s of vehicle time. Each
stream has its own sequence number, counted over the records built (consecutive numbers:
nothing was lost).

What is built is what the outputs read (:mod:`glmav_observer.reads`): a stream nobody
reads is not built, and one read at a rate gets a record at the first step at or after
each multiple of its period (:func:`~glmav_observer.reads.next_due_s`). Health is built at
the lower of its read rate and ``health_rate_hz``. A decision (:meth:`RecordBuilder.
decision`) makes ``active``, ``aided`` and ``health`` due at once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from glmav_observer.configurations import AIDED, CONFIGS, LOST_AXIS_OF_CONFIG, AxisName
from glmav_observer.frames import e_flat, rotate_t_flat
from glmav_observer.ingest.samples import TruthSample, VelocitySample
from glmav_observer.reads import READS_ALL, VELOCITY_STREAMS, Reads, next_due_s
from glmav_observer.records import (
    VELOCITY_SCHEMA,
    FaultEvent,
    HealthRecord,
    MeasurementRecord,
    Record,
    ReferenceFitSummary,
    TruthRecord,
    VelocityRecord,
)

Vec3 = tuple[float, float, float]


def merge_counters(*parts: Mapping[str, int]) -> dict[str, int]:
    """Counters of several components, summed by name, sorted by name."""
    out: dict[str, int] = {}
    for part in parts:
        for k, n in part.items():
            out[k] = out.get(k, 0) + n
    return dict(sorted(out.items()))


def _health_faulty(lost: AxisName | None) -> str:
    """A configuration's ``health`` while an axis is isolated."""
    return "degraded" if lost is None else "dead_reckoning"


_AXIS_INDEX: dict[str, int] = {"n": 0, "e": 1, "d": 2}
_AXES: tuple[AxisName, AxisName, AxisName] = ("n", "e", "d")


def dead_reckoned(
    lost: AxisName | None, sigma_lost_mps: float | None, drift: Sequence[float | None] | None
) -> tuple[tuple[AxisName, ...], Vec3 | None]:
    """A record's ``dead_reckoned_axes`` and ``sigma_ned_mps``: its lost axis with σ
    ``sigma_lost_mps``, and every axis with a σ in ``drift`` (per NED axis, None: measured;
    ``drift.drift_sigma_ned_mps`` and the isolated axes)."""
    if drift is None:
        if lost is None:
            return (), None
        sig = [0.0, 0.0, 0.0]
        sig[_AXIS_INDEX[lost]] = sigma_lost_mps or 0.0
        return (lost,), (sig[0], sig[1], sig[2])
    sig = [0.0 if x is None else x for x in drift]
    axes = [x is not None for x in drift]
    if lost is not None:
        j = _AXIS_INDEX[lost]
        sig[j] = sigma_lost_mps or 0.0
        axes[j] = True
    names = tuple(a for a, on in zip(_AXES, axes, strict=True) if on)
    return names, ((sig[0], sig[1], sig[2]) if names else None)


#: Per configuration (CONFIGS order): its name, its lost axis and its ``health`` while no
#: axis is isolated (``ok`` for ``full``; its lost axis dead-reckoned for the others).
_CONFIG_HEALTH: tuple[tuple[str, AxisName | None, str], ...] = tuple(
    (c, LOST_AXIS_OF_CONFIG[c], "ok" if c == "full" else _health_faulty(LOST_AXIS_OF_CONFIG[c]))
    for c in CONFIGS
)


class RecordBuilder:
    """Sequence numbers, record construction and health pacing of one vehicle."""

    def __init__(self, sysid: int, health_rate_hz: float, reads: Reads = READS_ALL) -> None:
        self.sysid = sysid
        self.health_rate_hz = health_rate_hz
        self._seq: dict[str, int] = {}
        #: the configurations' sequence numbers (CONFIGS order), counted apart: every step
        self._seq_config = [0] * len(CONFIGS)
        self.next_health_s: float | None = None
        self.set_reads(reads)

    # -- what is built, and when --------------------------------------------------------
    def set_reads(self, reads: Reads) -> None:
        """Build what ``reads`` says (the union of the outputs' reads) from now on."""
        self.reads = reads
        #: per velocity stream (VELOCITY_STREAMS order: CONFIGS, active, aided): its rate
        self._rate_v = [reads.rate(s) for s in VELOCITY_STREAMS]
        #: ... and the vehicle time from which its next record is due (inf: not read)
        self._next_v = [-math.inf if r > 0.0 else math.inf for r in self._rate_v]
        self._update_next()
        h = min(reads.rate("health"), self.health_rate_hz)
        self.health_on = h > 0.0
        self.health_period_s = 1.0 / h if h > 0.0 else math.inf
        self._health_now = False
        self.measurement_on = reads.rate("measurement") > 0.0
        self.truth_on = reads.rate("truth") > 0.0

    def _update_next(self) -> None:
        nv = self._next_v
        #: the first time a configuration's or active's record is due (aided: apart)
        self._next_min = min(nv[0], nv[1], nv[2], nv[3], nv[4])

    def velocity_due(self, t: float, aided: bool) -> bool:
        """Whether a velocity record is due at ``t`` (``aided``: the aided estimate runs):
        one comparison when none is."""
        return t >= self._next_min or (aided and t >= self._next_v[5])

    def _due(self, i: int, t: float) -> bool:
        """Whether velocity stream ``i``'s record is due at ``t``; if so, the next one's
        time is set (the caller builds it)."""
        if t < self._next_v[i]:
            return False
        self._next_v[i] = next_due_s(t, self._rate_v[i])
        return True

    def decision(self) -> None:
        """A fault isolated or recovered, a switch: ``active``, ``aided`` and ``health``
        are due at the next step, whatever their rates (decisions go out at once)."""
        nv = self._next_v
        for i in (4, 5):
            if self._rate_v[i] > 0.0:
                nv[i] = -math.inf
        self._update_next()
        self._health_now = self.health_on

    def _seqn(self, key: str) -> int:
        n = self._seq.get(key, 0) + 1
        self._seq[key] = n
        return n

    def measurement(self, s: VelocitySample, euler_rad: Vec3 | None, out: list[Record]) -> None:
        if not self.measurement_on:
            return
        out.append(self._measurement(s, euler_rad))

    def _measurement(self, s: VelocitySample, euler_rad: Vec3 | None) -> MeasurementRecord:
        return MeasurementRecord(
            self.sysid, s.t_boot_s, s.v_ned_mps, s.position_ned_m, self._seqn("measurement"),
            euler_rad,
        )  # fmt: skip

    def velocity(  # noqa: PLR0917 -- one record per configuration and active
        self,
        t: float,
        body: Sequence[Sequence[float]],
        ned: Sequence[Vec3],
        n_faulty: int,
        sigma_lost_mps: Sequence[float | None],
        active: str,
        active_ned_mps: Vec3,
        active_sigma_mps: float | None,
        out: list[Record],
        active_body_mps: Vec3 | None = None,
        active_health: str | None = None,
        drift_sigma_ned_mps: Sequence[float | None] | None = None,
    ) -> None:
        """The records due at one step: every configuration (CONFIGS order: ``body``,
        ``ned`` (tuples, put in the records as they are), ``sigma_lost_mps`` per
        configuration), then ``active`` (its body velocity the active configuration's, or
        ``active_body_mps`` when its NED one was moved: the aiding's offset; its health
        ``active_health`` when given: ``aided``). ``drift_sigma_ned_mps``: per NED axis,
        the σ of an axis every configuration dead-reckons (isolated, unaided, a silent
        stream; None: measured), or None when there is none."""
        seq = self._seq_config
        sysid = self.sysid
        due = self._due
        for i, (c, lost, health_ok) in enumerate(_CONFIG_HEALTH):
            if not due(i, t):
                continue
            n = seq[i] + 1
            seq[i] = n
            b, v = body[i], ned[i]
            dr_axes, sig_ned = dead_reckoned(lost, sigma_lost_mps[i], drift_sigma_ned_mps)
            if n_faulty:
                health = _health_faulty(lost)
            elif drift_sigma_ned_mps is not None:
                health = "dead_reckoning"
            else:
                health = health_ok
            out.append(
                VelocityRecord(
                    sysid, c, t, (b[0], b[1], b[2]), v, lost, health, n, None,
                    sigma_lost_mps[i], VELOCITY_SCHEMA, dr_axes, sig_ned,
                )
            )  # fmt: skip
        if not due(4, t):
            self._update_next()
            return
        self._update_next()
        a = CONFIGS.index(active)
        if active_health is not None:
            health_a = active_health
        elif n_faulty == 0:
            health_a = "ok" if drift_sigma_ned_mps is None else "dead_reckoning"
        elif n_faulty == 1:
            health_a = "dead_reckoning"
        else:
            health_a = "degraded"
        b_a = (body[a][0], body[a][1], body[a][2]) if active_body_mps is None else active_body_mps
        lost_a = LOST_AXIS_OF_CONFIG[active]
        dr_axes, sig_ned = dead_reckoned(lost_a, active_sigma_mps, drift_sigma_ned_mps)
        out.append(
            VelocityRecord(
                self.sysid, "active", t, b_a, active_ned_mps, lost_a, health_a,
                self._seqn("active"), active, active_sigma_mps, VELOCITY_SCHEMA, dr_axes,
                sig_ned,
            )
        )  # fmt: skip

    def aided(  # noqa: PLR0917 -- the fields of the aided record
        self,
        t: float,
        e_flat: list[float],
        v_ned_mps: list[float],
        source_config: str,
        sigma_lost_mps: float,
        aided: bool,
        out: list[Record],
    ) -> None:
        """The ``aided`` estimate while an axis is lost (:mod:`~glmav_observer.estimation.
        aiding`), when due: ``health`` says whether its lost axis is ``aided`` now or
        dead-reckoned."""
        if not self._due(5, t):
            return
        v_body = rotate_t_flat(e_flat, v_ned_mps)
        lost = LOST_AXIS_OF_CONFIG[source_config]
        dr_axes, sig_ned = dead_reckoned(lost, sigma_lost_mps, None)
        out.append(
            VelocityRecord(
                self.sysid, AIDED, t, (v_body[0], v_body[1], v_body[2]),
                (v_ned_mps[0], v_ned_mps[1], v_ned_mps[2]), lost,
                "aided" if aided else "dead_reckoning", self._seqn(AIDED), source_config,
                sigma_lost_mps, VELOCITY_SCHEMA, dr_axes, sig_ned,
            )
        )  # fmt: skip

    def health_due(self, t: float) -> bool:
        """True (once per period, and at the step after a decision) when a health record
        is due at ``t``."""
        if self.next_health_s is None or not self.health_on:
            return False
        if self._health_now:
            self._health_now = False
            if t < self.next_health_s:
                return True
        if t < self.next_health_s:
            return False
        while self.next_health_s <= t:
            self.next_health_s += self.health_period_s
        return True

    def health(  # noqa: PLR0917 -- the fields of a health record
        self,
        t: float,
        active: str,
        residual_ned_mps: Sequence[float],
        test_ratio: Sequence[float],
        axis_states: dict[str, str],
        faults: tuple[FaultEvent, ...],
        rates_hz: dict[str, float],
        counters: dict[str, int],
        reference_fit: ReferenceFitSummary | None,
    ) -> HealthRecord:
        res, rat = residual_ned_mps, test_ratio
        return HealthRecord(
            self.sysid, t, self._seqn("health"), active, (res[0], res[1], res[2]),
            (rat[0], rat[1], rat[2]), axis_states, faults, rates_hz, counters, reference_fit,
        )  # fmt: skip

    def truth(self, s: TruthSample, out: list[Record]) -> None:
        if self.truth_on:
            out.append(self._truth(s))

    def _truth(self, s: TruthSample) -> TruthRecord:
        # the compiled E (frames.e_flat): the numpy one cost 30 µs of a truth sample's
        # 35; they differ by an ulp in 7 % of entries (a truth record's last digit)
        phi, theta, psi = s.euler_rad
        v_body = rotate_t_flat(e_flat(phi, theta, psi), s.v_ned_mps)
        return TruthRecord(
            self.sysid, s.t_boot_s, (v_body[0], v_body[1], v_body[2]), s.v_ned_mps,
            s.euler_rad, None, self._seqn("truth"),
        )  # fmt: skip
