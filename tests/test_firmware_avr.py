"""Issue 12, 16-bit MCU in the loop: the AN1017 firmware built with avr-gcc, run in simavr.

The same firmware, runtime and C library as the SIL and dsPIC builds, for an ATmega328P (16-bit int,
2 KB RAM, no FPU), executed instruction by instruction by simavr with USART0 on a pty at 250 kbaud.
The bench drives it in lockstep over that serial line through a whole default-scenario session of
2 simulated seconds (1 ms periods: the simulated UART carries ~35 bytes per exchange) and its
recording must equal the in-process Python model's, every column, with zero frame errors.
Needs: gcc-avr + avr-libc (build), simavr + libsimavr-dev + libsimavrparts1 (the runner).
"""

from __future__ import annotations

import os
import re
import select
import subprocess
import time
from pathlib import Path

import pytest

from _firmware import play, random_stream, require_file, require_tool
from conftest import BENCH_CONFIGS
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.link import open_link
from hilbench.processes import spawn
from hilbench.targets.an1017.firmware import An1017Options
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.remote import RemoteTarget
from hilbench.targets.sil import FIRMWARE_DIR, PROTOCOL_DIR, RUNTIME_DIR

pytestmark = pytest.mark.slow

AVR_DIR = FIRMWARE_DIR / "ports" / "avr"
STRICT = ("-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror")
AVR_FLAGS = ("-mmcu=atmega328p", "-DF_CPU=16000000UL", "-Os", "-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u",
             "-DHBP_MAX_EDGES=3u",
             "-DAN1017_VARIANT=AN1017_VARIANT_SEED", f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}", f"-I{PROTOCOL_DIR}")
ATMEGA328P_RAM_BYTES = 2048


@pytest.fixture(scope="module")
def avr_gcc() -> str:
    return require_tool("avr-gcc", "the AVR build of the firmware (apt: gcc-avr avr-libc)")


@pytest.fixture(scope="module")
def avr_build(tmp_path_factory, avr_gcc: str, gcc: str) -> Path:
    require_tool("make", "the AVR build's Makefile (apt: make)")
    require_tool("simavr", "running the AVR build (apt: simavr)")
    require_file("/usr/include/simavr/parts/uart_pty.h", "libsimavr-dev", "the simavr runner with a UART pty")
    out = tmp_path_factory.mktemp("avr")
    result = subprocess.run(["make", "-C", str(AVR_DIR), f"OUT={out}", "VARIANT=seed"], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return out


@pytest.mark.parametrize("source", [FIRMWARE_DIR / "an1017.c", RUNTIME_DIR / "hrt.c", RUNTIME_DIR / "hrt_link.c",
                                    PROTOCOL_DIR / "hbp.c", PROTOCOL_DIR / "hbp_messages.c", AVR_DIR / "main.c"],
                         ids=lambda p: p.name)
def test_avr_gcc_strict_flags_16bit_int(avr_gcc: str, tmp_path: Path, source: Path) -> None:
    result = subprocess.run([avr_gcc, *STRICT, *AVR_FLAGS, "-c", str(source), "-o", str(tmp_path / "x.o")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


def start_simavr(build: Path) -> tuple[subprocess.Popen[bytes], str]:
    process = spawn([str(build / "run_simavr"), str(build / "an1017_avr_seed.elf")],  # dies with the test run
                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None
    fd = process.stdout.fileno()
    seen = b""
    deadline = time.monotonic() + 10.0
    while b"ready " not in seen or not seen.split(b"ready ", 1)[1].count(b"\n"):
        left = deadline - time.monotonic()
        ready, _, _ = select.select([fd], [], [], max(left, 0.0))
        chunk = os.read(fd, 4096) if ready else b""
        if not chunk:
            process.kill()
            process.wait(timeout=5)
            raise AssertionError(f"run_simavr printed no ready line: {seen!r}")
        seen += chunk
    return process, seen.split(b"ready ", 1)[1].split(b"\n", 1)[0].decode().strip()


def stop_simavr(process: subprocess.Popen[bytes]) -> str:
    """SIGTERM, wait (kill if it will not go), and return its stderr."""
    process.terminate()
    try:
        _, err = process.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        _, err = process.communicate(timeout=10)
    return err.decode(errors="replace")


def run_recording(tmp_path: Path, spec: str, name: str):
    cfg = load_run_config(RunRequest(str(BENCH_CONFIGS / "hurst_mclv.toml"), target=spec, duration_s=2.0,
                                     overrides=("link.period_us=1000", "link.timeout_ms=2000",
                                                "link.predict_duties=false")))  # as the model: no prediction
    out = tmp_path / f"{name}.csv"
    summary = run_bench(cfg, record=out)
    return [ln for ln in out.read_text().splitlines() if not ln.startswith("# ")], summary


def test_avr_in_simavr_holds_a_lockstep_session_equal_to_the_python_model(avr_build: Path, tmp_path: Path,
                                                                           capsys) -> None:
    expected, _ = run_recording(tmp_path, "inprocess:an1017", "model")
    process, pty_path = start_simavr(avr_build)
    try:
        got, summary = run_recording(tmp_path, pty_path, "avr")
    finally:
        stderr = stop_simavr(process)
    assert len(expected) == 2001  # header + 2 s of 1 ms periods
    header = expected[0].split(",")
    for i, (a, b) in enumerate(zip(expected, got)):
        assert a == b, (i, header, a, b)
    assert len(got) == len(expected)
    link = summary.link
    assert link.get("frames_rx", 0) >= 2000, link
    assert sum(link.get(k, 0) for k in ("crc_errors", "cobs_errors", "length_errors", "timeouts")) == 0, link
    # the motor ran: the recording reaches the ramp's speed
    speeds = [float(row.split(",")[header.index("speed_rpm[rpm]")]) for row in got[1:]]
    assert max(speeds) > 1000.0
    # RAM: static (avr-size data + bss) + the stack simavr measured, against the ATmega328P's 2 KB
    match = re.search(r"stack_bytes (\d+)", stderr)
    assert match, stderr
    size = subprocess.run(["avr-size", str(avr_build / "an1017_avr_seed.elf")], capture_output=True, text=True,
                          timeout=30, check=True).stdout.splitlines()[1].split()
    data, bss, stack = int(size[1]), int(size[2]), int(match.group(1))
    with capsys.disabled():
        print(f"\nAVR (ATmega328P) RAM: static {data + bss} B (data {data} + bss {bss}) + stack {stack} B measured "
              f"in simavr = {data + bss + stack} of {ATMEGA328P_RAM_BYTES} B")
    assert data + bss + stack < ATMEGA328P_RAM_BYTES


def assert_drive_for_drive(pty_path: str) -> None:
    """The AVR build on ``pty_path`` against the seed model: every Drive field (directions included)
    and every parameter reply, on a seeded random stream."""
    link = open_link(pty_path, timeout_s=2.0)
    try:
        avr = RemoteTarget(link, timeout_s=2.0)
        model = An1017Target(An1017Options(variant="seed"))
        n, seen = play(random_stream(5, 1500, 1000), [model, avr], 1000)
        assert n >= 1500 and {1, 2} <= {state for state, _, _ in seen}, seen
        status = avr.status()
        # a frame the host sent again (no answer within retry_s: simavr slowed by a loaded machine)
        # may arrive while the firmware still handles the first: dropped whole, counted as an
        # overrun. Never more overruns than retries, and no receive error at all.
        assert status.rx_errors == 0 and status.overruns <= avr.retries, (status, avr.retries)
    finally:
        link.close()


def test_avr_in_simavr_drive_for_drive_on_a_seeded_stream(avr_build: Path) -> None:
    process, pty_path = start_simavr(avr_build)
    try:
        assert_drive_for_drive(pty_path)
    finally:
        stop_simavr(process)
