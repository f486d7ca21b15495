"""Live tuning through the control socket against the AN1017 emulator process on a pty."""

from __future__ import annotations

import io
import threading
import time
from pathlib import Path

import pytest
from rich.console import Console

from conftest import hurst_bench_config
from hilbench.bench.control import ControlClient, ControlServer
from hilbench.bench.recorder import MARKER_PARAM, read_recording
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.ui.dashboard import Dashboard

Q15 = 1 / 32768


@pytest.mark.slow
def test_live_tuning_over_the_control_socket(tmp_path: Path) -> None:
    cfg = load_run_config(RunRequest(str(hurst_bench_config(tmp_path, 60.0)), target="emulator:an1017"))
    server = ControlServer(tmp_path / "sock" / "ctl.sock", publish=False)
    client = ControlClient(server.path, timeout_s=10.0)
    replies: dict[str, dict] = {}
    failures: list[BaseException] = []

    def script() -> None:
        try:
            replies["first_get"] = client.request({"cmd": "get"}, timeout_s=30)
            replies["set"] = client.request({"cmd": "set", "params": {"kp": 0.12, "ki": 0.015}}, timeout_s=10)
            replies["get"] = client.request({"cmd": "get"}, timeout_s=10)
            replies["range"] = client.request({"cmd": "set", "params": {"kp": 1.5}}, timeout_s=10)
            replies["unknown"] = client.request({"cmd": "set", "params": {"kx": 0.1}}, timeout_s=10)
            replies["constraint"] = client.request({"cmd": "set", "params": {"kp": 0.6, "ki": 0.5}}, timeout_s=10)
            replies["malformed"] = client.request({"cmd": "set", "params": "kp"}, timeout_s=10)
            replies["unstable"] = client.request({"cmd": "set", "params": {"kp": 0.3, "ki": 0.6}}, timeout_s=10)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:  # the guard restores the gains within its window
                replies["after_guard"] = client.request({"cmd": "get"}, timeout_s=10)
                if abs(replies["after_guard"]["data"]["params"]["ki"] - 0.015) < Q15:
                    break
            replies["stop"] = client.request({"cmd": "stop"}, timeout_s=10)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            failures.append(exc)
            client.request({"cmd": "stop"}, timeout_s=10)

    console = Console(file=io.StringIO(), width=120)
    dashboard = Dashboard("emulator:an1017", 60.0, console=console)
    thread = threading.Thread(target=script, daemon=True)
    thread.start()
    try:
        summary = run_bench(cfg, record=tmp_path / "live.csv", control=server, on_ready=dashboard.attach)
    finally:
        thread.join(timeout=60)
        server.close()
    assert not failures, failures
    assert summary.end_reason == "stopped by ctl"

    assert replies["set"]["ok"], replies["set"]
    params = replies["get"]["data"]["params"]  # read back from the target with PARAM_GET
    assert params["kp"] == pytest.approx(0.12, abs=Q15) and params["ki"] == pytest.approx(0.015, abs=Q15)
    assert not replies["range"]["ok"] and "out of range" in replies["range"]["message"]
    assert not replies["unknown"]["ok"] and "unknown parameter 'kx'" in replies["unknown"]["message"]
    assert not replies["constraint"]["ok"] and "Kp + Ki + Kd < 0.9999" in replies["constraint"]["message"]
    assert not replies["malformed"]["ok"]
    assert replies["unstable"]["ok"]
    restored = replies["after_guard"]["data"]["params"]
    assert restored["kp"] == pytest.approx(0.12, abs=Q15) and restored["ki"] == pytest.approx(0.015, abs=Q15)

    # the dashboard followed every accepted change and the restore
    assert dashboard.params["kp"] == pytest.approx(0.12, abs=Q15)

    data = read_recording(tmp_path / "live.csv")
    set_events = [e for e in data.events if e.endswith("set kp=0.12 ki=0.015")]
    assert len(set_events) == 1
    t_set = float(set_events[0].split()[0][2:])
    marked = data.columns["t_s"][data.columns["marker"] == MARKER_PARAM]
    assert t_set == pytest.approx(marked[0], abs=1e-9)  # the row of the period it was applied in
    assert any(e.split(" ", 1)[1].startswith("guard: ") and "restored kp=0.1199" in e for e in data.events), data.events
