"""Issue 23: command-line repros. `link-test emulator:nope` is "unknown target" (exit 2) as in
`run`; a bad `--hil-target` is one usage error, not an error per test; `emulate --port tcp:0`
serves one host after another."""

from __future__ import annotations

import os
import select
import subprocess
import sys
from pathlib import Path

import pytest

from _hostile import REPO_ROOT, assert_one_line_error, hilbench
from hilbench.link import open_link
from hilbench.processes import reap
from hilbench.targets.remote import RemoteTarget

TIMEOUT_S = 30.0


def test_link_test_names_an_unknown_target_as_run_does() -> None:
    """Repro: `link-test emulator:nope` said "no TargetHello after 5 HostHello attempts" (exit 4)."""
    line = assert_one_line_error(hilbench("link-test", "emulator:nope"), 2, "unknown target 'nope'")
    run = hilbench("run", "--target", "emulator:nope", "--no-ui", "--no-control")
    assert_one_line_error(run, 2, "unknown target 'nope'")
    assert line.startswith("hilbench: config error:")


@pytest.mark.slow
def test_link_test_starts_an_emulator_spec_as_run_does() -> None:
    """`link-test emulator:an1017` used to open a pty with nobody at its far end."""
    result = hilbench("link-test", "emulator:an1017", "--periods", "200")
    assert result.returncode == 0, result.stderr
    assert "200 / 200" in result.stdout


TINY_TEST = """
def test_one(bench):
    assert bench.hello

def test_two(bench):
    assert bench.hello
"""


@pytest.mark.parametrize("option, words", [
    (("--hil-target", "emulator:nope"), ("ERROR: --hil-target emulator:nope: unknown target 'nope'",)),
    (("--hil-target", "nonsense spec"), ("ERROR: --hil-target nonsense spec: unknown target spec",)),
    (("--hil-config", "/dev/zero"), ("ERROR: --hil-config: /dev/zero: more than the limit of 1 MiB",)),
])
def test_a_bad_hil_option_is_one_usage_error(tmp_path: Path, option: tuple[str, ...], words: tuple[str, ...]) -> None:
    """Repro: a bad `--hil-target` errored every test at setup with a traceback."""
    (tmp_path / "test_tiny.py").write_text(TINY_TEST)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *option, "test_tiny.py"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 4  # pytest's usage error
    assert "Traceback" not in result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and all(w in lines[0] for w in words), result.stderr
    assert "test_one" not in result.stdout  # no test ran


def _first_line(proc: subprocess.Popen[bytes]) -> str:
    assert proc.stdout is not None
    buf = b""
    while not buf.endswith(b"\n"):
        ready, _, _ = select.select([proc.stdout], [], [], TIMEOUT_S)
        assert ready, "emulate printed nothing"
        chunk = os.read(proc.stdout.fileno(), 1024)
        assert chunk, "emulate exited early"
        buf += chunk
    return buf.decode().strip()


@pytest.mark.slow
def test_emulate_on_tcp_keeps_serving_after_the_first_host() -> None:
    """Repro: `hilbench emulate --port tcp:0` ended after its first client."""
    proc = subprocess.Popen([sys.executable, "-P", "-m", "hilbench", "emulate", "an1017", "--port", "tcp:0", "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO_ROOT)
    try:
        url = _first_line(proc)
        assert url.startswith("socket://127.0.0.1:")
        for _ in range(3):  # one host after another
            link = open_link(url, timeout_s=2.0)
            try:
                hello = RemoteTarget(link, timeout_s=2.0).handshake(50)
                assert hello.firmware_name == "AN1017"
            finally:
                link.close()
        assert proc.poll() is None
    finally:
        reap(proc)
        assert b"Traceback" not in proc.stderr.read()  # type: ignore[union-attr]
        proc.stdout.close()  # type: ignore[union-attr]
        proc.stderr.close()  # type: ignore[union-attr]


@pytest.mark.slow
def test_emulate_on_tcp_once_ends_after_the_first_host() -> None:
    proc = subprocess.Popen([sys.executable, "-P", "-m", "hilbench", "emulate", "loopback", "--port", "tcp:0", "--once",
                             "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO_ROOT)
    try:
        link = open_link(_first_line(proc), timeout_s=2.0)
        try:
            assert RemoteTarget(link, timeout_s=2.0).handshake(50).firmware_name == "loopback"
        finally:
            link.close()
        assert proc.wait(TIMEOUT_S) == 0
    finally:
        reap(proc)
        proc.stdout.close()  # type: ignore[union-attr]
        proc.stderr.close()  # type: ignore[union-attr]
