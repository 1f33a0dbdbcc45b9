"""The active estimate's lost axis with ``[estimation] aero_active`` (issue 13):
:meth:`LostAxisAiding.active_offset` (the aided offset, and its return to the dead
reckoning when the filter drops it) and :class:`ActiveSelection` carrying the offset
through a switch."""

from __future__ import annotations

import math

import pytest

from glmav_observer.estimation.aero import PseudoMeasurement
from glmav_observer.estimation.aiding import RETURN_TIME_S, LostAxisAiding
from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.fdi import FaultDetector
from glmav_observer.estimation.fdi_types import FdiConfig
from glmav_observer.estimation.selection import ActiveSelection

#: the records' rate: the corpus's IMU (ArduPilot's 50 Hz RAW_IMU)
RATE_HZ = 50.0
#: the hand-over's jump bound (benchmarks/corpus.py's goal, tests/integration's assert)
JUMP_BOUND_MPS = 0.05


def test_the_active_offset_is_the_filters_then_returns_to_dead_reckoning() -> None:
    """North lost at t = 0; the filter pulls its offset towards +0.8 m/s (pseudo-
    measurements 0.8 m/s above a dead reckoning that reads 0), then a rule stops it (the
    model declared broken): its offset drops to 0 at once, the active estimate's does
    not. (The hand-over's σ is 1 m/s, so that rule 2 lets an offset of 0.8 m/s stand.)"""
    aiding = LostAxisAiding(1.0)
    aiding.start(0.0, 0)
    axis = aiding._axis
    assert axis is not None
    dt = 1.0 / RATE_HZ
    published: list[float] = []
    filter_offsets: list[float] = []
    t_stop_s = 10.0
    n = int(20.0 * RATE_HZ)
    for i in range(1, n + 1):
        t = i * dt
        aiding.propagate(dt, [0.0, 0.0, 0.0])
        if i % 10 == 0:  # a 5 Hz velocity sample
            pm = PseudoMeasurement(0.8, 0.1, 0.0)
            axis.update(None if t > t_stop_s else pm, model_broken=t > t_stop_s)
        st = aiding.lost_axis(0.0)  # the dead reckoning reads 0: st.v_mps is the offset
        filter_offsets.append(st.v_mps)
        published.append(aiding.active_offset(t, st.v_mps))
    assert axis.stopped and "two rows disagree" in axis.stop_reason
    # the record at which the filter dropped its offset (the first update after 10 s)
    k_stop = next(k for k in range(int(RATE_HZ), n) if filter_offsets[k] == 0.0)
    assert k_stop == round(10.2 * RATE_HZ) - 1
    # while the aiding runs the active offset *is* the filter's (active = aided)
    assert published[:k_stop] == filter_offsets[:k_stop]
    assert published[k_stop - 1] > 0.7  # pulled most of the way to 0.8 in 10 s
    # after the stop the filter is the dead reckoning (offset 0) ...
    assert filter_offsets[-1] == 0.0
    # ... and the active estimate returns to it exponentially, τ = RETURN_TIME_S: each
    # record moves it by ≤ offset · Δt/τ = 0.8 · 0.02 = 0.016 m/s, inside the hand-over's
    # 0.05 m/s jump bound; 3τ after, 5 % is left; 10 s after, 0.8 · e⁻¹⁰ = 4e-5 m/s
    steps = [abs(b - a) for a, b in zip(published[k_stop - 1 :], published[k_stop:], strict=False)]
    assert max(steps) <= published[k_stop - 1] * dt / RETURN_TIME_S + 1e-12
    assert max(steps) < JUMP_BOUND_MPS
    k3 = k_stop + int(3.0 * RETURN_TIME_S * RATE_HZ)
    assert published[k3] == pytest.approx(published[k_stop - 1] * math.exp(-3.0), rel=0.05)
    assert abs(published[-1]) < 1e-4


def test_the_active_offset_returns_when_the_aiding_stops_running_and_resets_on_a_switch() -> None:
    """A second axis isolated: the filter no longer runs (no offset given), the active
    estimate returns from what it published; a new hand-over (``start``) or the recovery
    (``stop``) starts the next configuration from the published value: nothing returns."""
    aiding = LostAxisAiding(0.1)
    aiding.start(0.0, 1)
    assert aiding.active_offset(0.02, 0.5) == 0.5
    assert aiding.active_offset(0.04, None) == pytest.approx(0.5)  # no jump
    assert aiding.active_offset(0.04 + RETURN_TIME_S, None) == pytest.approx(0.5 / math.e)
    aiding.stop()
    assert aiding.active_offset(10.0, None) == 0.0
    aiding.start(20.0, 0)
    assert aiding.active_offset(20.02, 0.0) == 0.0


def test_a_switch_starts_the_next_configuration_from_the_aided_estimate() -> None:
    """The recovery (c2 → full) while the active north carries an aided offset of 0.4
    m/s: ``full`` starts from the active estimate with it, so the switch's jump is the
    rounding's, not 0.4 m/s."""
    bank = ObserverBank()
    euler = (0.0, 0.0, 0.0)  # E = I: the bank's NED estimates are its states
    for c, v in (("full", (1.0, 2.0, 0.1)), ("c2", (1.3, 2.0, 0.1))):
        bank.set_state_ned(c, v, euler)
    sel = ActiveSelection(compensate_accel_bias=False, handover_contamination_mps=1.0)
    zero = (0.0, 0.0, 0.0)
    ints = ((0.0,) * 6, zero, zero)
    sel.continue_handover("c2", 0, 0.0, ints, None)
    sel.aided_offset_mps = 0.4
    ned_l = bank.x_hat_ned_mps().tolist()
    assert sel.active_ned(ned_l, zero)[0] == pytest.approx(1.3)  # the dead reckoning
    active = sel.active_ned(ned_l, zero, None, sel.aided_offset_mps)
    assert active[0] == pytest.approx(1.7)
    ev, _ = sel.switch(1.0, "full", None, bank, FaultDetector(FdiConfig()), [0.0] * 3, ints, euler)
    assert ev.v_before_ned_mps == pytest.approx(active)
    assert sel.aided_offset_mps == 0.0  # ``full`` has no lost axis
    ned_l = bank.x_hat_ned_mps().tolist()
    assert ned_l[0] == pytest.approx(list(active), abs=1e-12)
    settled = sel.settle_jump(ned_l, zero)
    assert settled is not None and settled.jump_mps is not None
    assert settled.jump_mps < 1e-9
