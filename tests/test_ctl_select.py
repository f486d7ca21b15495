"""Which session `ctl` acts on (issue 22, item 2): never a guess among several. Two real sessions run
as processes, each started in its own directory; `hilbench ctl get` run in one of those directories
acts on that one, run anywhere else it refuses and lists both, and `--session PID|N` picks one."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench.bench.control import list_sessions

#: a session of the in-process AN1017 with kp given, paced by sleeps (light on a loaded machine)
SESSION = """
import sys, threading
import hilbench
from hilbench.bench.control import ControlServer
from hilbench.processes import watch_parent
watch_parent()
with hilbench.Bench(target="inprocess:an1017", control=ControlServer(), keep_rows=False) as bench:
    bench.set_params(kp=float(sys.argv[1]))
    print("ready", flush=True)
    stop = threading.Event()
    while bench.run(0.005):
        stop.wait(0.01)
"""


def _ctl(cwd: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", "ctl", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=60)


@pytest.mark.slow
def test_ctl_picks_the_session_of_this_directory_or_refuses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runtime = tmp_path / "xdg"
    runtime.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    env = {**os.environ, "XDG_RUNTIME_DIR": str(runtime), "HILBENCH_PARENT_PID": str(os.getpid())}
    dirs = {"a": tmp_path / "bench_a", "b": tmp_path / "bench_b", "elsewhere": tmp_path / "elsewhere"}
    for d in dirs.values():
        d.mkdir()
    kp = {"a": 0.125, "b": 0.25}  # exact in Q15: each session says who it is by its kp
    procs = {name: subprocess.Popen([sys.executable, "-c", SESSION, str(kp[name])], cwd=dirs[name], env=env,
                                    stdout=subprocess.PIPE, text=True) for name in kp}
    try:
        for proc in procs.values():
            assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 30
        while len(list_sessions()) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)  # the discovery files are written before "ready"; a loaded machine may lag
        running = list_sessions()
        assert len(running) == 2
        for name in kp:
            got = _ctl(dirs[name], env, "get", "--json")
            assert got.returncode == 0, got.stderr
            assert json.loads(got.stdout)["data"]["params"]["kp"] == kp[name]  # the one started here
            assert "sessions running" not in got.stderr
        refused = _ctl(dirs["elsewhere"], env, "get")
        assert refused.returncode == 2 and refused.stdout == ""
        line = refused.stderr.strip()
        assert "\n" not in line and "none was started in" in line and "--session" in line
        assert all(f"pid {proc.pid} in {dirs[name]}" in line for name, proc in procs.items())
        by_pid = _ctl(dirs["elsewhere"], env, "get", "--json", "--session", str(procs["b"].pid))
        assert by_pid.returncode == 0 and json.loads(by_pid.stdout)["data"]["params"]["kp"] == kp["b"]
        newest = running[0]
        by_number = _ctl(dirs["elsewhere"], env, "get", "--json", "--session", "1")
        assert by_number.returncode == 0
        name_of_newest = next(name for name, proc in procs.items() if proc.pid == newest.pid)
        assert json.loads(by_number.stdout)["data"]["params"]["kp"] == kp[name_of_newest]
        wrong = _ctl(dirs["elsewhere"], env, "get", "--session", "7")
        assert wrong.returncode == 2 and "no such pid or number" in wrong.stderr
    finally:
        for proc in procs.values():
            proc.terminate()
        for proc in procs.values():
            proc.wait(timeout=30)


@pytest.mark.parametrize("command", ["ctl", "scope"])
def test_socket_and_session_together_are_refused(command: str, tmp_path: Path) -> None:
    """Third audit: `scope --socket X --session N` ignored --session (ctl refused the pair)."""
    words = ["get"] if command == "ctl" else []
    done = subprocess.run([sys.executable, "-m", "hilbench", command, "--socket", str(tmp_path / "none.sock"),
                           "--session", "1", *words], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == f"hilbench: config error: {command}: give --socket or --session, not both"
