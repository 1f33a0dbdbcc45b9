"""``[ingest] max_vehicles`` holds for the service, whatever its number of workers (issue
31 D12): 255 system ids churning on one UDP port, against ``serve`` with 2 workers (the
default on this project's 2-core machines) and with 1."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import time
from collections import Counter
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from glmav_testkit.fleet_helpers import OBS, wait_bound_udp

#: the default ``[ingest] max_vehicles`` (configs/service.toml)
MAX_VEHICLES = 8
CMD_SET_MESSAGE_INTERVAL = 511


@pytest.mark.timeout(120)
@pytest.mark.parametrize("workers", [2, 1])
def test_255_churning_sysids_admit_max_vehicles_in_total(
    workers: int, free_udp_port: Callable[[], int]
) -> None:
    port = free_udp_port()
    serve = subprocess.Popen(
        [OBS, "serve", "--workers", str(workers), "--link", f"udpin:127.0.0.1:{port}",
         "--no-zenoh"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.0)
    mavs = {s: mavlink2.MAVLink(None, srcSystem=s, srcComponent=1) for s in range(1, 256)}
    parser = mavlink2.MAVLink(None)
    requested: Counter[int] = Counter()
    try:
        wait_bound_udp(port, serve)
        # every id sends ATTITUDE at 10 Hz (2550 datagrams/s in rounds) until 2 s after the
        # first rate request (an admitted vehicle without its IMU streams is asked for
        # them past the rate monitor's 2 s window: the evidence of admission seen from
        # outside; the workers may start seconds after the port is bound on a loaded
        # machine, hence an event, with a 40 s deadline)
        t0 = time.monotonic()
        t_end = t0 + 40.0
        k = 0
        while (now := time.monotonic()) < t_end:
            if requested:
                t_end = min(t_end, now + 2.0)
            for mav in mavs.values():
                msg = mavlink2.MAVLink_attitude_message(100 * k, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                sock.sendto(bytes(msg.pack(mav)), ("127.0.0.1", port))
            k += 1
            while True:
                try:
                    data = sock.recv(65535)
                except BlockingIOError:
                    break
                for m in parser.parse_buffer(data) or []:
                    if m.get_type() == "COMMAND_LONG" and m.command == CMD_SET_MESSAGE_INTERVAL:
                        requested[m.target_system] += 1
            time.sleep(max(0.0, t0 + 0.1 * k - now))
    finally:
        serve.send_signal(signal.SIGINT)
        stdout, stderr = serve.communicate(timeout=60)
        sock.close()
    assert serve.returncode == 0, stderr[-2000:]
    vehicles = [int(v) for v in re.findall(r"(?m)^vehicle (\d+)\b", stdout)]
    assert 0 < len(vehicles) <= MAX_VEHICLES, stdout[-3000:]
    # rate requests only to admitted vehicles (before: 16 admitted with 2 workers, and
    # requests to all of them)
    assert requested, stdout[-2000:]
    assert set(requested) <= set(vehicles), (sorted(requested), vehicles)
    dropped = re.search(r"vehicle_cap_dropped[=: ]+(\d+)", stdout)
    assert dropped is not None and int(dropped.group(1)) > 0, stdout[-3000:]
