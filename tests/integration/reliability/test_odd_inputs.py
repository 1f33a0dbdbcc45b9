"""Issue 31, D6, D8 and D10: odd files given to the commands, run as processes.

- D10: ``--config /dev/zero`` read until the kernel killed the process (23.5 GB); a FIFO
  blocked for ever; a UTF-8 BOM said "Invalid statement"; 100,000 nested arrays gave a
  RecursionError traceback. The processes run here under a 4 GB address-space limit
  and a timeout, so that the code before the fix fails the test instead of the machine.
- D8: a ``.ulg`` with 200 flipped bits gave a ``ValueError`` traceback, exit 1 and a
  0-byte ``--out``; a damaged ``.bin`` left a 0-byte ``--out``.
- D6: ``replay --out`` through a symbolic link overwrote the link's target.
"""

from __future__ import annotations

import gzip
import os
import random
import resource
import subprocess
from pathlib import Path

import pytest

from glmav_testkit.fleet_helpers import OBS, SITL

PUBLIC_LOGS = Path(__file__).parents[2] / "data" / "public-logs"
#: the address space a command may take (it needs ~1.5 GB of mappings to start)
MAX_ADDRESS_SPACE_BYTES = 4 << 30


def _bounded() -> None:  # in the child, before exec
    resource.setrlimit(resource.RLIMIT_AS, (MAX_ADDRESS_SPACE_BYTES, MAX_ADDRESS_SPACE_BYTES))


def _run(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    """A command, bounded in memory and time (the timeout is the test failing: a FIFO
    opened without O_NONBLOCK waits for ever, a correct refusal takes ~1 s)."""
    return subprocess.run(
        list(args),
        check=False,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        preexec_fn=_bounded,
        stdin=subprocess.DEVNULL,
    )


@pytest.fixture(scope="module")
def odd_configs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, str]]:
    d = tmp_path_factory.mktemp("configs")
    fifo = d / "fifo.toml"
    os.mkfifo(fifo)
    (d / "bom.toml").write_bytes(b"\xef\xbb\xbf[service]\nid = 'x'\n")
    (d / "deep.toml").write_bytes(b"x = " + b"[" * 100_000 + b"]" * 100_000 + b"\n")
    return {
        "device": (Path("/dev/zero"), "is a device, not a regular file: refused"),
        "fifo": (fifo, "is a FIFO, not a regular file: refused"),
        "bom": (d / "bom.toml", "starts with a UTF-8 byte order mark (BOM)"),
        "deep": (d / "deep.toml", "arrays or tables nested deeper than 32 levels: refused"),
    }


#: serve's default worker mode (no --workers: one per usable core) and one worker
WORKER_MODES = {"default-workers": [], "one-worker": ["--workers", "1"]}


@pytest.mark.parametrize("workers", list(WORKER_MODES))
@pytest.mark.parametrize("kind", ["device", "fifo", "bom", "deep"])
def test_odd_config_files_are_exit_2_with_the_reason(
    kind: str, workers: str, odd_configs: dict[str, tuple[Path, str]]
) -> None:
    path, reason = odd_configs[kind]
    for cmd in (
        [
            OBS,
            "serve",
            "--config",
            str(path),
            "--link",
            "udpin:127.0.0.1:9",
            *WORKER_MODES[workers],
        ],
        [SITL, "run", "--config", str(path), "--duration", "1"],
    ):
        proc = _run(*cmd)
        assert proc.returncode == 2, (cmd, proc.returncode, proc.stderr[-2000:])
        assert f"{path}: -: {reason}" in proc.stderr, proc.stderr[-2000:]
        assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("workers", list(WORKER_MODES))
def test_a_signing_key_file_that_is_a_device_is_refused(workers: str, tmp_path: Path) -> None:
    config = tmp_path / "service.toml"
    config.write_text('[security]\nsigning_key_file = "/dev/zero"\n', encoding="utf-8")
    proc = _run(OBS, "serve", "--config", str(config), "--link", "udpin:127.0.0.1:9",
                *WORKER_MODES[workers])  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert (
        f"{config}: security.signing_key_file: cannot read /dev/zero: is a device, not a "
        "regular file: refused"
    ) in proc.stderr


def _damaged(src: Path, dst: Path, seed: int, flips: int = 200) -> Path:
    """``src`` (gzip) with ``flips`` random bits flipped past its first 16 bytes (the
    magic stays: the file is still recognised as what it was)."""
    data = bytearray(gzip.decompress(src.read_bytes()))
    rng = random.Random(seed)
    for _ in range(flips):
        data[rng.randrange(16, len(data))] ^= 1 << rng.randrange(8)
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize(
    ("log", "what"),
    [("px4_sitl_trimmed.ulg.gz", "ULog"), ("arducopter_sitl_trimmed.BIN.gz", "dataflash log")],
)
def test_a_damaged_flight_log_is_exit_2_with_the_reason_and_no_output(
    log: str, what: str, tmp_path: Path
) -> None:
    """Seeds 0-2: seed 0 of the .ulg is the traceback of the issue (a parameter's bytes
    where its float was); the others are refused for other reasons found by the reader
    (no attitude, no GPS fix left), each named, each leaving no output."""
    damaged_reason = 0
    for seed in range(3):
        bad = _damaged(PUBLIC_LOGS / log, tmp_path / f"bad{seed}-{log[:-3]}", seed)
        out, rrd = tmp_path / "out.jsonl", tmp_path / "out.rrd"
        proc = _run(OBS, "replay", str(bad), "--out", str(out), "--rrd", str(rrd),
                    "--no-progress", timeout_s=300)  # fmt: skip
        assert proc.returncode == 2, (seed, proc.returncode, proc.stderr[-2000:])
        assert proc.stderr.startswith(f"glmav-observer replay: {bad}: "), proc.stderr[-2000:]
        assert "Traceback" not in proc.stderr
        damaged_reason += f"{bad}: damaged {what}: " in proc.stderr
        assert not out.exists() and not rrd.exists()  # was a 0-byte out.jsonl
        assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith("bad")) == []
    assert damaged_reason >= 1


def test_replay_out_through_a_link_leaves_the_target_untouched(tmp_path: Path) -> None:
    log = tmp_path / "px4.ulg"
    log.write_bytes(gzip.decompress((PUBLIC_LOGS / "px4_sitl_trimmed.ulg.gz").read_bytes()))
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    link = tmp_path / "out.jsonl"
    link.symlink_to(victim)
    rrd_link = tmp_path / "out.rrd"
    rrd_link.symlink_to(victim)
    for flag, path in (("--out", link), ("--rrd", rrd_link)):
        proc = _run(OBS, "replay", str(log), flag, str(path), "--force", "--no-progress")
        assert proc.returncode == 2, proc.stderr[-2000:]
        assert f"glmav-observer replay: {path}: is a symbolic link: refused" in proc.stderr
    assert victim.read_text() == "precious\n"  # was overwritten with the records
    assert link.is_symlink() and rrd_link.is_symlink()
