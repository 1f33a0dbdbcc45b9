"""Rerun sink against real Rerun processes on loopback.

- ``connect:URL`` to a real gRPC receiver (``rerun --save``), decimated, read back;
- ``serve``: only 127.0.0.1 sockets by default, a late viewer gets the buffered data,
  the web viewer answers over HTTP;
- a viewer that is gone: ``write`` keeps going, memory stays bounded, ``close`` returns;
- ``spawn`` with a (virtual) display starts a real viewer that takes the data;
- a screenshot of the viewer showing a recording, rendered headless (Xvfb + lavapipe),
  checked by pixel statistics.

The last two are marked ``viewer``: they need system packages
(``scripts/install-render-deps.sh``: Xvfb, lavapipe), so the default run leaves them out
(``addopts -m "not viewer"``) and CI runs them with ``pytest -m viewer`` after installing
the packages. Selected without the packages, they fail, never skip.
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import time
import urllib.request
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import psutil
import pytest

from glmav_observer.frames import e_exact
from glmav_observer.publish.rerun import (
    COLORS,
    TIMELINE,
    open_rerun_sink,
    read_recording,
    rerun_executable,
)
from glmav_observer.records import (
    CONFIGS,
    FaultEvent,
    HealthRecord,
    MeasurementRecord,
    Record,
    TruthRecord,
    VelocityRecord,
)

REPO_ROOT = Path(__file__).resolve().parents[3]
RERUN = rerun_executable() or "rerun"  # the binary itself, so that signals reach it


def flight(duration_s: float, *, sysid: int = 1, fault_t_s: float = 6.0) -> list[Record]:
    """Records at the daemon's default rates for a vehicle circling at 2 m/s.

    Estimates: truth plus a per-configuration offset; from ``fault_t_s`` the north
    measurement is biased by 1 m/s, the configurations that use it drift, and 0.5 s
    later the service isolates axis n and switches to c2 (north lost).
    """
    out: list[Record] = []
    offsets = {"full": 0.0, "c1": 0.03, "c2": -0.03, "c3": 0.05}
    for k in range(int(duration_s * 250)):
        t = k / 250
        w = 0.3
        v_ned = np.array([-2 * math.sin(w * t), 2 * math.cos(w * t), 0.2 * math.sin(2 * t)])
        euler = (0.05 * math.sin(w * t), -0.08, w * t + math.pi / 2)
        v_body = e_exact(euler).T @ v_ned
        pos = (6.67 * math.cos(w * t), 6.67 * math.sin(w * t), -5.0)
        bias = 1.0 if t >= fault_t_s else 0.0
        isolated = t >= fault_t_s + 0.5
        for c in CONFIGS:
            drift = 0.4 * bias * min(t - fault_t_s, 0.5) if c != "c2" else 0.0
            est = v_ned + offsets.get(c, 0.0) + np.array([drift, 0.0, 0.0])
            vb = e_exact(euler).T @ est
            out.append(
                VelocityRecord(sysid, c, t, tuple(vb), tuple(est), None, "ok", k, None, None)  # type: ignore[arg-type]
            )
        src = "c2" if isolated else "full"
        bank = out[-len(CONFIGS) :]
        active = next(r for r in bank if isinstance(r, VelocityRecord) and r.config == src)
        out.append(
            VelocityRecord(
                sysid,
                "active",
                t,
                active.v_body_mps,
                active.v_ned_mps,
                "n" if isolated else None,
                "dead_reckoning" if isolated else "ok",
                k,
                src,
                0.05 * (t - fault_t_s) if isolated else None,
            )
        )
        if k % 5 == 0:  # SIM_STATE 50 Hz
            out.append(TruthRecord(sysid, t, tuple(v_body), tuple(v_ned), euler, pos, k))  # type: ignore[arg-type]
        if k % 8 == 0:  # LOCAL_POSITION_NED ~30 Hz
            meas = v_ned + np.array([bias, 0.0, 0.0])
            out.append(MeasurementRecord(sysid, t, tuple(meas), pos, k, euler))  # type: ignore[arg-type]
        if k % 25 == 0:  # health 10 Hz
            faults = (FaultEvent("n", "bias", fault_t_s + 0.5, fault_t_s),) if isolated else ()
            out.append(
                HealthRecord(
                    sysid,
                    t,
                    k,
                    src,
                    (bias, 0.02, -0.01),
                    (3.0 * bias + 0.3, 0.4, 0.2),
                    {
                        "n": "faulty" if isolated else ("suspect" if bias else "ok"),
                        "e": "ok",
                        "d": "ok",
                    },
                    faults,
                    {},
                    {},
                )
            )
    return out


def _wait_for(predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.02)


def _listening(port: int) -> list[tuple[str, int | None]]:
    return [
        (c.laddr.ip, c.pid)
        for c in psutil.net_connections("inet")
        if c.status == psutil.CONN_LISTEN and c.laddr.port == port
    ]


def _rows(path: Path, entity: str) -> int:
    try:
        with warnings.catch_warnings():  # "no footer": the file is still being written
            warnings.simplefilter("ignore")
            return len(read_recording(path).get(entity, {}).get("Scalars:scalars", []))
    except Exception:  # the file does not exist yet or ends mid-message
        return 0


@pytest.fixture
def receiver(
    free_tcp_port: Callable[[], int], tmp_path: Path
) -> Iterator[tuple[str, Path, subprocess.Popen[bytes]]]:
    """A real gRPC receiver on 127.0.0.1 (``rerun --save``) that writes what it gets to a file."""
    port = free_tcp_port()
    out = tmp_path / "received.rrd"
    proc = subprocess.Popen(
        [RERUN, "--bind", "127.0.0.1", "--port", str(port), "--save", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_for(lambda: bool(_listening(port)), 20, "the receiver to listen")
        yield f"rerun+http://127.0.0.1:{port}/proxy", out, proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.mark.timeout(60)
def test_connect_streams_decimated_records(
    receiver: tuple[str, Path, subprocess.Popen[bytes]],
) -> None:
    url, out, proc = receiver
    records = flight(2.0)
    sink = open_rerun_sink(f"connect:{url}", decimation=5, recording_name="connect-test")
    assert sink.effective_mode == f"connect:{url}"
    for r in records:
        sink.write(r)
    assert sink.flush(timeout_s=20)
    sink.close()
    assert sink.stats.batches_dropped == 0
    full_u = [r for r in records if isinstance(r, VelocityRecord) and r.config == "full"]
    expected = full_u[::5]  # every 5th record per configuration (decimation 5)
    entity = "/vehicle/1/estimate/v_body/u"
    _wait_for(lambda: _rows(out, entity) == len(expected), 20, "all rows at the receiver")
    # the receiver finishes its file on SIGTERM as on SIGINT; SIGINT is not sent because a
    # suite started in the background by a shell without job control (`cmd &`) runs with
    # SIGINT ignored, and an ignored signal stays ignored in the receiver across exec
    proc.send_signal(signal.SIGTERM)
    proc.wait(20)
    rec = read_recording(out)
    got = rec[entity]
    np.testing.assert_allclose(got[TIMELINE], [r.t_boot_s for r in expected], atol=1e-9)
    # instance 0 of the estimate entities is the full configuration
    assert [v[0] for v in got["Scalars:scalars"]] == [r.v_body_mps[0] for r in expected]
    truth = [r for r in records if isinstance(r, TruthRecord)]
    assert len(rec["/vehicle/1/truth/v_ned/n"]["Scalars:scalars"]) == len(truth)  # not decimated
    assert len(rec["/vehicle/1/health/state"]["Scalars:scalars"]) == 20  # 10 Hz, 2 s


@pytest.mark.timeout(90)
def test_serve_binds_loopback_only_and_late_viewer_gets_data(
    free_tcp_port: Callable[[], int], tmp_path: Path
) -> None:
    me = psutil.Process()
    before = {
        (c.laddr.ip, c.laddr.port)
        for c in me.net_connections("inet")
        if c.status == psutil.CONN_LISTEN
    }
    grpc_port, web_port = free_tcp_port(), free_tcp_port()
    sink = open_rerun_sink("serve", grpc_port=grpc_port, web_port=web_port)
    try:
        assert sink.grpc_url == f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        assert sink.web_url is not None
        _wait_for(lambda: bool(_listening(grpc_port)) and bool(_listening(web_port)), 20, "ports")
        assert {ip for ip, _ in _listening(grpc_port)} == {"127.0.0.1"}
        assert {ip for ip, _ in _listening(web_port)} == {"127.0.0.1"}
        # nothing else was opened on any other interface, by us or the web viewer process
        new = {
            (c.laddr.ip, c.laddr.port)
            for c in me.net_connections("inet")
            if c.status == psutil.CONN_LISTEN
        } - before
        assert sink._web_process is not None
        web = psutil.Process(sink._web_process.pid)
        new |= {
            (c.laddr.ip, c.laddr.port)
            for c in web.net_connections("inet")
            if c.status == psutil.CONN_LISTEN
        }
        assert new == {("127.0.0.1", grpc_port), ("127.0.0.1", web_port)}
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as resp:
            assert resp.status == 200
            assert b"<html" in resp.read(4096).lower()

        records = flight(1.0)
        for r in records:
            sink.write(r)
        assert sink.flush(timeout_s=20)
        # a viewer that joins after the data was logged gets it from the server's buffer
        late = tmp_path / "late.rrd"
        viewer_port = free_tcp_port()
        proc = subprocess.Popen(
            [
                RERUN,
                "--bind",
                "127.0.0.1",
                "--port",
                str(viewer_port),
                "--save",
                str(late),
                sink.grpc_url,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            n_full = sum(1 for r in records if isinstance(r, VelocityRecord) and r.config == "full")
            entity = "/vehicle/1/estimate/v_ned/e"
            _wait_for(lambda: _rows(late, entity) == n_full, 30, "the late viewer's data")
        finally:
            proc.send_signal(signal.SIGTERM)  # (SIGINT may be ignored: see above)
            proc.wait(20)
    finally:
        sink.close()
    _wait_for(lambda: not _listening(grpc_port) and not _listening(web_port), 20, "ports closed")


@pytest.mark.timeout(120)
def test_gone_viewer_does_not_block_or_grow(free_tcp_port: Callable[[], int]) -> None:
    dead = free_tcp_port()  # nothing listens there
    records = flight(30.0)
    me = psutil.Process()
    rss0 = me.memory_info().rss
    # a short flush period makes many small chunks: rerun's byte quota fills within the test
    sink = open_rerun_sink(f"connect:rerun+http://127.0.0.1:{dead}/proxy", flush_period_s=0.05)
    max_queued = 0
    for i, r in enumerate(records):
        sink.write(r)
        if i % 1000 == 0:
            max_queued = max(max_queued, sink.queued_batches())
    grown_mb = (me.memory_info().rss - rss0) / 1e6
    t0 = time.monotonic()
    sink.close(timeout_s=3)
    close_s = time.monotonic() - t0
    # rerun buffers for an unreachable viewer up to its own byte quota (~100 MB measured),
    # then blocks its sender: our sender thread stops, our queue (64 batches) fills and the
    # rest is dropped and counted; write() never waits.
    assert sink.stats.batches_dropped > 0
    assert sink.stats.rows_dropped > 0
    assert max_queued <= 64
    assert grown_mb < 400, grown_mb  # rerun's quota plus our bounded queue, with margin
    # close: join 3 s + rerun's flush 2 s + its last connection attempt 5 s, with margin
    assert close_s < 20, close_s


def _xvfb_display() -> tuple[subprocess.Popen[bytes], str]:
    """A virtual X display: Xvfb picks a free display number and reports it on a pipe."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.fail("Xvfb not installed: run scripts/install-render-deps.sh")
    r, w = os.pipe()
    proc = subprocess.Popen(
        [xvfb, "-displayfd", str(w), "-screen", "0", "1920x1200x24", "-nolisten", "tcp"],
        pass_fds=(w,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        pytest.fail("Xvfb did not start")
    return proc, f":{number}"


def _render_env(display: str, tmp_path: Path) -> dict[str, str]:
    icds = sorted(Path("/usr/share/vulkan/icd.d").glob("lvp_icd*.json"))
    if not icds:
        pytest.fail(
            "lavapipe (mesa-vulkan-drivers) not installed: run scripts/install-render-deps.sh"
        )
    runtime = tmp_path / "xdg"
    runtime.mkdir(mode=0o700, exist_ok=True)
    return {
        **os.environ,
        "DISPLAY": display,
        "VK_ICD_FILENAMES": ":".join(map(str, icds)),  # software Vulkan, whatever GPU is there
        "XDG_RUNTIME_DIR": str(runtime),
    }


@pytest.mark.viewer
@pytest.mark.timeout(90)
def test_spawn_with_a_display_starts_a_viewer(
    free_tcp_port: Callable[[], int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    xvfb, display = _xvfb_display()
    viewer: psutil.Process | None = None
    try:
        for key, value in _render_env(display, tmp_path).items():
            monkeypatch.setenv(key, value)
        port = free_tcp_port()
        sink = open_rerun_sink(
            "spawn", spawn_port=port, fallback_save_path=str(tmp_path / "no.rrd")
        )
        owners = [pid for _, pid in _listening(port) if pid is not None]
        assert owners, "the spawned viewer does not listen"
        viewer = psutil.Process(owners[0])
        assert Path(viewer.exe()).name == "rerun"
        assert sink.effective_mode == "spawn"
        for r in flight(1.0):
            sink.write(r)
        assert sink.flush(timeout_s=30)  # the viewer took every batch
        sink.close()
        assert sink.stats.batches_dropped == 0
        assert viewer.is_running()
        assert not (tmp_path / "no.rrd").exists()
    finally:
        if viewer is not None and viewer.is_running():
            viewer.kill()
        xvfb.kill()
        xvfb.wait()


#: Minimum pixels of a series colour in the screenshot (tolerance 30 per channel).
#: Measured at 1600x1000 points (3200x2000 px): truth ~1.5e4, c2 ~1.8e4, c3 ~1.9e4,
#: active ~1.2e4 px. The same viewer showing an empty recording has 0 pixels of each of
#: these (its UI is grey, blue and orange). Minimum: about a tenth of the measured counts.
MIN_SERIES_PIXELS = {"truth": 1500, "c2": 1500, "c3": 1500, "active": 1200}


def _count_color(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 30) -> int:
    return int((np.abs(img[:, :, :3].astype(int) - np.array(rgb)).max(axis=2) <= tol).sum())


@pytest.mark.viewer
@pytest.mark.timeout(120)
def test_viewer_screenshot_of_a_recording(tmp_path: Path) -> None:
    from PIL import Image

    rrd = tmp_path / "flight.rrd"
    sink = open_rerun_sink(f"save:{rrd}", recording_name="screenshot")
    for r in flight(12.0):
        sink.write(r)
    sink.close()
    if shutil.which("Xvfb") is None:
        pytest.fail("Xvfb not installed: run scripts/install-render-deps.sh")
    xvfb, display = _xvfb_display()
    png = tmp_path / "view.png"
    try:
        # the pointer sits at the screen's centre; a screen larger than the window keeps
        # it off the plots (no hover tooltip in the picture)
        result = subprocess.run(
            [
                RERUN,
                "--renderer",
                "vulkan",
                "--bind",
                "127.0.0.1",
                "--port",
                "0",
                "--window-size",
                "1600x1000",
                "--screenshot-to",
                str(png),
                str(rrd),
            ],
            env=_render_env(display, tmp_path),
            capture_output=True,
            timeout=100,
            check=False,
        )
    finally:
        xvfb.kill()
        xvfb.wait()
    assert png.is_file(), result.stderr.decode(errors="replace")[-3000:]
    img = np.asarray(Image.open(png).convert("RGB"))
    h, w, _ = img.shape
    assert w >= 1600 and h >= 1000
    luminance = img.mean(axis=2)
    assert luminance.std() > 10  # not a blank frame (measured: 25 with the plots, 0 if blank)
    counts = {name: _count_color(img, COLORS[name]) for name in MIN_SERIES_PIXELS}
    for name, minimum in MIN_SERIES_PIXELS.items():
        assert counts[name] >= minimum, counts
    if os.environ.get("GLMAV_WRITE_DOCS_IMG") == "1":  # refresh docs/img/rerun-view.png
        target = REPO_ROOT / "docs" / "img" / "rerun-view.png"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(png, target)
