"""Helpers of the hostile-input tests (issue 23): run a command as a real process with its memory
capped, and judge its error the way the house rules ask (one line on stderr naming what and where,
the error kind's exit code, no traceback)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

REPO_ROOT = Path(__file__).resolve().parent.parent

#: the address space a hostile-input command may use: far above what the bench needs, far below
#: the machine's memory (a read without a limit ends in MemoryError instead of the OOM killer)
MEMORY_CAP_BYTES = 3 * 1024**3


def _cap_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP_BYTES, MEMORY_CAP_BYTES))


def hilbench(*args: str, cwd: Path | None = None, timeout_s: float = 120.0, stdin_text: str | None = None,
             env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """`python -P -m hilbench ARGS` with its memory capped; killed (and reaped) after timeout_s."""
    command = [sys.executable, "-P", "-m", "hilbench", *args]
    proc = subprocess.Popen(command, cwd=cwd or REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.PIPE if stdin_text is not None else subprocess.DEVNULL, text=True,
                            preexec_fn=_cap_memory, env=env)
    try:
        out, err = proc.communicate(stdin_text, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"{' '.join(args)}: still running after {timeout_s} s; stderr: {err[-500:]}") from None
    return subprocess.CompletedProcess(command, proc.returncode, out, err)


def assert_one_line_error(result: subprocess.CompletedProcess[str], exit_code: int, *words: str) -> str:
    """The command failed with `exit_code` and said so in one line on stderr holding every word."""
    err = result.stderr
    assert "Traceback" not in err, err[-3000:]
    lines = [line for line in err.splitlines() if line.strip()]
    assert result.returncode == exit_code, f"exit {result.returncode}, stderr: {err[-2000:]}"
    assert len(lines) == 1, f"{len(lines)} lines on stderr: {err[-2000:]}"
    for word in words:
        assert word in lines[0], f"{word!r} not in {lines[0]!r}"
    return lines[0]


def wait_for(condition: Callable[[], object], timeout_s: float, what: str, every_s: float = 0.02) -> object:
    """The condition's first true value; AssertionError naming `what` after timeout_s."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s} s")
        time.sleep(every_s)


def pid_alive(pid: int) -> bool:
    """A process that exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as handle:
            return handle.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def descendants(pid: int) -> list[int]:
    """Every process whose parent chain leads to `pid` (from /proc; the kernel's own view)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii") as handle:
                ppid = int(handle.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry))
    out: list[int] = []
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


__all__: Sequence[str] = ["MEMORY_CAP_BYTES", "assert_one_line_error", "descendants", "hilbench", "pid_alive",
                          "wait_for"]
