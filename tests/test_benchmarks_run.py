"""The cheap benchmarks run to their last line (each was found broken once by a change elsewhere: a
message's fields, the wire library's files). The figures are not checked: tests assert no times."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from _firmware import require_tool

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def _run(script: str, *args: str) -> str:
    done = subprocess.run([sys.executable, str(BENCHMARKS / script), *args], capture_output=True, text=True,
                          timeout=300, cwd=BENCHMARKS.parent)
    assert done.returncode == 0, f"{script}: exit {done.returncode}\n{done.stderr[-2000:]}"
    return done.stdout


def test_bench_protocol_compares_v1_with_this_tree() -> None:
    if shutil.which("git") is None or not (BENCHMARKS.parent / ".git").exists():
        pytest.skip("bench_protocol reads protocol 1 from git history: not a git checkout")
    out = _run("bench_protocol.py", "--repeats", "1")
    assert "v3 per lockstep period" in out.splitlines()[-1], out[-500:]


def test_bench_link_builds_the_c_loopback_and_compares() -> None:
    require_tool("gcc", "the C loopback target (apt: gcc)")
    out = _run("bench_link.py", "--repeats", "1", "--periods", "200", "--no-tcp")
    assert "<-> C loopback" in out and out.splitlines()[-1].startswith("ratio framed py / raw"), out[-500:]


@pytest.mark.slow
def test_bench_realtime_prints_the_bench_its_baseline_and_the_vm_steal() -> None:
    out = _run("bench_realtime.py", "--seconds", "1")
    assert "against emulator:an1017" in out and "VM steal time over the bench" in out, out[-800:]
    assert "baseline in the same run" in out and out.count("VM steal") == 3, out[-800:]
