"""The GPS's own velocity bridges the autopilot's re-convergence after a GPS loss (issue 29).

When the GPS comes back after a loss, the autopilot's velocity (``LOCAL_POSITION_NED``)
still carries part of the error it dead-reckoned during the loss. ArduPilot resets its
velocity to the GPS's at the first fix (b_quad_gps_off: north from 0.38 to 0.01 m/s off
in one sample) but not all of it: east stays 0.06-0.09 m/s off and decays over ~2 s.
``GPS_RAW_INT``'s ground velocity is back at once and no IMU of the vehicle touched it.
While the autopilot disagrees with it, the horizontal measurement the bank is corrected
with is that velocity, carried to the present with the IMU:

    y(t) = v_gps(t_g) + A(t) − A(t_g − L)                                   (B1)

with A = ∫ E Γ dt the earth-frame acceleration's integral (the bank's, ``HeldInputs``),
t_g the GPS sample's arrival (the vehicle time of the bank) and L the GPS velocity's lag
behind it (the receiver's filter, the autopilot's GPS delay, the link's order).

**L is learnt online** while the autopilot is aided and nothing is isolated: a GPS
sample per ``learn_interval_s`` is compared with ``full``'s estimate taken back by L, v_full(t_g) − (A(t_g) −
A(t_g − L)), for every L of a grid over [0, ``lag_max_s``]; the squared differences are
summed with exponential forgetting, and L is the grid point of the smallest sum (before
``lag_min_samples`` samples: ``lag_prior_s``). A hover teaches nothing about L (A does not
move) and needs none (B1 does not depend on L then).

**The GPS's velocity is trusted only once it has been seen to follow the vehicle**, over the
same forgotten window: the vehicle's velocity varied (its spread, per axis, at least
``excite_sigma`` ``sigma_v_mps``: else agreement proves nothing) and the residual at the
best L is at most ``trust_sigma`` ``sigma_v_mps`` RMS per axis. A GPS that reports a fix
and a velocity of 0 while the vehicle moves (a real ArduSub vehicle's surface GPS,
``ardusub_small``) is never trusted, and no bridge starts.

**σ_gps**, the GPS velocity's 1σ per axis, is the receiver's own (``vel_acc``) when it
reports one, else that residual's RMS (at least ``sigma_floor_mps``): what the GPS has
shown against the autopilot's aided velocity, not a datasheet's figure. ArduPilot's SITL
GPS shows 0.016-0.018 m/s; a real receiver's 0.05-0.1 m/s would show as that.

**Start**: at the first GPS sample with a 3D fix after the GPS had lost it (``DriftAxes``),
if B1 lies within ``gate_sigma`` of the bank's estimate (σ: its dead reckoning's and the
GPS's together) *and* the autopilot still disagrees with B1 by more than ``start_sigma``
σ_gps on n or e: an autopilot that reset to its GPS is left alone (the bridge would only
trade its error for the GPS's noise). While it runs, the FDI does not test n and e (the
autopilot's velocity has not re-converged: a late reset would look like a bias to a
reference that warmed up before it). **End**: at the first measurement with the
autopilot aided and within ``start_sigma`` σ_gps of B1 on n and e (a GPS sample's noise
alone is outside that once in 8000), after ``max_s``, when the GPS stops (no sample for
``gps_timeout_s``, or no fix), or after ``max_rejects`` GPS samples in a row fail the
gate against the bank. The hand back: the offset B1 − the autopilot's velocity at the
end decays linearly to 0 over ``blend_s``; no step, and no GPS noise after the end.

What it cannot poison: it runs only after a GPS loss and only while the autopilot's
velocity is off by more than the GPS's shown accuracy; every GPS sample is gated against
the bank's IMU-propagated estimate. Measured: docs/field-failures.md ("After the GPS
returns: the GPS's own velocity").
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from glmav_observer.estimation.reasons import const

#: horizontal (north, east) pair, m/s or m/s·s
Ne = tuple[float, float]
#: the integrals at one time: A n, A e (m/s), B's n row, B's e row (s)
Row = tuple[float, ...]


@dataclass(frozen=True, slots=True)
class GpsBridgeConfig:
    """Settings of :class:`GpsBridge` (``[estimation.gps_bridge]``; module docstring)."""

    enabled: bool = const(
        True, unit="", source="requirement",
        reason="after a GPS loss, bridge the autopilot's re-convergence with the GPS's own "
        "velocity (issue 29: never worse than the autopilot's own)",
    )  # fmt: skip
    sigma_v_mps: float = const(
        0.1, unit="m/s", source="physics",
        reason="the scale of the trust test (excite_sigma, trust_sigma): a u-blox M8's "
        "datasheet speed accuracy is 0.05 m/s (50 %), ≈ 0.07 1σ; 0.1 with margin for "
        "multipath on a small airframe",
    )  # fmt: skip
    sigma_floor_mps: float = const(
        0.02, unit="m/s", source="physics",
        reason="σ_gps is never taken below this: GPS_RAW_INT's speed has 1 cm/s steps, and "
        "a near-noise-free stream (ArduPilot's SITL: 0.016 m/s) would make the agreement "
        "test stricter than any autopilot's velocity can meet",
    )  # fmt: skip
    lag_prior_s: float = const(
        0.2, unit="s", source="physics",
        reason="the GPS velocity's lag before one is learnt: between ArduPilot's u-blox "
        "driver defaults (0.12 s for M7-M10, 0.22 s for older or unknown receivers), "
        "plus the stream's arrival after the autopilot's sample",
    )  # fmt: skip
    lag_max_s: float = const(
        0.5, unit="s", source="physics",
        reason="the top of the lag's grid: ArduPilot's GPS_DELAY_MS range (0-250 ms) plus "
        "a 5 Hz period and the link's order",
    )  # fmt: skip
    lag_step_s: float = const(
        0.01, unit="s", source="requirement",
        reason="the lag's resolution: at 1 m/s² of acceleration a 5 ms error moves B1 by "
        "5 mm/s, a twentieth of σ_gps",
    )  # fmt: skip
    learn_interval_s: float = const(
        1.0, unit="s", source="requirement",
        reason="one GPS sample per this long is learnt from (5 Hz GPS: every fifth): the "
        "learning costs ~40 µs a sample, 7 % of a replay at 5 Hz; 60 samples still fill "
        "the 60 s window",
    )  # fmt: skip
    lag_memory_s: float = const(
        60.0, unit="s", source="physics",
        reason="time constant of the learning window: ~300 samples at 5 Hz, over which "
        "a link's lag does not change (a new link restarts nothing: the sums forget)",
    )  # fmt: skip
    lag_min_samples: int = const(
        10, unit="", source="statistic",
        reason="GPS samples learnt from (10 s at learn_interval_s) before the learnt lag "
        "and the trust test replace the prior: 20 residuals on two axes",
    )  # fmt: skip
    excite_sigma: float = const(
        3.0, unit="", source="statistic",
        reason="trusted only if the vehicle's velocity spread (RMS about its mean, per axis) "
        "over the window is at least this many σ_gps: a test with power (a GPS stuck at a "
        "constant then fails the residual test by 1.5×)",
    )  # fmt: skip
    trust_sigma: float = const(
        2.0, unit="", source="statistic",
        reason="... and the residual at the best lag at most this many σ_gps RMS per axis "
        "(the GPS's noise and `full`'s error together: √(0.1² + 0.05²) ≈ 1.1 σ_gps)",
    )  # fmt: skip
    gate_sigma: float = const(
        5.0, unit="", source="statistic",
        reason="a GPS sample whose B1 is further than this many σ from the bank's estimate "
        "is not used (a Gaussian fails 5σ in 6e-7 of the samples)",
    )  # fmt: skip
    max_rejects: int = const(
        3, unit="", source="statistic",
        reason="this many gated-out GPS samples in a row end the bridge (three 5σ events in "
        "a row do not happen by chance)",
    )  # fmt: skip
    start_sigma: float = const(
        4.0, unit="", source="statistic",
        reason="the bridge runs only while the autopilot is further than this many σ_gps "
        "from B1 on n or e: a GPS sample's noise alone does it once in 8000 (2 axes at "
        "6e-5), and the GPS's noise is then a quarter or less of the autopilot's error; "
        "the first measurement within it (the autopilot aided) ends the bridge",
    )  # fmt: skip
    blend_s: float = const(
        1.0, unit="s", source="requirement",
        reason="the hand back: the offset B1 − the autopilot's velocity at the end (≤ "
        "start_sigma σ_gps) decays linearly to 0 over this long, no step (0.08-0.4 m/s: "
        "≤ 0.4 m/s²), and no GPS noise enters after the end",
    )  # fmt: skip
    max_s: float = const(
        30.0, unit="s", source="requirement",
        reason="the bridge ends after this long whatever the autopilot says: its estimator "
        "has long re-converged (ArduPilot's within 1 s); a disagreement that lasts is the "
        "FDI's business",
    )  # fmt: skip
    gps_timeout_s: float = const(
        1.0, unit="s", source="physics",
        reason="no GPS sample for this long ends the bridge: 5 periods at 5 Hz",
    )  # fmt: skip


class GpsBridge:
    """B1's state: the acceleration integral's recent history, the learnt lag, and the
    bridge while it runs (module docstring). Kept across the estimator's restarts (the
    lag is the link's: :meth:`restart`); :meth:`stop` ends a bridge."""

    def __init__(self, cfg: GpsBridgeConfig, counters: Counter[str] | None = None) -> None:
        """``counters``: where its events are counted (``gps_bridge_starts``,
        ``_rejected``, ``_not_needed``, ``_measurements``; the estimator's, which health
        records publish); its own when None."""
        self.cfg = cfg
        self.counters: Counter[str] = Counter() if counters is None else counters
        n = round(cfg.lag_max_s / cfg.lag_step_s) + 1
        self._lags_np = np.arange(n) * cfg.lag_step_s
        #: per L of the grid, the forgotten sum of squared residuals (n and e)
        self._sse = np.zeros(n)
        self._n_learnt = 0
        self._t_learnt_s = -math.inf
        #: the forgotten sums of the learning window: weight, Σv and Σv² of ``full`` (n, e)
        self._w = 0.0
        self._sv = [0.0, 0.0]
        self._svv = [0.0, 0.0]
        #: (vehicle s, A n, A e, B's n row, B's e row) at the bank's times, oldest first
        self._hist: deque[tuple[float, ...]] = deque(maxlen=128)
        self._bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.active = False
        self._t_start_s = 0.0
        self._t_gps_s = 0.0
        self._v_gps: Ne = (0.0, 0.0)
        #: the integrals at t_g − L of the GPS sample in use (B1's anchor)
        self._anchor: Row = (0.0,) * 8
        self._sigma_gps_mps = cfg.sigma_floor_mps
        #: B1 − the autopilot's velocity when the hand back began, decaying over blend_s
        self._offset: Ne = (0.0, 0.0)
        #: the GPS stopped or failed its gate: the hand back begins at the next measurement
        self._end_due = False
        self._t_blend_s: float | None = None
        self._rejects = 0

    @property
    def starts(self) -> int:
        """Bridges started."""
        return self.counters["gps_bridge_starts"]

    @property
    def rejected(self) -> int:
        """GPS samples out of the gate against the bank's estimate."""
        return self.counters["gps_bridge_rejected"]

    @property
    def not_needed(self) -> int:
        """Fixes back after a loss with the autopilot already agreeing with the GPS."""
        return self.counters["gps_bridge_not_needed"]

    # ------------------------------------------------------------ A's history
    def note(
        self, t_s: float, a_int: Sequence[float], b_int_flat: Sequence[float],
        bias_body_mps2: Sequence[float],
    ) -> None:  # fmt: skip
        """The bank's integrals at its time ``t_s``: A = ∫EΓ dt (n, e) and B = ∫E dt (its
        n and e rows, row-major ``b_int_flat``), and the accelerometer bias in force (the
        one the held measurement is propagated with): B1 uses A − B b̂ over the interval,
        as the bank does (ΔB b̂ with the bias now, so a refit does not move old entries)."""
        self._bias = (bias_body_mps2[0], bias_body_mps2[1], bias_body_mps2[2])
        row = (t_s, a_int[0], a_int[1], *b_int_flat[0:6])
        hist = self._hist
        if hist and t_s <= hist[-1][0]:
            if t_s == hist[-1][0]:
                hist[-1] = row
            return
        hist.append(row)
        # only what the grid reaches: one entry at or before t − lag_max_s, and the rest
        t_keep = t_s - self.cfg.lag_max_s
        while len(hist) > 2 and hist[1][0] <= t_keep:
            hist.popleft()

    def _raw_at(self, t_s: float) -> Row | None:
        """(A n, A e, B's n row, B's e row) at ``t_s``, linear between the noted times
        (the last one after them); None before the first."""
        hist = self._hist
        if not hist or t_s < hist[0][0]:
            return None
        for i in range(len(hist) - 1, -1, -1):
            r0 = hist[i]
            if r0[0] <= t_s:
                if i == len(hist) - 1:
                    return r0[1:]
                r1 = hist[i + 1]
                w = (t_s - r0[0]) / (r1[0] - r0[0])
                return tuple(x0 + w * (x1 - x0) for x0, x1 in zip(r0[1:], r1[1:], strict=True))
        return None  # pragma: no cover - t_s ≥ hist[0][0] ends the loop above

    def _compensated(self, r: Row) -> Ne:
        b = self._bias
        return (
            r[0] - (r[2] * b[0] + r[3] * b[1] + r[4] * b[2]),
            r[1] - (r[5] * b[0] + r[6] * b[1] + r[7] * b[2]),
        )

    # ------------------------------------------------------------ the lag
    @property
    def lag_s(self) -> float:
        """L: the learnt one, or the prior until ``lag_min_samples`` were learnt from."""
        if self._n_learnt < self.cfg.lag_min_samples:
            return self.cfg.lag_prior_s
        return float(self._lags_np[int(np.argmin(self._sse))])

    def learn_due(self, t_s: float) -> bool:
        """A GPS sample at ``t_s`` is to be learnt from (``learn_interval_s``)."""
        return t_s - self._t_learnt_s >= self.cfg.learn_interval_s

    def learn(self, t_s: float, v_gps: Ne, v_full: Ne) -> None:
        """One GPS sample at the bank's time ``t_s`` against ``full``'s estimate then
        (the autopilot aided, nothing isolated: the caller's test)."""
        hist = self._hist
        if not hist or hist[0][0] > t_s - self.cfg.lag_max_s or hist[-1][0] < t_s:
            return  # (A not known over the whole grid yet)
        h = np.array(hist)
        b = np.array(self._bias)
        a_n = h[:, 1] - h[:, 3:6] @ b  # A − B b̂ at the noted times (n, e)
        a_e = h[:, 2] - h[:, 6:9] @ b
        t_back = t_s - self._lags_np
        # the residual at every L of the grid: v_gps − (v_full − (A(t) − A(t − L)))
        rn = v_gps[0] - v_full[0] + a_n[-1] - np.interp(t_back, h[:, 0], a_n)
        re = v_gps[1] - v_full[1] + a_e[-1] - np.interp(t_back, h[:, 0], a_e)
        decay = math.exp(-max(t_s - self._t_learnt_s, 0.0) / self.cfg.lag_memory_s)
        self._t_learnt_s = t_s
        self._sse = self._sse * decay + rn * rn + re * re
        self._w = self._w * decay + 1.0
        for j in range(2):
            self._sv[j] = self._sv[j] * decay + v_full[j]
            self._svv[j] = self._svv[j] * decay + v_full[j] * v_full[j]
        self._n_learnt += 1

    @property
    def trusted(self) -> bool:
        """The GPS's velocity has followed the vehicle's (module docstring)."""
        cfg = self.cfg
        w = self._w
        if self._n_learnt < cfg.lag_min_samples or w <= 0.0:
            return False
        s2 = cfg.sigma_v_mps**2
        spread_sq = min(self._svv[j] / w - (self._sv[j] / w) ** 2 for j in range(2))
        residual_sq = float(self._sse.min()) / (2.0 * w)
        return spread_sq >= cfg.excite_sigma**2 * s2 and residual_sq <= cfg.trust_sigma**2 * s2

    @property
    def sigma_shown_mps(self) -> float:
        """The GPS velocity's residual against ``full`` at the best L, RMS per axis, at
        least ``sigma_floor_mps`` (``sigma_v_mps`` before anything is learnt)."""
        if self._w <= 0.0:
            return self.cfg.sigma_v_mps
        shown = math.sqrt(float(self._sse.min()) / (2.0 * self._w))
        return max(shown, self.cfg.sigma_floor_mps)

    # ------------------------------------------------------------ the bridge
    def on_gps(
        self,
        t_s: float,
        v_gps: Ne,
        *,
        sigma_gps_mps: float | None,
        start: bool,
        v_est: Ne,
        sigma_est_mps: float,
    ) -> None:
        """A GPS sample with a 3D fix at the bank's time ``t_s``; ``start``: the GPS had
        lost its fix until now; ``v_est`` / ``sigma_est_mps``: the bank's estimate (n, e)
        and its σ, which B1 is gated against."""
        cfg = self.cfg
        if not cfg.enabled or not (self.active or (start and self.trusted)):
            return
        anchor = self._raw_at(t_s - self.lag_s)
        now = self._raw_at(t_s)
        if anchor is None or now is None:
            return
        a_back, a_now = self._compensated(anchor), self._compensated(now)
        # the receiver's own σ when it reports one (vel_acc), else what the GPS has shown
        shown = self.sigma_shown_mps
        sigma_g = max(sigma_gps_mps, cfg.sigma_floor_mps) if sigma_gps_mps else shown
        y = (v_gps[0] + a_now[0] - a_back[0], v_gps[1] + a_now[1] - a_back[1])
        gate = cfg.gate_sigma * math.sqrt(sigma_est_mps**2 + sigma_g**2)
        off = max(abs(y[0] - v_est[0]), abs(y[1] - v_est[1]))
        if off > gate:
            self.counters["gps_bridge_rejected"] += 1
            self._rejects += 1
            if self.active and self._rejects >= cfg.max_rejects:
                self._end_due = True
            return
        self._rejects = 0
        if not self.active and off <= cfg.start_sigma * sigma_g:
            self.counters["gps_bridge_not_needed"] += 1  # the autopilot already agrees
            return
        if not self.active:
            self.active = True
            self.counters["gps_bridge_starts"] += 1
            self._t_start_s = t_s
            self._t_blend_s = None
            self._end_due = False
        self._t_gps_s = t_s
        self._v_gps = v_gps
        self._anchor = anchor
        self._sigma_gps_mps = sigma_g

    @property
    def bridging(self) -> bool:
        """B1 replaces the autopilot's horizontal velocity now (not yet handing back)."""
        return self.active and self._t_blend_s is None

    def gps_lost(self, t_s: float) -> None:
        """A GPS sample without a 3D fix: the bridge hands back (blended)."""
        if self.active:
            self._end_due = True

    def restart(self) -> None:
        """The estimator restarts (a gap, a reboot, a clock reset): the bridge ends, and
        the integrals' history goes with the bank they came from; what was learnt of the
        lag and of the GPS stays (the link's), learnt on from the next sample on."""
        self.stop()
        self._hist.clear()
        self._t_learnt_s = -math.inf

    def stop(self) -> None:
        """The bridge ends at once."""
        self.active = False
        self._t_blend_s = None
        self._end_due = False
        self._rejects = 0

    def measurement(self, t_s: float, y_ap: Ne, aided: bool) -> Ne | None:
        """The horizontal measurement the bank is corrected with at ``t_s`` (a
        measurement's time, the bank there, its integrals noted) instead of the
        autopilot's ``y_ap`` (lag-compensated), or None: the autopilot's as it is."""
        if not self.active:
            return None
        cfg = self.cfg
        now = self._raw_at(t_s)
        assert now is not None  # (noted at the bank's time, after the anchor's)
        a_now, a0 = self._compensated(now), self._compensated(self._anchor)
        y_b = (self._v_gps[0] + a_now[0] - a0[0], self._v_gps[1] + a_now[1] - a0[1])
        if self._t_blend_s is None:
            tol = cfg.start_sigma * self._sigma_gps_mps
            agrees = aided and abs(y_ap[0] - y_b[0]) <= tol and abs(y_ap[1] - y_b[1]) <= tol
            late = t_s - self._t_gps_s > cfg.gps_timeout_s or t_s - self._t_start_s > cfg.max_s
            if not (agrees or late or self._end_due):
                self.counters["gps_bridge_measurements"] += 1
                return y_b
            # the hand back: B1 − the autopilot's velocity now decays over blend_s
            self._t_blend_s = t_s
            self._offset = (y_b[0] - y_ap[0], y_b[1] - y_ap[1])
        w = 1.0 - (t_s - self._t_blend_s) / cfg.blend_s
        if w <= 0.0:
            self.stop()
            return None
        self.counters["gps_bridge_measurements"] += 1
        return (y_ap[0] + w * self._offset[0], y_ap[1] + w * self._offset[1])
