"""Child processes hilbench starts (emulators, firmware-in-the-loop builds, the scope, pool
workers): always reaped, and never outliving their parent, whatever kills it.

Three layers, because each alone has a hole:

* `reap` on every exit path the parent controls (terminate, wait, kill);
* ``PR_SET_PDEATHSIG`` (Linux): the kernel sends the child SIGTERM when the parent dies, even by
  kill -9. It is armed in the child between fork and exec (`child_preexec`), or in a pool worker
  by its initializer (`worker_init`). The kernel's "parent" is the *thread* that forked, so it is
  armed only when the main thread starts the child (a thread that ends would take its children
  with it); the parent's pid is checked after arming, so a parent that died before cannot be missed;
* `watch_parent`, in Python children: a daemon thread that ends the process when its parent
  process is gone (its parent pid changes), whichever thread started it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from typing import Any, Callable, Sequence

#: the environment variable that names a child's parent (for `watch_parent`)
PARENT_ENV = "HILBENCH_PARENT_PID"
_PR_SET_PDEATHSIG = 1
#: how often `watch_parent` looks
WATCH_EVERY_S = 0.2


def reap(process: subprocess.Popen[Any], timeout_s: float = 3.0) -> int:
    """Terminate a child and wait for it; kill it if it will not go. Returns its exit code."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=timeout_s)
    return process.returncode


def _prctl() -> Callable[..., int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True).prctl  # type: ignore[no-any-return]
    except (OSError, AttributeError):
        return None


_PRCTL = _prctl()  # resolved here, never between fork and exec


def die_with_parent(parent_pid: int, sig: int = signal.SIGTERM) -> None:
    """In the child: ask for ``sig`` when the parent dies; exit at once if it already has."""
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)


def child_preexec() -> Callable[[], None] | None:
    """The ``preexec_fn`` for a child started now: `die_with_parent` when this is the main thread
    (None otherwise: see the module docstring)."""
    if _PRCTL is None or threading.current_thread() is not threading.main_thread():
        return None
    parent = os.getpid()
    return lambda: die_with_parent(parent)


def child_env(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a child: ``env`` (default: ours) naming this process as its parent."""
    out = dict(os.environ if env is None else env)
    out[PARENT_ENV] = str(os.getpid())
    return out


def spawn(argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[Any]:
    """subprocess.Popen that dies with this process (`child_preexec`, `child_env`)."""
    kwargs["env"] = child_env(kwargs.get("env"))
    kwargs.setdefault("preexec_fn", child_preexec())
    return subprocess.Popen(list(argv), **kwargs)


def watch_parent(every_s: float = WATCH_EVERY_S) -> bool:
    """In a Python child started by `spawn`: end this process (SIGTERM to itself) when the parent
    named by PARENT_ENV is gone. False (nothing watched) when not started so."""
    try:
        parent = int(os.environ.get(PARENT_ENV, ""))
    except ValueError:
        return False
    return _watch(parent, every_s)


def _watch(parent: int, every_s: float) -> bool:
    """A daemon thread that sends this process SIGTERM once ``parent`` is gone: our parent pid
    changes (we were re-parented) or, for a process that is not our parent (a pool's maker behind
    a fork server), it no longer exists."""
    direct = os.getppid() == parent

    def gone() -> bool:
        return os.getppid() != parent if direct else not _alive(parent)

    if gone():
        os.kill(os.getpid(), signal.SIGTERM)
        return False

    def watch() -> None:
        while not gone():
            time.sleep(every_s)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="hilbench-watch-parent", daemon=True).start()
    return True


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def worker_init(parent_pid: int) -> None:
    """A process pool's initializer: the worker dies with the process that made the pool (its
    parent with the fork start method; behind a fork server, watched by pid)."""
    if os.getppid() == parent_pid and _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    os.environ[PARENT_ENV] = str(parent_pid)
    _watch(parent_pid, WATCH_EVERY_S)


__all__ = ["PARENT_ENV", "child_env", "child_preexec", "die_with_parent", "reap", "spawn", "watch_parent",
           "worker_init"]
