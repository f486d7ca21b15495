"""Issue 23: every child dies with its parent, whatever kills it. kill -9 of `hilbench sweep` (its
pool workers), of `hilbench run --scope` (the scope and the emulator) and of a pytest run with the
plugin (the bench's emulator) leaves no process of theirs alive after 2 s.

Each test waits until the children it expects exist (a condition), takes the parent's whole tree
from /proc, kills the parent with SIGKILL and waits (on a condition, 2 s at most) until none of
the tree is alive."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from _hostile import REPO_ROOT, descendants, pid_alive, wait_for
from hilbench import processes

#: the acceptance: no process of theirs alive this long after the kill
GONE_WITHIN_S = 2.0
#: how long the children may take to appear (a loaded machine starts Python slowly)
START_TIMEOUT_S = 120.0


def _start(args: list[str], cwd: Path = REPO_ROOT) -> subprocess.Popen[bytes]:
    return subprocess.Popen(args, cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def _kill_and_judge(parent: subprocess.Popen[bytes], tree: list[int]) -> None:
    assert tree, "no children to judge"
    parent.send_signal(signal.SIGKILL)
    parent.wait(30)
    try:
        wait_for(lambda: not [pid for pid in tree if pid_alive(pid)], GONE_WITHIN_S,
                 f"children {tree} gone after kill -9 of their parent")
    finally:
        for pid in tree:  # never leave them behind, whatever the verdict
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            return handle.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


@pytest.mark.slow
def test_kill_9_of_a_sweep_leaves_no_pool_worker(tmp_path: Path) -> None:
    """Repro: after kill -9 of `hilbench sweep`, both pool workers were alive 13 s later."""
    parent = _start([sys.executable, "-P", "-m", "hilbench", "sweep", "-p", "kp=0.05:0.5:40", "--workers", "2",
                     "--duration", "1.0", "--step-at", "0.5", "--resume", str(tmp_path / "s.jsonl")])
    try:
        tree = wait_for(lambda: len(descendants(parent.pid)) >= 2 and descendants(parent.pid), START_TIMEOUT_S,
                        "two pool workers")
        wait_for(lambda: (tmp_path / "s.jsonl").exists(), START_TIMEOUT_S, "the workers at work")
        _kill_and_judge(parent, descendants(parent.pid) or list(tree))  # type: ignore[arg-type]
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()


@pytest.mark.slow
def test_kill_9_of_run_scope_leaves_no_scope_and_no_emulator(tmp_path: Path) -> None:
    pytest.importorskip("aiohttp", reason="the scope extra (aiohttp) is not installed")
    parent = _start([sys.executable, "-P", "-m", "hilbench", "run", "--target", "emulator:an1017", "--duration", "3600",
                     "--no-ui", "--scope"], cwd=tmp_path)

    def both() -> list[int]:
        tree = descendants(parent.pid)
        lines = [_cmdline(pid) for pid in tree]
        has_scope = any(" scope --socket " in line for line in lines)
        has_emulator = any("hilbench.targets.emulator" in line for line in lines)
        return tree if has_scope and has_emulator else []

    try:
        tree = wait_for(both, START_TIMEOUT_S, "the scope and the emulator")
        _kill_and_judge(parent, tree)  # type: ignore[arg-type]
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()


PLUGIN_TEST = """
import time

def test_holds_its_bench(bench):
    bench.set_reference(1000)
    bench.press("s2")
    while True:  # killed from outside
        bench.run(0.01)
"""


@pytest.mark.slow
def test_kill_9_of_pytest_with_the_plugin_leaves_no_emulator(tmp_path: Path) -> None:
    (tmp_path / "test_holds.py").write_text(PLUGIN_TEST)
    parent = _start([sys.executable, "-P", "-m", "pytest", "-q", "-p", "no:cacheprovider", "--hil-target",
                     "emulator:an1017", "test_holds.py"], cwd=tmp_path)

    def emulator() -> list[int]:
        tree = descendants(parent.pid)
        return tree if any("hilbench.targets.emulator" in _cmdline(pid) for pid in tree) else []

    try:
        tree = wait_for(emulator, START_TIMEOUT_S, "the bench's emulator")
        _kill_and_judge(parent, tree)  # type: ignore[arg-type]
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()


def test_a_child_of_a_parent_that_died_before_it_was_armed_exits() -> None:
    """The race: the parent dies between fork and PR_SET_PDEATHSIG. The child sees that its parent
    is not the one that started it and exits at once."""
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: as if started by a parent that has gone (pid 1 is never our parent here)
        os.close(read_fd)
        try:
            processes.die_with_parent(parent_pid=os.getppid() + 10**6)
            os.write(write_fd, b"survived")
        finally:
            os._exit(0)
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as handle:
        assert handle.read() == b""
    _, status = os.waitpid(pid, 0)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 1


def test_watch_parent_ends_a_python_child_started_from_a_thread(tmp_path: Path) -> None:
    """PR_SET_PDEATHSIG is armed only from the main thread; a Python child started from another
    thread is still ended by its own watch when the parent goes (here: a middle process killed -9)."""
    import threading

    script = tmp_path / "middle.py"
    script.write_text(
        "import sys, threading, time\n"
        "from hilbench.processes import spawn\n"
        "out = []\n"
        "def start():\n"
        "    out.append(spawn([sys.executable, '-P', '-c', 'from hilbench.processes import watch_parent; "
        "import time; watch_parent(); time.sleep(600)']))\n"
        "t = threading.Thread(target=start); t.start(); t.join()\n"
        "print(out[0].pid, flush=True)\n"
        "time.sleep(600)\n")
    middle = subprocess.Popen([sys.executable, "-P", str(script)], stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)), start_new_session=True)
    try:
        assert middle.stdout is not None
        result: list[str] = []
        reader = threading.Thread(target=lambda: result.append(middle.stdout.readline()), daemon=True)  # type: ignore[union-attr]
        reader.start()
        reader.join(START_TIMEOUT_S)
        child = int(result[0])
        wait_for(lambda: "watch_parent" in _cmdline(child), START_TIMEOUT_S, "the grandchild running")
        _kill_and_judge(middle, [child])
    finally:
        if middle.poll() is None:
            middle.kill()
            middle.wait()
