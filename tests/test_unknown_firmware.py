"""A firmware no hilbench module knows (firmware/template, built by its Makefile as `sil:PATH`) under
the tools a user reaches for beside `run`/`step`/`report` (tests/test_self_describing.py): `ctl set`
and `ctl get` on its parameters by name while it runs, the scope's stream with its telemetry as
named columns with units, and the pytest plugin's `bench` fixture on it. Everything comes from the
firmware's handshake (protocol 3); no Python plug-in is involved.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest

import hilbench
from _firmware import require_tool
from conftest import REPO_ROOT

TEMPLATE = "sil:firmware/template"
CONFIG = REPO_ROOT / "bench_configs" / "hurst_mclv.toml"

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def _tools() -> None:
    require_tool("gcc", "the template's SIL build")
    require_tool("make", "the template's Makefile")


def _cli(*args: str, timeout: float = 120.0, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **env}, cwd=REPO_ROOT)


def test_ctl_sets_and_reads_the_templates_parameters(tmp_path: Path) -> None:
    config = tmp_path / "hold.toml"  # a scenario with no end: the run lasts until `ctl stop`
    config.write_text(CONFIG.read_text() + "\n[[scenario]]\nat_s = 0.01\npress = \"s2\"\n")
    with tempfile.TemporaryDirectory(prefix="hb") as runtime:  # a short path for the Unix socket
        env = {"XDG_RUNTIME_DIR": runtime}
        process = subprocess.Popen([sys.executable, "-m", "hilbench", "run", str(config), "--target", TEMPLATE,
                                    "--duration", "86400", "--no-ui", "--set", "tuning.guard=false"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   env={**os.environ, **env}, cwd=REPO_ROOT)
        try:
            sessions = Path(runtime) / "hilbench" / "sessions"
            deadline = time.monotonic() + 120  # a first run builds the template
            while not (sessions.is_dir() and any(sessions.glob("*.session"))):
                assert process.poll() is None, process.stderr.read() if process.stderr else ""
                assert time.monotonic() < deadline, "no session published"
                time.sleep(0.05)  # polling for the session's socket with a deadline
            changed = _cli("ctl", "set", "duty_pct=35", timeout=30, **env)
            assert changed.returncode == 0, changed.stderr
            got = _cli("ctl", "get", timeout=30, **env)
            assert '"duty_pct": 35' in got.stdout, got.stdout
            refused = _cli("ctl", "set", "duty_pct=101", timeout=30, **env)  # declared range 0..100 %
            assert refused.returncode != 0 and "out of range" in refused.stderr, refused.stderr
            stopped = _cli("ctl", "stop", timeout=30, **env)
            assert stopped.returncode == 0, stopped.stderr
            out, err = process.communicate(timeout=60)
            assert process.returncode == 0, err
            assert "stopped by ctl" in out
        finally:
            if process.poll() is None:
                process.kill()
                process.communicate(timeout=10)


class _Request:
    """A control request answered in process (what the control socket hands the session)."""

    def __init__(self, cmd: str, **args: Any) -> None:
        self.cmd, self.args = cmd, args
        self.answer: tuple[bool, str, Any] | None = None

    def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None:
        self.answer = (ok, text, data)


def test_the_scope_stream_names_the_templates_columns_with_units(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO_ROOT)
    columns = ["t_s", "speed_rpm", "fw_speed_rpm", "edge_interval_us", "fw_sector"]
    with hilbench.Bench(target=TEMPLATE) as bench:
        bench.press("s2")
        bench.run(0.3)
        request = _Request("stream", since=-1, columns=columns)
        bench.session.handle_control(request, bench.t_s)  # type: ignore[union-attr]
    assert request.answer is not None and request.answer[0], request.answer
    meta = request.answer[2]["meta"]
    units = dict(meta["columns"])
    assert units["fw_speed_rpm"] == "rpm" and units["edge_interval_us"] == "us" and units["speed_rpm"] == "rpm"
    assert meta["params"]["duty_pct"]["min"] == 0 and meta["params"]["duty_pct"]["max"] == 100
    assert request.answer[2]["frames"], "no frame of the run"


PLUGIN_TEST = '''
def test_the_template_turns_the_motor(bench):
    assert bench.hello.firmware_name == "TEMPLATE"
    bench.set_params(duty_pct=30)
    bench.press("s2")
    bench.run(0.4)
    signals = bench.signals()
    assert signals["speed_rpm"][-1] > 300.0
    assert abs(signals["fw_speed_rpm"][-1] - signals["speed_rpm"][-1]) < 0.05 * signals["speed_rpm"][-1]
'''


def test_the_pytest_plugin_runs_a_test_on_the_template(tmp_path: Path) -> None:
    (tmp_path / "test_user.py").write_text(PLUGIN_TEST)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--hil-target",
                             f"sil:{REPO_ROOT / 'firmware' / 'template'}", str(tmp_path / "test_user.py")],
                            capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout
