"""Child processes hilbench starts (emulators, firmware-in-the-loop builds): always reaped."""

from __future__ import annotations

import subprocess


def reap(process: subprocess.Popen[bytes], timeout_s: float = 3.0) -> int:
    """Terminate a child and wait for it; kill it if it will not go. Returns its exit code."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=timeout_s)
    return process.returncode


__all__ = ["reap"]
