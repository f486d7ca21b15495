"""The link commands as a user runs them: real processes, one-line errors, clean exits."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys

import pytest
from _tcp_serve import ServedInThread
from conftest import REPO_ROOT, run_cli

from hilbench.link import open_link
from hilbench.targets.remote import RemoteTarget


@pytest.mark.parametrize("args", [
    ("link-test", "serial:/dev/ttyNOPE_hilbench?baud=250000"),
    ("link-test", "/dev/ttyNOPE_hilbench"),
    ("emulate", "loopback", "--port", "/dev/ttyNOPE_hilbench"),
])
def test_missing_port_is_one_line_and_nonzero(args) -> None:
    result = run_cli(*args)
    assert result.returncode == 4  # LinkError
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "/dev/ttyNOPE_hilbench" in lines[0]


def test_unknown_target_lists_the_known_ones() -> None:
    result = run_cli("emulate", "nonesuch")
    assert result.returncode == 2
    assert "loopback" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_link_test_default_runs_the_loopback_process() -> None:
    result = run_cli("link-test", "--periods", "300", timeout=120)
    assert result.returncode == 0, result.stderr
    for needle in ("round trips/s", "RTT p50", "RTT p99", "RTT max", "crc_errors", "seq_gaps", "300 / 300"):
        assert needle in result.stdout


def _read_line(proc: subprocess.Popen, timeout_s: float) -> str:
    fd = proc.stdout.fileno()
    buf = b""
    while not buf.endswith(b"\n"):
        ready, _, _ = select.select([fd], [], [], timeout_s)
        assert ready, "emulate printed nothing"
        chunk = os.read(fd, 1024)
        assert chunk, "emulate exited early"
        buf += chunk
    return buf.decode().strip()


@pytest.mark.slow
def test_emulate_pty_prints_path_and_exits_when_host_hangs_up() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "hilbench", "emulate", "loopback", "--port", "pty", "--once"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO_ROOT)
    try:
        path = _read_line(proc, 30)
        assert path.startswith("/dev/")
        link = open_link(path, timeout_s=2.0)
        try:
            hello = RemoteTarget(link, timeout_s=2.0).handshake(1000)
            assert hello.firmware_name == "loopback"
        finally:
            link.close()
        assert proc.wait(timeout=30) == 0
        assert b"Traceback" not in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.slow
def test_emulate_ctrl_c_exits_cleanly() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "hilbench", "emulate", "an1017", "--port", "pty"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO_ROOT)
    try:
        _read_line(proc, 30)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) in (0, 130)
        assert b"Traceback" not in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.slow
@pytest.mark.parametrize("faults", ["", "?corrupt=0.0005&fault_seed=3"])
def test_link_test_over_socket_url_clean_and_lossy(faults: str) -> None:
    """`hilbench link-test socket://HOST:PORT[?fault keys]`: the loopback target served over TCP by
    this test process; the lossy spec injects faults with no code and no Drive is wrong."""
    served = ServedInThread("loopback")
    try:
        # a lost frame costs a retry (0.1 s), not the deadline; the deadline is long enough that a
        # loaded machine's scheduling delays lose no period (the server is a thread of this process):
        # a period that got no Drive fails link-test (exit 4)
        result = run_cli("link-test", served.url + faults, "--periods", "300", "--timeout-ms", "1000", timeout=120)
    finally:
        served.close()
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    rows = {line.strip("│┃ ").split("│")[0].strip(): line.split("│")[-2].strip()
            for line in result.stdout.splitlines() if line.count("│") >= 3}
    assert rows["mismatched Drives"] == "0"
    if faults:
        assert int(rows["host link crc_errors"]) + int(rows["host link cobs_errors"]) > 0
    else:
        assert rows["periods (good / asked)"] == "300 / 300"
        assert rows["host link frame_errors"] == "0"
