"""Recordings equal, column for column, to those of the main they were frozen from (tests/golden).

Restructuring the bench, moving a firmware onto the C runtime or changing the protocol must not
change one recorded value: the default scenario, a scenario with live writes, faults, load, bus and
button events, and the servo, on the in-process model, the emulator process and the SIL build (the
servo's SIL build came after the digests were made: it is held to the in-process servo's).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "golden"))
from golden import CASES, Case, load_golden, record  # noqa: E402

from _firmware import require_tool  # noqa: E402

GOLDEN = load_golden()


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_recording_equals_the_golden_digests(case: Case, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    if case.long and os.environ.get("HILBENCH_LONG_TESTS") != "1":
        pytest.skip(f"{case.name}: minutes on a simulator, run with HILBENCH_LONG_TESTS=1")
    for tool in case.tools:
        if shutil.which(tool) is None:
            if tool != "gcc":
                require_tool(tool, f"the {case.target} build")
            request.getfixturevalue(tool)  # skips, or fails under HILBENCH_REQUIRE_GCC=1
    got = record(case, tmp_path)
    want = GOLDEN[case.golden_name]
    missing = sorted(set(want) - set(got))
    changed = sorted(name for name in want if name in got and got[name] != want[name])
    assert not missing, f"{case.name}: columns gone: {missing}"
    assert not changed, f"{case.name}: columns changed: {changed}"
