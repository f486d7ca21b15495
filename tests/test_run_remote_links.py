"""`hilbench run` over any link the one spec grammar names: the emulator served over TCP and reached
through socket://, and a lossy pty chosen by spec (issue "targets as plug-ins", link acceptance)."""

from __future__ import annotations

import json
import select
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO_ROOT, run_cli
from hilbench.bench.recorder import read_recording


def _data_columns(path: Path) -> dict[str, np.ndarray]:
    return {k: v for k, v in read_recording(path).columns.items() if k not in ("rtt_us", "lateness_us")}


@pytest.mark.slow
def test_a_session_over_socket_to_the_emulator_served_on_tcp_equals_the_in_process_one(tmp_path: Path) -> None:
    server = subprocess.Popen([sys.executable, "-m", "hilbench", "emulate", "--port", "tcp:0", "--once", "--quiet"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT)
    try:
        ready, _, _ = select.select([server.stdout], [], [], 30)
        assert ready, "the emulator printed no URL"
        url = server.stdout.readline().strip()  # type: ignore[union-attr]
        assert url.startswith("socket://127.0.0.1:")
        remote = run_cli("run", "--target", url, "--duration", "0.5", "--record", str(tmp_path / "tcp.npz"),
                         "--no-ui", "--no-control", timeout=120)
        assert remote.returncode == 0, remote.stderr
        server.wait(timeout=30)  # it served the one host that connected, which hung up
    finally:
        if server.poll() is None:
            server.kill()
        server.communicate(timeout=10)
    local = run_cli("run", "--target", "inprocess:an1017", "--duration", "0.5", "--record", str(tmp_path / "in.npz"),
                    "--no-ui", "--no-control", timeout=120)
    assert local.returncode == 0, local.stderr
    a, b = _data_columns(tmp_path / "tcp.npz"), _data_columns(tmp_path / "in.npz")
    assert list(a) == list(b)
    assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a), [k for k in a if not np.array_equal(a[k], b[k], equal_nan=True)]


@pytest.mark.slow
def test_a_session_over_a_lossy_link_chosen_by_spec_survives() -> None:
    spec = "emulator:an1017?corrupt=3e-5&drop=1e-3&fault_seed=5"
    result = run_cli("run", "--target", spec, "--duration", "0.3", "--set", "link.retry_ms=5", "--json", "--no-control",
                     timeout=300)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["end_reason"] == "completed" and summary["periods"] == 6000
    link = summary["link"]
    assert link["frame_errors"] > 0 and link["retries"] > 0  # frames were lost and sent again


def test_real_time_over_a_network_link_warns_that_its_latency_adds_to_the_loops() -> None:
    from hilbench.bench.settings import link_warnings
    from hilbench.bench.settings import load_config

    far = load_config(None, ['link.target="socket://10.0.0.7:5000"', 'run.mode="realtime"', "link.period_us=1000"])
    assert any("network's latency" in w for w in link_warnings(far))
    assert link_warnings(load_config(None, ['link.target="socket://10.0.0.7:5000"'])) == []  # lockstep: no effect
    assert link_warnings(load_config(None, ['run.mode="realtime"', "link.period_us=1000"])) == []


@pytest.mark.slow
def test_a_silent_client_does_not_hold_the_emulators_tcp_port_from_the_host() -> None:
    """Third audit: a client that connected and sent nothing held `emulate --port tcp:` for ever;
    the real host got 'no TargetHello'. It is dropped after SILENT_CLIENT_S for the next."""
    from hilbench.targets.emulator import SILENT_CLIENT_S

    server = subprocess.Popen([sys.executable, "-m", "hilbench", "emulate", "loopback", "--port", "tcp:0", "--quiet"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT)
    silent = None
    try:
        ready, _, _ = select.select([server.stdout], [], [], 30)
        assert ready, "the emulator printed no URL"
        url = server.stdout.readline().strip()  # type: ignore[union-attr]
        silent = socket.create_connection(("127.0.0.1", int(url.rsplit(":", 1)[1])))
        # its handshake retries for 5 x 2 s, past the silent client's SILENT_CLIENT_S
        host = run_cli("link-test", url, "--periods", "200", "--timeout-ms", "2000", timeout=120)
        assert host.returncode == 0, host.stdout[-1500:] + host.stderr
        silent.settimeout(SILENT_CLIENT_S + 30)
        assert silent.recv(64) == b""  # the emulator hung up on it
    finally:
        if silent is not None:
            silent.close()
        server.kill()
        server.communicate(timeout=10)
