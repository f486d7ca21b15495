"""The conformance suite (hilbench/bench/conformance.py, `hilbench conformance SPEC`, the pytest module
hilbench.testing.conformance) on every kind of target this tree builds: the Python models in
process and as emulator processes (the target kit and `serve`), the C firmwares on the runtime as
host processes (SIL), on an ATmega328P in simavr and on a Cortex-M4 in QEMU. Every check passes on
every one: the runtime and the Python kit keep the same promises.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from _firmware import require_file, require_tool
from conftest import REPO_ROOT
from hilbench.bench.conformance import CHECKS, run_checks

#: the tools each kind of target needs (tests/_firmware.py: a skip here, a failure in CI)
TOOLS = {
    "sil": (("gcc", "the SIL builds"), ("make", "the firmware Makefiles")),
    "simavr": (("avr-gcc", "the AVR builds (apt: gcc-avr avr-libc)"), ("make", "the firmware Makefiles")),
    "qemu": (("qemu-system-arm", "the Cortex-M4 target (apt: qemu-system-arm)"),
             ("arm-none-eabi-gcc", "the Cortex-M4 builds (apt: gcc-arm-none-eabi libnewlib-arm-none-eabi)"),
             ("make", "the firmware Makefiles")),
}
SIMAVR_HEADER = "/usr/include/simavr/sim_avr.h"

SPECS = [
    pytest.param("inprocess:an1017", id="inprocess-an1017"),
    pytest.param("inprocess:foc", id="inprocess-foc"),
    pytest.param("inprocess:loopback", id="inprocess-loopback"),
    pytest.param("emulator:an1017", id="emulator-an1017", marks=pytest.mark.slow),
    pytest.param("emulator:foc", id="emulator-foc", marks=pytest.mark.slow),
    pytest.param("sil:an1017", id="sil-an1017"),
    pytest.param("sil:foc", id="sil-foc"),
    pytest.param("sil:firmware/tiny", id="sil-tiny"),
    pytest.param("sil:firmware/template", id="sil-template", marks=pytest.mark.slow),
    pytest.param("simavr:an1017", id="simavr-an1017", marks=pytest.mark.slow),
    pytest.param("simavr:foc", id="simavr-foc", marks=pytest.mark.slow),
    pytest.param("simavr:firmware/tiny", id="simavr-tiny", marks=pytest.mark.slow),
    pytest.param("qemu:an1017", id="qemu-an1017", marks=pytest.mark.slow),
    pytest.param("qemu:foc", id="qemu-foc", marks=pytest.mark.slow),
]


def _require_tools(spec: str) -> None:
    kind = spec.split(":", 1)[0]
    for tool, why in TOOLS.get(kind, ()):
        require_tool(tool, why)
    if kind == "simavr":
        require_file(SIMAVR_HEADER, "libsimavr-dev", "the AVR builds run in simavr")


@pytest.mark.parametrize("spec", SPECS)
def test_every_check_passes(spec: str, monkeypatch: pytest.MonkeyPatch) -> None:
    _require_tools(spec)
    monkeypatch.chdir(REPO_ROOT)
    results = run_checks(spec)
    assert [r.name for r in results] == [name for name, _ in CHECKS]
    failed = [f"{r.name}: {r.detail}" for r in results if r.ok is not True]
    assert not failed, f"{spec}: " + "; ".join(failed)


def test_the_cli_reports_each_check_and_fails_on_a_broken_promise(tmp_path: Path) -> None:
    ok = subprocess.run([sys.executable, "-m", "hilbench", "conformance", "inprocess:loopback", "--json"],
                        capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert ok.returncode == 0, ok.stderr
    checks = json.loads(ok.stdout)["checks"]
    assert [c["status"] for c in checks] == ["PASS"] * len(CHECKS)
    assert any("UNKNOWN_ID" in c["detail"] and "all-or-nothing" in c["detail"] for c in checks)


class _SteppingTwice:
    """A fake link to a target that steps every Sensors it gets, repeats too (its Drive counts them)."""

    def __init__(self) -> None:
        from hilbench.targets.loopback.target import LoopbackTarget

        self.target = LoopbackTarget()
        self.steps = 0
        self.out: list = []

    def send(self, msg) -> None:
        from hilbench.protocol import HostHello, Sensors, Start, StatusRequest

        if isinstance(msg, HostHello):
            self.out.append(self.target.hello(msg))
        elif isinstance(msg, Sensors):
            self.steps += 1
            self.out.append(self.target.step(msg._replace(seq=self.steps & 0xFF, encoder=self.steps))._replace(seq=msg.seq))
        elif isinstance(msg, Start):
            self.target.start()
        elif isinstance(msg, StatusRequest):  # (the probe before a Start)
            self.out.append(self.target.status()._replace(seq=msg.seq))

    def recv_or_none(self, timeout_s):
        return self.out.pop(0) if self.out else None

    def reset_sequence(self) -> None:
        pass


def test_a_target_that_steps_a_repeated_seq_twice_fails() -> None:
    """The suite catches what it checks: a repeat answered with another Drive (it was stepped again)."""
    from hilbench.bench.conformance import ConformanceFailure, Wire, check_repeated_seq

    with pytest.raises(ConformanceFailure, match="repeated Sensors"):
        check_repeated_seq(Wire(_SteppingTwice(), 50))


def test_the_pytest_module_runs_on_a_target() -> None:
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--pyargs",
                             "hilbench.testing.conformance", "--hil-target", "inprocess:an1017", "-m",
                             "hil_conformance"], capture_output=True, text=True, timeout=300, cwd=REPO_ROOT / "docs")
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"{len(CHECKS)} passed" in result.stdout


@pytest.mark.parametrize("spec", ["emulator:an1017", "sil:an1017",
                                  pytest.param("simavr:an1017", marks=pytest.mark.slow)])
def test_a_stop_disarms_the_watchdog(spec: str) -> None:
    """A host that ends cleanly (Stop) and leaves is no host gone: no watchdog trip after it (the trip
    left a FAULT the next session started in, failing its no_fault check); the C runtime and the
    Python server alike. Then the next session's requests are answered at once: simavr's own sleep
    callback made the AVR wait until the wall clock caught up with the simulated time it ran ahead
    while busy in real time (~5x the time spent there: 3.3 s after 0.6 s), answering nothing
    meanwhile; the runner's sleep now lasts at most its own length (run_simavr.c)."""
    from hilbench.bench.conformance import Connection, check_stop_disarms_watchdog

    _require_tools(spec)
    conn = Connection(spec)
    try:
        assert "no trip" in check_stop_disarms_watchdog(conn.wire)
        conn.wire.handshake()  # lockstep: each answer within the suite's reply time (2 s)
        conn.wire.status()
    finally:
        conn.close()
