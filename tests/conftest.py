"""Shared test fixtures.

HILBENCH_REQUIRE_GCC=1 (set by .ci/run) turns "gcc not found" from a skip into a failure, so CI
can never pass by silently skipping the C side of the protocol.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
FIRMWARE_DIR = REPO_ROOT / "firmware_protocol"
BENCH_CONFIGS = REPO_ROOT / "bench_configs"
sys.path.insert(0, str(FIRMWARE_DIR / "vectors"))  # reference_codec: the independent CRC and COBS


@pytest.fixture
def tmpdir_short() -> Iterator[Path]:
    """A fresh folder under /tmp, removed after the test: a socket's path must stay under AF_UNIX's
    ~107 bytes and another user must be able to reach it once opened up (pytest's tmp_path may be
    longer and sits in a 0700 folder)."""
    folder = Path(tempfile.mkdtemp(prefix="hbt-"))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="session")
def gcc() -> str:
    """Path to gcc; skips locally without it, fails under HILBENCH_REQUIRE_GCC=1."""
    path = shutil.which("gcc")
    if path is None:
        if os.environ.get("HILBENCH_REQUIRE_GCC") == "1":
            pytest.fail("gcc is required (HILBENCH_REQUIRE_GCC=1) but was not found on PATH")
        pytest.skip("gcc not found")
    return path


@pytest.fixture(scope="session")
def sil_builds(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder for the session's SIL builds: `build_sil(sil_builds, defines=...)` compiles a set of
    sources, flags and defines once (its file name is their digest) however many tests ask for it."""
    return tmp_path_factory.mktemp("sil_builds")


def run_cli(*args: str, timeout: float = 60.0, input_text: str | None = None) -> subprocess.CompletedProcess[str]:
    """Run `python -m hilbench ARGS` as a real process and reap it."""
    return subprocess.run(
        [sys.executable, "-m", "hilbench", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        input=input_text,
        cwd=REPO_ROOT,
    )


def hurst_bench_config(tmp_path: Path, duration_s: float, seed: int = 7) -> Path:
    """The Hurst bench with a hold scenario: the pot at 1000 rpm, S2 at 10 ms, run for duration_s."""
    text = (BENCH_CONFIGS / "hurst_mclv.toml").read_text()
    text += f"""
[run]
duration_s = {duration_s}
seed = {seed}

[[scenario]]
at_s = 0.0
ref_rpm = 1000.0

[[scenario]]
at_s = 0.01
press = "s2"
"""
    path = tmp_path / "hold.toml"
    path.write_text(text)
    return path


def _require_compiled(what: str, backends: tuple[str, ...]) -> bool:
    """True when a compiled core is built; under HILBENCH_REQUIRE_GCC=1 its absence fails."""
    if "c" in backends:
        return True
    if os.environ.get("HILBENCH_REQUIRE_GCC") == "1":
        pytest.fail(f"the compiled {what} core is not built (HILBENCH_REQUIRE_GCC=1): install with pip install -e .")
    return False


def require_c_plant() -> bool:
    """The compiled plant core (hilbench/plant/_plantcore.c)."""
    from hilbench.plant.model import available_backends

    return _require_compiled("plant", available_backends())


def require_c_an1017() -> bool:
    """The compiled AN1017 firmware core (hilbench/targets/an1017/_core.c)."""
    from hilbench.targets.an1017.target import available_backends

    return _require_compiled("AN1017", available_backends())
