"""A stress-like CPU load: N busy processes, for a while or for as long as a command runs.

    python scripts/cpu_load.py --procs 4 --seconds 60
    python scripts/cpu_load.py --procs 4 -- python -m pytest -q -n0 tests/integration/reliability/test_faults.py

Each worker spins on arithmetic at normal priority (no sleep, no I/O), as ``stress -c N``
does; with N = 2x the cores the tests see a load average of about N plus their own. With
a command, the load starts first, the command runs, the load stops when it exits, and
the command's exit code is returned. The load average before and after is printed on
stderr so a report can quote it. Workers stop with this process (they are its children
and check that their parent is alive).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import subprocess
import sys
import time


def _spin(parent_pid: int, until: float) -> None:
    x = 0
    while time.monotonic() < until:
        for _ in range(200_000):
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF
        if os.getppid() != parent_pid:  # the parent died: stop
            return


def _loadavg() -> str:
    try:
        one, five, fifteen = os.getloadavg()
    except OSError:
        return "unknown"
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="N busy processes (a stress-like CPU load)")
    ap.add_argument(
        "--procs",
        type=int,
        default=2 * (os.cpu_count() or 1),
        help="busy processes (default 2x cores)",
    )
    ap.add_argument(
        "--seconds", type=float, default=3600.0, help="stop after this long (default 1 h)"
    )
    ap.add_argument(
        "command", nargs=argparse.REMAINDER, help="-- COMMAND...: run it under the load"
    )
    args = ap.parse_args(argv)
    if args.procs < 1:
        ap.error("--procs must be >= 1")
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    until = time.monotonic() + args.seconds
    workers = [
        mp.Process(target=_spin, args=(os.getpid(), until), daemon=True) for _ in range(args.procs)
    ]
    for w in workers:
        w.start()
    print(f"cpu_load: {args.procs} busy processes; load average {_loadavg()}", file=sys.stderr)
    code = 0
    try:
        if command:
            time.sleep(5.0)  # let the load average climb a little before the command starts
            print(f"cpu_load: running {' '.join(command)} (load {_loadavg()})", file=sys.stderr)
            code = subprocess.call(command)
        else:
            while any(w.is_alive() for w in workers):
                time.sleep(0.5)
    except KeyboardInterrupt:
        code = 130
    finally:
        for w in workers:
            w.terminate()
        for w in workers:
            w.join(5.0)
        print(f"cpu_load: stopped; load average {_loadavg()}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
