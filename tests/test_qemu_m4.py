"""Firmware on a simulated Cortex-M4: the MPS2 AN386 port (firmware/runtime/ports/cortex_m4) in QEMU.

The board support written here (vector table, reset code, memory map, UART0 with its receive
interrupt, the timer-0 clock) is brought up with an echo program; then each firmware built for it
(`qemu:NAME`) runs a whole `hilbench run` in lockstep over the simulated UART, and its recording
must equal the in-process target's, column for column. QEMU must not outlive its parent.
Needs (apt): qemu-system-arm, gcc-arm-none-eabi, libnewlib-arm-none-eabi, make.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from _firmware import require_tool
from hilbench import read_recording
from hilbench.targets.qemu import M4Build, build_m4, start_qemu

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
CLOCK_HZ = 25_000_000


@pytest.fixture(scope="module")
def m4_tools() -> None:
    require_tool("qemu-system-arm", "the Cortex-M4 target (apt: qemu-system-arm)")
    require_tool("arm-none-eabi-gcc", "the Cortex-M4 builds (apt: gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    require_tool("make", "the Cortex-M4 Makefile (apt: make)")


def _read(fd: int, n: int, timeout_s: float = 10.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout_s
    while len(out) < n:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            break
        out += os.read(fd, n - len(out))
    return out


def test_bring_up_echo_and_clock(m4_tools, tmp_path: Path) -> None:
    elf = build_m4(M4Build("echo", "echo_m4.elf"), tmp_path)
    master, slave = os.openpty()
    tty.setraw(slave)
    process = start_qemu(elf, os.ttyname(slave)).process
    try:
        payload = bytes(range(0, 0xFE)) * 2  # every byte value but the two clock requests, twice
        for at in range(0, len(payload), 32):  # within echo's 64-byte queue: a burst could outrun its UART
            chunk = payload[at:at + 32]
            os.write(master, chunk)
            assert _read(master, len(chunk)) == chunk, at
        os.write(master, b"\xff")
        first = int.from_bytes(_read(master, 8), "little")
        deadline = time.monotonic() + 10.0
        later = first
        while later - first < CLOCK_HZ // 10 and time.monotonic() < deadline:  # 0.1 s of the board's clock
            os.write(master, b"\xff")
            later = int.from_bytes(_read(master, 8), "little")
        assert CLOCK_HZ // 10 <= later - first < 20 * CLOCK_HZ
    finally:
        process.terminate()
        process.wait(timeout=10)
        os.close(master)
        os.close(slave)


def test_clock_counts_a_wrap_whose_interrupt_has_not_run(m4_tools, tmp_path: Path) -> None:
    """Timer 0 wraps while interrupts are masked (the wrap count cannot move yet): the 64-bit clock
    must still go forward, not step back by 2^32 ticks (171.8 s, a watchdog trip in real time)."""
    elf = build_m4(M4Build("echo", "echo_m4.elf"), tmp_path)
    master, slave = os.openpty()
    tty.setraw(slave)
    process = start_qemu(elf, os.ttyname(slave)).process
    try:
        os.write(master, b"\xfe")
        reply = _read(master, 16)
        assert len(reply) == 16, reply
        before, after = int.from_bytes(reply[:8], "little"), int.from_bytes(reply[8:], "little")
        # QEMU started a moment ago: no wrap yet before; the counter moved to 1000 ticks short of its
        # first wrap, then read just after it: the clock is past 2^32 ticks (by well under a second)
        assert before < CLOCK_HZ * 10 and (1 << 32) <= after < (1 << 32) + CLOCK_HZ, (before, after)
    finally:
        process.terminate()
        process.wait(timeout=10)
        os.close(master)
        os.close(slave)


def _record(spec: str, out: Path, seconds: float, config: str | None = None, scenario: str | None = None) -> dict:
    argv = [sys.executable, "-m", "hilbench", "run"]
    if config:
        argv.append(str(REPO / config))
    argv += ["--target", spec, "--duration", str(seconds), "--no-ui", "--no-control", "--record", str(out),
             "--set", "link.timeout_ms=10000"]  # a simulator starved by a loaded machine is slow, not lost
    if scenario:
        argv += ["--scenario", str(REPO / scenario)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=900, cwd=REPO)
    assert out.exists(), f"{spec}: no recording (exit {done.returncode}): {done.stderr.strip()[-600:]}"
    return read_recording(out).columns


def assert_same_recording(got: dict, want: dict, label: str) -> None:
    assert sorted(got) == sorted(want), label
    rows = len(next(iter(want.values())))
    assert rows > 1000, label
    changed = [name for name in want if not np.array_equal(np.asarray(got[name]), np.asarray(want[name]))]
    assert not changed, f"{label}: columns differ: {changed}"


@pytest.mark.parametrize("scenario,seconds", [(None, 0.3), ("tests/golden/random_an1017.toml", 0.8)],
                         ids=["default", "random"])
def test_qemu_an1017_records_what_inprocess_records(m4_tools, tmp_path: Path, scenario, seconds) -> None:
    want = _record("inprocess:an1017", tmp_path / "inprocess.npz", seconds, scenario=scenario)
    got = _record("qemu:an1017", tmp_path / "qemu.npz", seconds, scenario=scenario)
    assert_same_recording(got, want, "qemu:an1017")


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    with open(f"/proc/{pid}/stat") as f:  # a zombie is gone too (its parent was init's to reap)
        return f.read().split(") ", 1)[1].startswith("Z")


def test_qemu_dies_with_its_parent(m4_tools, tmp_path: Path) -> None:
    """A parent killed outright (SIGKILL: no cleanup runs) takes QEMU along (PR_SET_PDEATHSIG)."""
    elf = build_m4(M4Build("echo", "echo_m4.elf"), tmp_path)
    code = ("import sys, time\nfrom pathlib import Path\nfrom hilbench.link import open_link\n"
            "from hilbench.targets.qemu import start_qemu\n"
            "link = open_link('pty', timeout_s=5)\n"
            f"p = start_qemu(Path({str(elf)!r}), link.peer_path).process\n"
            "print(p.pid, flush=True)\ntime.sleep(600)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        qemu_pid = int(parent.stdout.readline())
        assert not _gone(qemu_pid)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10.0
        while not _gone(qemu_pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _gone(qemu_pid)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait(timeout=10)


def test_a_start_after_a_resent_request_is_taken(m4_tools, monkeypatch: pytest.MonkeyPatch) -> None:
    """A request answered late is sent again, and its twin is then still being answered by the M4 (a
    TargetHello is long) when the next frame arrives, which its receiver drops whole (Status.overruns);
    Start has no reply. RemoteTarget.start first sends StatusRequests until one is answered without a
    resend: the firmware starts each time. (Sent at once, as before, the Start was lost: this test
    failed 2 runs in 3 on a loaded machine; the conformance suite's repeated-seq check failed in CI so.)"""
    from hilbench.bench.launcher import open_target
    from hilbench.protocol import OUTPUT_OFF, Sensors

    monkeypatch.chdir(REPO)
    handle = open_target("qemu:foc", timeout_s=2.0, retry_s=0.25)
    try:
        target = handle.target
        hello = target.handshake(50)
        adc = (1 << (hello.adc_bits - 1),) * len(hello.adc_roles)
        seq = 0
        for attempt in range(12):
            target.stop()
            target.retry_s = 0.0002  # every answer late: the HostHello goes twice or more
            target.handshake(50)
            target.retry_s = 0.25
            target.start()
            modes = []
            for _ in range(40):
                seq = (seq + 1) & 0xFF
                modes.append(target.step(Sensors(seq, 0, (), 0, adc)).output_mode)
            assert any(m != OUTPUT_OFF for m in modes), f"attempt {attempt}: outputs off 40 periods after Start"
    finally:
        handle.close()
