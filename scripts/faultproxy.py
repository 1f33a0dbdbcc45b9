#!/usr/bin/env python3
"""Put a lossy radio between a MAVLink vehicle and a ground station (UDP, for testing).

    # the service listens on 14550; point the vehicle (or glmav-sitl) at 14560
    glmav-observer serve --link udpin:127.0.0.1:14550 &
    python scripts/faultproxy.py --listen 14560 --target 127.0.0.1:14550 \\
        --drop 0.2 --reorder 0.05 --duplicate 0.05 --delay-ms 20 --jitter-ms 10
    glmav-sitl run --scenario cruise --link udpout:127.0.0.1:14560

Datagrams from the vehicle are dropped, held back (reordered), duplicated and delayed
at random (seeded); replies pass unharmed. Counters are printed every few seconds and
at exit (Ctrl-C). The proxy binds to 127.0.0.1 unless --bind says otherwise.
Implementation: glmav_testkit.faultproxy (tests/support/glmav_testkit/faultproxy.py, standard
library only; importable after ``pip install -e '.[test]'``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from glmav_testkit.faultproxy import FaultSpec, UdpFaultProxy


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--listen", type=int, required=True, help="UDP port the vehicle sends to")
    ap.add_argument("--bind", default="127.0.0.1", help="address to listen on (default loopback)")
    ap.add_argument("--target", required=True, help="HOST:PORT of the ground station")
    ap.add_argument("--drop", type=float, default=0.0, help="loss probability (0-1)")
    ap.add_argument("--reorder", type=float, default=0.0, help="probability of holding back")
    ap.add_argument("--reorder-ms", type=float, default=20.0, help="how long held back")
    ap.add_argument("--duplicate", type=float, default=0.0, help="duplication probability")
    ap.add_argument("--delay-ms", type=float, default=0.0, help="latency added to all")
    ap.add_argument("--jitter-ms", type=float, default=0.0, help="uniform extra latency")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--report-s", type=float, default=5.0, help="print counters this often")
    args = ap.parse_args(argv)
    host, _, port = args.target.rpartition(":")
    try:
        spec = FaultSpec(
            drop=args.drop,
            duplicate=args.duplicate,
            reorder=args.reorder,
            delay_s=args.delay_ms / 1e3,
            jitter_s=args.jitter_ms / 1e3,
            reorder_delay_s=args.reorder_ms / 1e3,
            seed=args.seed,
        )
        proxy = UdpFaultProxy((host or "127.0.0.1", int(port)), spec, (args.bind, args.listen))
    except (ValueError, OSError) as err:
        print(f"faultproxy: {err}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print(f"faultproxy: {args.bind}:{proxy.port} -> {args.target} ({spec.label()})", flush=True)
    with proxy:
        while not stop.wait(args.report_s):
            print(f"faultproxy: {proxy.stats()}", flush=True)
    print(f"faultproxy: final {proxy.stats()}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
