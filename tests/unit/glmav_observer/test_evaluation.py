"""The one definition of the error against truth: interpolation, batch and online forms."""

from __future__ import annotations

import numpy as np

from glmav_observer.evaluation import (
    TruthScorer,
    errors_against_truth,
    interpolate_truth,
    rmse,
)
from glmav_observer.records import TruthRecord, VelocityRecord


def test_interpolate_truth() -> None:
    t_truth = np.array([0.0, 0.02, 0.04, 0.30, 0.32])  # a 0.26 s dropout after 0.04
    v_truth = np.column_stack([3.0 * t_truth + 1.0, -t_truth])
    t_est = np.array([-0.01, 0.0, 0.005, 0.02, 0.039, 0.1, 0.31, 0.33])
    ok, v = interpolate_truth(t_est, t_truth, v_truth, max_gap_s=0.1)
    # before the first sample, inside the dropout and after the last: no truth
    assert ok.tolist() == [False, True, True, True, True, False, True, False]
    # a linear truth is reproduced exactly (float round-off only)
    np.testing.assert_allclose(v[ok, 0], 3.0 * t_est[ok] + 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(v[ok, 1], -t_est[ok], rtol=0, atol=1e-15)
    assert np.isnan(v[~ok]).all()
    ok, _ = interpolate_truth(t_est, t_truth[:0], v_truth[:0], max_gap_s=0.1)
    assert not ok.any()


def _flight(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Estimates at 250 Hz and truth at 50 Hz with jitter and a 0.3 s truth dropout."""
    rng = np.random.default_rng(seed)
    t_est = np.arange(0.0, 10.0, 0.004)
    v_est = np.column_stack([np.sin(t_est), np.cos(2 * t_est), 0.1 * t_est])
    v_est = v_est + rng.normal(0.0, 0.05, v_est.shape)
    t_truth = np.arange(0.01, 10.0, 0.02) + rng.uniform(-0.003, 0.003, 500)
    t_truth = t_truth[(t_truth < 6.0) | (t_truth > 6.3)]  # the dropout
    v_truth = np.column_stack([np.sin(t_truth), np.cos(2 * t_truth), 0.1 * t_truth])
    return t_est, v_est, t_truth, v_truth


def test_the_online_scorer_is_the_batch_definition() -> None:
    """Fed in publication order (each truth sample after the estimates up to its time),
    the service's online scorer gives the batch RMSE of errors_against_truth exactly (to
    float round-off: the same interpolation, summed in another order)."""
    skip_s = 3.0
    for seed in range(3):
        t_est, v_est, t_truth, v_truth = _flight(seed)
        keep = t_est >= t_est[0] + skip_s
        _, err = errors_against_truth(t_est[keep], v_est[keep], t_truth, v_truth)
        want = rmse(err)
        scorer = TruthScorer(skip_s=skip_s)
        j = 0
        for i, t in enumerate(t_est):
            while j < len(t_truth) and t_truth[j] <= t:
                vt = (float(v_truth[j, 0]), float(v_truth[j, 1]), float(v_truth[j, 2]))
                scorer.add(TruthRecord(1, float(t_truth[j]), vt, vt, vt, None, j))
                j += 1
            v = (float(v_est[i, 0]), float(v_est[i, 1]), float(v_est[i, 2]))
            scorer.add(VelocityRecord(1, "full", float(t), v, v, None, "ok", i))
        got = scorer.rmse()["full"]
        assert want is not None and got is not None
        np.testing.assert_allclose(got, want, rtol=1e-12)
        assert scorer.n("full") == len(err)
        # the dropout (0.3 s > TRUTH_MAX_GAP_S) is not scored: 0.3 s of 250 Hz missing
        assert len(err) < keep.sum() - 0.25 / 0.004


def test_a_late_truth_sample_is_not_compared_with_a_stale_estimate() -> None:
    """The old definition compared each truth sample with the latest estimate: a truth
    sample arriving first after an outage met the estimate from before it (1.6 m/s in
    test_faults' outage). Interpolated at estimate times, no estimate is bracketed by
    truth samples across the outage."""
    s = TruthScorer(skip_s=0.0)
    for k in range(100):  # 2 s steady at 1 m/s, truth at 50 Hz, estimates at 250 Hz
        t = 0.004 * k * 5
        s.add_truth(t, (1.0, 0.0, 0.0))
        for q in range(5):
            s.add_estimate("active", t + 0.004 * q, (1.0, 0.0, 0.0))
    s.add_truth(3.5, (5.0, 0.0, 0.0))  # after a 1.5 s outage, faster
    s.add_estimate("active", 3.5, (5.0, 0.0, 0.0))
    r = s.rmse()["active"]
    assert r is not None and r[0] == 0.0
    # 501 estimates: the four after the last truth before the outage (1.984-1.996 s) are
    # not bracketed by truth less than 0.1 s apart; the one at 3.5 s meets truth exactly
    assert s.n("active") == 497
    # a reboot (time back to 0): a new timeline, the skip applies again
    s2 = TruthScorer(skip_s=1.0)
    for t0 in (0.0, 0.0):
        for k in range(500):
            t = t0 + 0.004 * k
            if k % 5 == 0:
                s2.add_truth(t, (0.0, 0.0, 0.0))
            s2.add_estimate("full", t, (0.1, 0.0, 0.0))
    # per boot: 1 s of 250 Hz after the skip, less the last four (after the last truth)
    assert s2.n("full") == 2 * 246
