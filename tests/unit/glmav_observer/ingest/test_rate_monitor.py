"""The rate requests' schedule (ingest/rates.py): counted when sent, renewed once per
event, the interval before asked once, and what is restored."""

from __future__ import annotations

from glmav_observer.ingest.rates import MESSAGE_IDS, RateMonitor, RateRequest

WANTED = {"ATTITUDE": 100.0, "HIGHRES_IMU": 250.0}
NEED = {"ATTITUDE": 10.0, "HIGHRES_IMU": 50.0}


def _monitor() -> RateMonitor:
    return RateMonitor(
        WANTED, NEED, window_s=2.0, retry_s=5.0, retry_max_s=60.0, t_registered_s=0.0
    )


def _names(reqs: list[RateRequest]) -> list[str]:
    return [r.message for r in reqs]


def test_a_request_not_sent_is_due_again_and_grows_no_backoff() -> None:
    mon = _monitor()
    for t in (2.0, 3.0, 4.0, 5.0):  # a link down: due at every check, nothing counted
        assert _names(mon.due_requests(1, 1, t)) == ["ATTITUDE", "HIGHRES_IMU"]
    assert mon.asked("ATTITUDE") == 0
    for r in mon.due_requests(1, 1, 6.0):
        mon.sent(r, 6.0)
    assert mon.asked("ATTITUDE") == 1
    assert mon.due_requests(1, 1, 10.9) == []  # the first back-off: 5 s
    assert _names(mon.due_requests(1, 1, 11.0)) == ["ATTITUDE", "HIGHRES_IMU"]


def test_renewed_at_once_once_per_window_and_the_silent_stream_restarts_its_backoff() -> None:
    mon = _monitor()
    for t in (2.0, 7.0, 17.0):  # asked three times: the next back-off would be 40 s
        for r in mon.due_requests(1, 1, t):
            mon.sent(r, t)
    assert mon.asked("ATTITUDE") == 3
    assert mon.renew(20.0) and not mon.renew(21.9)  # a reconnect, then the reboot it shows
    reqs = mon.due_requests(1, 1, 20.0)  # at once, before any window
    assert [(r.message, r.rate_hz) for r in reqs] == [("ATTITUDE", 100.0), ("HIGHRES_IMU", 250.0)]
    for r in reqs:
        mon.sent(r, 20.0)
    assert mon.due_requests(1, 1, 24.9) == []  # its back-off from the start: 5 s
    # the streams flow at their rates: nothing due; then ATTITUDE stops altogether
    for k in range(200):
        mon.note("ATTITUDE", 0.01 * k, 25.0 + 0.01 * k)
        mon.note("HIGHRES_IMU", 0.01 * k, 25.0 + 0.01 * k)
    assert mon.due_requests(1, 1, 27.0) == []
    for k in range(200, 921):  # HIGHRES_IMU goes on
        mon.note("HIGHRES_IMU", 0.01 * k, 25.0 + 0.01 * k)
    reqs = mon.due_requests(1, 1, 29.1)  # ATTITUDE silent > 2 s (host): asked at once
    assert _names(reqs) == ["ATTITUDE"]
    mon.sent(reqs[0], 29.1)
    assert mon.due_requests(1, 1, 34.0) == []  # ... with a 5 s back-off, not 10
    assert _names(mon.due_requests(1, 1, 34.1)) == ["ATTITUDE"]


def test_the_interval_before_is_asked_once_and_restored() -> None:
    mon = _monitor()
    assert mon.query_due("ATTITUDE") and not mon.query_due("ATTITUDE")
    mon.note_interval(MESSAGE_IDS["HIGHRES_IMU"], 5000)  # not asked: someone else's answer
    mon.note_interval(MESSAGE_IDS["ATTITUDE"], 250_000)
    mon.note_interval(MESSAGE_IDS["ATTITUDE"], 10_000)  # a later answer: ours in force
    for r in mon.due_requests(1, 1, 2.0):
        mon.sent(r, 2.0)
    assert not mon.query_due("HIGHRES_IMU")  # set already: its before is unknown
    restore = {r.message: r.rate_hz for r in mon.restore_requests(1, 1)}
    assert restore == {"ATTITUDE": 4.0, "HIGHRES_IMU": 0.0}  # 0: the vehicle's default


def test_a_plan_moves_a_stream_the_service_set_but_not_one_set_by_others() -> None:
    mon = _monitor()
    for k in range(2001):  # ATTITUDE at 100 Hz for 20 s, set by someone else; no IMU
        mon.note("ATTITUDE", 0.01 * k, 0.01 * k)
    reqs = mon.due_requests(1, 1, 3.0)
    assert _names(reqs) == ["HIGHRES_IMU"]
    mon.sent(reqs[0], 3.0)
    mon.set_plan({"ATTITUDE": 6.3, "HIGHRES_IMU": 31.6}, NEED)  # a 57,600-baud budget
    assert mon.due_requests(1, 1, 7.9) == []  # at its next check (the 5 s back-off)
    reqs = mon.due_requests(1, 1, 8.0)
    assert [(r.message, r.rate_hz) for r in reqs] == [("HIGHRES_IMU", 31.6)]
    mon.sent(reqs[0], 8.0)
    for k in range(321):  # the vehicle obeys: 32 Hz from 8 s
        mon.note("HIGHRES_IMU", 8.0 + k / 32.0, 8.0 + k / 32.0)
    mon.set_plan({"ATTITUDE": 6.3, "HIGHRES_IMU": 33.0}, NEED)  # 4 %: not worth a request
    assert mon.due_requests(1, 1, 18.0) == [] and mon.asked("ATTITUDE") == 0
