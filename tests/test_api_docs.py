"""docs/api.md's examples run, each in a fresh interpreter with no other import first."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO_ROOT

EXAMPLES = re.findall(r"```python\n(.*?)```", (REPO_ROOT / "docs" / "api.md").read_text(), re.DOTALL)


def test_the_page_has_examples() -> None:
    assert len(EXAMPLES) >= 5


@pytest.mark.parametrize("index", range(len(EXAMPLES)))
def test_api_example_runs(index: int, tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-c", EXAMPLES[index]], capture_output=True, text=True,
                            timeout=300, cwd=tmp_path)
    assert result.returncode == 0, f"example {index}:\n{EXAMPLES[index]}\n{result.stdout}\n{result.stderr}"


def test_import_hilbench_alone_opens_a_bench_and_returns_arrays(tmp_path: Path) -> None:
    code = ("import hilbench; b = hilbench.Bench(target='inprocess:an1017').open(); b.run(1.0); "
            "s = b.signals(); b.close(); print(type(s['t_s']).__name__, len(s['t_s']))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["ndarray", "20000"]
