"""Golden recordings: per-column digests of recordings made with an earlier main, to prove that a
restructuring changes no recorded value.

Each case is a `hilbench run` (a real process, the packaged default config or a repository config,
a target spec, a scenario) recorded to NPZ. A column's digest is the SHA-256 of its values as
little-endian float64 (every recorded column is numeric, and float64 holds each exactly), so a
change of storage type that keeps every value keeps the digest. `recordings.json` holds the digests
and the commit they were made with; `python tests/golden/make_golden.py` writes it again (only do
that on the commit the file names, or on purpose).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO_ROOT = HERE.parent.parent
DIGESTS = HERE / "recordings.json"


@dataclass(frozen=True)
class Case:
    """One recorded run: `hilbench run [config] --target TARGET [--scenario FILE]`."""

    name: str
    target: str
    config: str | None = None  # repository-relative; None: the packaged default
    scenario: str | None = None  # repository-relative scenario file
    tools: tuple[str, ...] = ()  # system tools the target needs (gcc for sil:)
    same_as: str | None = None  # a target 730876f did not have: it must record that case's digests
    long: bool = False  # minutes on a simulator: only with HILBENCH_LONG_TESTS=1 (CI's 20-minute budget)

    @property
    def golden_name(self) -> str:
        """The case in recordings.json this one is held to."""
        return self.same_as or self.name

    def argv(self, record: Path) -> list[str]:
        argv = [sys.executable, "-m", "hilbench", "run"]
        if self.config:
            argv.append(str(REPO_ROOT / self.config))
        argv += ["--target", self.target, "--no-ui", "--no-control", "--record", str(record)]
        if not self.target.startswith("inprocess:"):  # a process starved by a loaded machine is slow, not lost
            argv += ["--set", "link.timeout_ms=10000"]  # (lockstep: the wait changes no recorded value)
        if self.scenario:
            argv += ["--scenario", str(REPO_ROOT / self.scenario)]
        return argv


RANDOM = "tests/golden/random_an1017.toml"
SERVO = "bench_configs/servo_200w.toml"
CASES: tuple[Case, ...] = (
    Case("default-inprocess", "inprocess:an1017"),
    Case("default-emulator", "emulator:an1017"),
    Case("default-sil", "sil:an1017", tools=("gcc",)),
    Case("random-inprocess", "inprocess:an1017", scenario=RANDOM),
    Case("random-emulator", "emulator:an1017", scenario=RANDOM),
    Case("random-sil", "sil:an1017", scenario=RANDOM, tools=("gcc",)),
    Case("servo-inprocess", "inprocess:foc", config=SERVO),
    Case("servo-emulator", "emulator:foc", config=SERVO),
    # the FOC firmware in C came after 730876f: its SIL build is held to the in-process servo's digests
    Case("servo-sil", "sil:foc", config=SERVO, tools=("gcc",), same_as="servo-inprocess"),
    # twin-speculative lockstep (issue 25) must record exactly what per-period lockstep records
    Case("default-sil-twin", "sil:an1017?twin=auto", tools=("gcc",), same_as="default-sil"),
    Case("random-sil-twin", "sil:an1017?twin=auto", scenario=RANDOM, tools=("gcc",), same_as="random-sil"),
    Case("servo-sil-twin", "sil:foc?twin=auto", config=SERVO, tools=("gcc",), same_as="servo-inprocess"),
    Case("default-simavr-twin", "simavr:an1017?twin=auto", tools=("avr-gcc", "simavr"), same_as="default-sil"),
    Case("random-simavr-twin", "simavr:an1017?twin=auto", scenario=RANDOM, tools=("avr-gcc", "simavr"),
         same_as="random-sil", long=True),  # 110 s here; live writes on simavr: tests/test_speculative.py
    Case("servo-simavr-twin", "simavr:foc?twin=auto", config=SERVO, tools=("avr-gcc", "simavr"),
         same_as="servo-inprocess", long=True),  # 73 s here; the servo on simavr, short: tests/test_speculative.py
    Case("default-qemu-twin", "qemu:an1017?twin=auto", tools=("arm-none-eabi-gcc", "qemu-system-arm"),
         same_as="default-sil"),
    Case("servo-qemu-twin", "qemu:foc?twin=auto", config=SERVO, tools=("arm-none-eabi-gcc", "qemu-system-arm"),
         same_as="servo-inprocess", long=True),  # 62 s here; the servo on QEMU, short: tests/test_speculative.py
)


def column_digest(values: np.ndarray) -> str:
    """SHA-256 of a column's values as little-endian float64."""
    return hashlib.sha256(np.ascontiguousarray(values, dtype="<f8").tobytes()).hexdigest()


def record(case: Case, folder: Path, timeout_s: float = 600.0) -> dict[str, str]:
    """Run a case and return {column: digest} of its recording."""
    from hilbench import read_recording

    path = folder / f"{case.name}.npz"
    done = subprocess.run(case.argv(path), capture_output=True, text=True, timeout=timeout_s, cwd=REPO_ROOT)
    if done.returncode not in (0, 9) or not path.exists():  # exit 9 (a check failed) still records
        raise AssertionError(f"{case.name}: exit {done.returncode}{'' if path.exists() else ', no recording'}: "
                             f"{done.stderr.strip()[-400:]}")
    data = read_recording(path)
    return {name: column_digest(col) for name, col in sorted(data.columns.items())}


def load_golden() -> dict[str, dict[str, str]]:
    return json.loads(DIGESTS.read_text())["cases"]
