"""A board on another host: the emulator's pty exported by a real ser2net with an RFC 2217 accepter
(what labgrid's exporter runs), and a lockstep session through rfc2217://127.0.0.1:PORT whose
recording equals the direct one. Needs Debian's ser2net: skips without it, fails under
HILBENCH_REQUIRE_TOOLS=1."""

from __future__ import annotations

import select
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from _firmware import require_tool
from conftest import REPO_ROOT, run_cli
from hilbench.bench.recorder import read_recording


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _wait_listening(port: int, process: subprocess.Popen[bytes], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and process.poll() is None:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)  # polling for the listener with a deadline
    raise AssertionError(f"ser2net is not listening on {port}")


def _stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


#: 2 000 lockstep exchanges through ser2net (each ~3.5 ms over RFC 2217 here): the start, S2, the ramp
DURATION_S = "0.1"


@pytest.mark.slow
def test_a_session_through_ser2net_rfc2217_equals_the_direct_one(tmp_path: Path) -> None:
    ser2net = require_tool("ser2net", "exporting a board over RFC 2217 (apt-get install ser2net)")
    emulator = subprocess.Popen([sys.executable, "-m", "hilbench", "emulate", "--port", "pty", "--quiet"],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=REPO_ROOT)
    exporter = None
    try:
        ready, _, _ = select.select([emulator.stdout], [], [], 30)
        assert ready, "the emulator printed no path"
        tty = emulator.stdout.readline().decode().strip()  # type: ignore[union-attr]
        port = _free_port()
        config = tmp_path / "ser2net.yaml"
        config.write_text(f"connection: &board\n  accepter: telnet(rfc2217),tcp,127.0.0.1,{port}\n"
                          f"  connector: serialdev,{tty},250000n81,local\n  options:\n    kickolduser: true\n")
        exporter = subprocess.Popen([ser2net, "-n", "-u", "-c", str(config)], stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
        _wait_listening(port, exporter)
        url = f"rfc2217://127.0.0.1:{port}?ign_set_control"  # ser2net does not answer SET_CONTROL
        remote = run_cli("run", "--target", url, "--duration", DURATION_S, "--record", str(tmp_path / "far.npz"),
                         "--no-ui", "--no-control", timeout=180)
        assert remote.returncode == 0, remote.stderr
    finally:
        if exporter is not None:
            _stop(exporter)
        _stop(emulator)
        if emulator.stdout is not None:
            emulator.stdout.close()
    direct = run_cli("run", "--target", "inprocess:an1017", "--duration", DURATION_S, "--record", str(tmp_path / "near.npz"),
                     "--no-ui", "--no-control", timeout=120)
    assert direct.returncode == 0, direct.stderr
    far, near = read_recording(tmp_path / "far.npz").columns, read_recording(tmp_path / "near.npz").columns
    different = [k for k in near if k not in ("rtt_us", "lateness_us") and not np.array_equal(far[k], near[k], equal_nan=True)]
    assert not different and len(near["t_s"]) == 2000
