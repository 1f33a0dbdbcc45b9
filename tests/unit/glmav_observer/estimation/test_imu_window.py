"""The compiled window of one redundant IMU's differences (imu_window.PairWindow) against
numpy over the same samples."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from glmav_observer.estimation.imu_window import PairWindow, deviation_test

WINDOW_S = 0.5
MAX_AGE_S = 0.1
MIN_SAMPLES = 5
MIN_FILL = 0.8


def _stream(rate_hz: float, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    gravity = np.array([0.0, 0.0, -9.81])
    offset = np.array([0.02, -0.01, 0.03])  # a calibration offset between the two
    f1 = rng.normal(0.0, 0.3, (n, 3)) + gravity
    f2 = f1 + offset + rng.normal(0.0, 0.05, (n, 3))
    return t, f1, f2


@pytest.mark.parametrize("rate_hz", [50.0, 1000.0])  # 25 samples; 500 (the ring grows)
def test_step_is_the_windows_mean_less_the_baseline_and_its_sigma(rate_hz: float) -> None:
    t, f1, f2 = _stream(rate_hz, int(3 * rate_hz), seed=int(rate_hz))
    w = PairWindow()
    baseline = None
    for k in range(len(t)):
        w.note(t[k], tuple(f2[k]))
        r = w.step(t[k], tuple(f1[k]), WINDOW_S, MAX_AGE_S, MIN_SAMPLES, MIN_FILL)
        inside = (t > t[k] - WINDOW_S) & (t <= t[k])
        d = f2[inside] - f1[inside]
        ready = len(d) >= MIN_SAMPLES and t[k] - t[inside][0] >= MIN_FILL * WINDOW_S
        assert (r is not None) == ready, k
        if r is None:
            continue
        mean = d.mean(axis=0)
        if baseline is None:
            baseline = mean
        dev, sig = r
        # summed in C doubles in the window's order against numpy's pairwise sums: a few
        # ulp of values ~0.3 (1e-12 is ~1e4 ulp of margin)
        np.testing.assert_allclose(dev, mean - baseline, rtol=0, atol=1e-12)
        np.testing.assert_allclose(sig, d.std(axis=0) / math.sqrt(len(d)), rtol=1e-12)
    assert len(w) == round(WINDOW_S * rate_hz)


def test_a_stale_secondary_empties_the_window() -> None:
    w = PairWindow()
    t, f1, f2 = _stream(50.0, 50, seed=1)
    for k in range(40):
        w.note(t[k], tuple(f2[k]))
        w.step(t[k], tuple(f1[k]), WINDOW_S, MAX_AGE_S, MIN_SAMPLES, MIN_FILL)
    assert len(w) == 25
    # the secondary's last sample is 0.12 s old at IMU 1's next: beyond max_age_s
    assert w.step(t[39] + 0.12, tuple(f1[40]), WINDOW_S, MAX_AGE_S, MIN_SAMPLES, MIN_FILL) is None
    assert len(w) == 0


def test_copy_and_pickle_carry_the_window_and_the_baseline() -> None:
    t, f1, f2 = _stream(250.0, 400, seed=2)  # 125 samples in the window: grown, wrapped
    w = PairWindow()
    for k in range(300):
        w.note(t[k], tuple(f2[k]))
        r = w.step(t[k], tuple(f1[k]), WINDOW_S, MAX_AGE_S, MIN_SAMPLES, MIN_FILL)
        if r is not None:
            w.learn_baseline(r[0], 60.0)
    clones = [copy.deepcopy(w), pickle.loads(pickle.dumps(w))]
    for c in clones:
        assert len(c) == len(w) and c.baseline == w.baseline and c.f_last == w.f_last
    for k in range(300, 400):
        outs = []
        for x in (w, *clones):
            x.note(t[k], tuple(f2[k]))
            outs.append(x.step(t[k], tuple(f1[k]), WINDOW_S, MAX_AGE_S, MIN_SAMPLES, MIN_FILL))
        assert outs[0] == outs[1] == outs[2]  # bit for bit


def test_onset_is_the_first_difference_beyond_the_floor() -> None:
    w = PairWindow()
    assert w.onset(0.15) == math.inf  # no baseline yet
    for k in range(30):
        t = k * 0.02
        w.note(t, (0.0, 0.4 if k >= 27 else 0.0, 0.0))  # a 0.4 m/s² step on y at 0.54 s
        w.step(t, (0.0, 0.0, 0.0), WINDOW_S, MAX_AGE_S, MIN_SAMPLES, MIN_FILL)
    assert w.baseline == [0.0, 0.0, 0.0]
    assert w.onset(0.15) == pytest.approx(0.54)
    assert w.onset(0.5) == math.inf


def test_deviation_test_is_the_threshold_per_axis_of_the_largest_sigma() -> None:
    rng = np.random.default_rng(3)
    floor, k, end = 0.15, 5.0, 0.5
    for _ in range(500):
        n = int(rng.integers(1, 4))
        devs = [
            (list(rng.normal(0.0, 0.2, 3)), list(np.abs(rng.normal(0.0, 0.03, 3))))
            for _ in range(n)
        ]
        thr, exceeds, quiet, sig = deviation_test(devs, floor, k, end)
        want = [max(floor, k * max(s[a] for _, s in devs)) for a in range(3)]
        assert thr == want
        assert exceeds == any(abs(m[a]) > want[a] for m, _ in devs for a in range(3))
        assert quiet == all(abs(m[a]) < end * want[a] for m, _ in devs for a in range(3))
        assert sig is max(devs, key=lambda v: max(v[1]))[1]
