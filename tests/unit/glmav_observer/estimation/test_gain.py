"""The gain policy of ``full`` (estimation/gain.py): the bias its J(γ) assumes, and the
noise estimate it waits for, on a constructed fit and on a glmav-sitl flight."""

from __future__ import annotations

import lzma
import math
from pathlib import Path

import numpy as np
import pytest

from glmav_observer.app import Service
from glmav_observer.config import ServiceConfig
from glmav_observer.estimation.fdi_reference import OBSERVED_SIGMA, Reference
from glmav_observer.estimation.gain import bias_left_mps2
from glmav_observer.ingest.framing import FrameCounters, iter_tlog

DATA = Path(__file__).resolve().parents[3] / "data"


def _reference(bias_mps2: tuple[float, float, float], sigma_mps2: float) -> Reference:
    theta = (0.0, 0.0, 0.0, *bias_mps2, 0.0, 0.0)
    cov = np.diag([1e-4, 1e-4, 1e-4, *[sigma_mps2**2] * 3, 1e-6, 1e-6])
    return Reference(theta, cov, (0.0,) * 9, (0.0, 0.0, 0.0))


def test_the_bias_left_is_what_the_bank_is_not_fed() -> None:
    # x observed (0.6 > 2σ = 0.04): subtracted, only its σ is left; y unobserved (0.01 <
    # 0.04): all of it is left; z exactly 0
    ref = _reference((0.6, 0.01, 0.0), 0.02)
    assert OBSERVED_SIGMA == 2.0  # the classification above assumes it
    want = math.sqrt(0.02**2 + (0.01**2 + 0.02**2) + 0.02**2)
    assert bias_left_mps2(ref, compensated=True) == pytest.approx(want, rel=1e-12)
    # not compensated: the bank integrates the whole fitted bias
    assert bias_left_mps2(ref, compensated=False) == pytest.approx(math.hypot(0.6, 0.01))
    assert bias_left_mps2(None, compensated=True) == 0.0


def test_on_white_noise_the_gain_stays_low_and_waits_for_its_noise_estimate() -> None:
    """glmav-sitl's ideal sensors: LOCAL_POSITION_NED is truth plus white noise (σ 0.05 m/s
    at 30 Hz, docs/model.md), an IMU whose bias the fit observes and the bank is fed."""
    data = lzma.decompress((DATA / "glmav_sitl" / "glmav_sitl_fault_noise.tlog.xz").read_bytes())
    svc = Service(ServiceConfig(request_rates=False), [])
    for r in iter_tlog(data, FrameCounters()):
        svc.feed_message(r.msg, r.t_host_us * 1e-6, "log")
    (est,) = svc.estimators.values()
    scale = est.fdi.axes[0].cfg.scale_samples
    for ax in est.fdi.axes[:2]:  # n, e: healthy all flight (the noise fault is on d)
        assert ax.n_diff >= scale
        # E[Δr²] = 2σ² (+ the IMU's over one interval, ~1e-6 m²/s²: negligible); a mean
        # of 250 squared differences has a relative σ of √(2/250) = 9 %, σ half of it:
        # 0.05 within 15 % (3σ)
        assert math.sqrt(ax.var_diff_mps2 / 2.0) == pytest.approx(0.05, rel=0.15)
    # J(γ)'s optimum for σ_y 0.05 at 30 Hz is 12.4 s⁻¹ at b = 0.2 m/s² and ~5 at the
    # 0.05 floor (observer.gamma_full_optimal); with |b̂| (0.6 m/s² here, compensated in
    # the bank) it was 25 and the gain climbed to the cap
    gamma = float(est.bank.gamma_gain[0])
    assert 4.0 <= gamma <= 14.0
