"""Issue 24: a host killed in real time: the firmware turns its outputs off within its watchdog time
(the SIL build and the AVR build in simavr, on their ptys, the host a `hilbench run` process).

The host is SIGKILLed mid-run (no Stop, nothing sent), the test opens the same pty at once and
waits for the firmware's unsolicited Drive that reports the trip: outputs OFF, state FAULT, fault
WATCHDOG. It must come no earlier than the firmware could know (none before the kill: the host ran
with no trip) and within the watchdog time after the host's last frame, plus the stand-in's
scheduling slack. simavr runs with --realtime (its simulated time paced to the wall clock, as a
chip's is; unpaced it ran 1.2-3.4x faster than the wall clock and the host's frames, moved by its
pty thread, fell so far behind that the watchdog tripped before the kill); the bound is still the
watchdog time divided by the simulator's speed over the run (its cycles over the wall time: at
most 1 when paced, less when the machine cannot keep up).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _firmware import require_tool
from hilbench.link.link import Link
from hilbench.link.transport import FdTransport
from hilbench.processes import reap, spawn
from hilbench.protocol import Drive
from test_board_guide import _start

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
#: longer than the stalls a loaded 2-CPU machine gives a Python host (tens of ms), so the kill trips it
WATCHDOG_MS = 300
AVR_WATCHDOG_MS = WATCHDOG_MS
OUTPUT_OFF, STATE_FAULT, FAULT_WATCHDOG = 0, 4, 1
#: the stand-in process may be descheduled on a loaded machine; the SIL's poll loop itself is 1 ms
SLACK_S = 0.25
AVR_F_CPU = 16_000_000


def _host(port: str, period_us: int, watchdog_ms: int) -> subprocess.Popen[bytes]:
    return spawn([sys.executable, "-m", "hilbench", "run", "--target", port, "--mode", "realtime", "--no-ui",
                  "--no-control", "--set", "run.duration_s=60", "--set", f"link.period_us={period_us}",
                  "--set", f"link.watchdog_ms={watchdog_ms}", "--set", "link.timeout_ms=5000"],
                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)


def _listen(port: str) -> Link:
    """A second reader of the stand-in's pty (the host holds its exclusive lock), opened with a plain
    open(): pyserial's open flushes the input, and a trip's Drive queued between the kill and this
    open was thrown away with it (no Drive in 10 s, once in a loaded full suite). The stand-in made
    its pty raw."""
    device = port.split(":", 1)[1].split("?")[0]
    fd = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    return Link(FdTransport(fd, device, owns_fd=True), device)


def _tail(host: subprocess.Popen[bytes]) -> str:
    """The end of a finished host's output (its summary or its error line), for a failure's message."""
    try:
        out, err = host.communicate(timeout=10)
    except subprocess.TimeoutExpired:  # a grandchild holding its pipes: the failure's own message stands
        return "(its output not read: its pipes still open after 10 s)"
    return (out[-400:] + err[-400:]).decode(errors="replace")


def _kill_and_watch(port: str, period_us: int, run_s: float, watchdog_ms: int) -> tuple[Drive, float]:
    """Run the host run_s seconds, SIGKILL it: the trip's Drive and its delay (s). The test opens
    the port just before the kill (a second reader for a few ms), so that a simulator running faster
    than the wall clock cannot send the trip before anyone listens."""
    host = _host(port, period_us, watchdog_ms)
    link = None
    try:
        try:
            host.wait(timeout=run_s)
        except subprocess.TimeoutExpired:
            pass  # still running after run_s: the stimulus
        assert host.poll() is None, (host.stderr.read() if host.stderr else b"")[-800:]
        link = _listen(port)
        drain_until = time.monotonic() + 0.05
        while time.monotonic() < drain_until:  # a trip already latched: the host stalled, not the kill
            msg = link.recv_or_none(max(0.0, drain_until - time.monotonic()))
            assert not (isinstance(msg, Drive) and msg.fault == FAULT_WATCHDOG), "tripped before the kill"
        os.kill(host.pid, signal.SIGKILL)
        host.wait(timeout=30)
        killed_at = time.monotonic()
        assert host.returncode == -signal.SIGKILL, \
            f"the host ended before the kill (exit {host.returncode}): {_tail(host)}"
        # the two readers split frames between them: this decoder may hold the head of a frame whose
        # tail the host took, which would merge with the trip's Drive into one bad frame. A fresh
        # reader starts at nothing; a tail still pending ends in a delimiter and is one dropped frame.
        # It opens before the old one closes: the pty's last close would flush its input (a trip's
        # Drive queued in that moment lost).
        fresh = _listen(port)
        link.close()
        link = fresh
        deadline = killed_at + 10.0
        seen = []
        while time.monotonic() < deadline:
            msg = link.recv_or_none(max(0.0, deadline - time.monotonic()))
            if isinstance(msg, Drive) and msg.fault == FAULT_WATCHDOG:
                return msg, time.monotonic() - killed_at
            if msg is not None:
                seen.append(msg)
        pytest.fail(f"no watchdog Drive within 10 s after the host was killed; received {seen[-5:]}, "
                    f"link {link.stats}; the host said: {_tail(host)}")
    finally:
        if link is not None:
            link.close()
        reap(host)


def test_sil_turns_outputs_off_when_the_realtime_host_is_killed() -> None:
    require_tool("gcc", "the SIL firmware (apt: gcc)")
    sil, pty = _start([sys.executable, "-m", "hilbench.targets.sil"])
    try:
        drive, delay_s = _kill_and_watch(f"serial:{pty}", 1000, 2.0, WATCHDOG_MS)
    finally:
        reap(sil, 10.0)
    print(f"\nSIL: outputs off {delay_s * 1000:.0f} ms after the host was killed (watchdog {WATCHDOG_MS} ms)")
    assert (drive.output_mode, drive.state, drive.fault) == (OUTPUT_OFF, STATE_FAULT, FAULT_WATCHDOG)
    assert delay_s <= WATCHDOG_MS / 1000 + SLACK_S


def test_avr_in_simavr_turns_outputs_off_when_the_realtime_host_is_killed(tmp_path: Path) -> None:
    require_tool("avr-gcc", "the AVR stand-in (apt: gcc-avr avr-libc)")
    require_tool("simavr", "the AVR stand-in (apt: simavr libsimavr-dev libsimavrparts1)")
    build = subprocess.run(["make", "-s", "-C", str(REPO / "firmware/an1017/ports/avr"), f"OUT={tmp_path}"],
                           capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    log = tmp_path / "run_simavr.err"
    with log.open("wb") as err:
        simavr, pty = _start([str(tmp_path / "run_simavr"), "--realtime", str(tmp_path / "an1017_avr_seed.elf")],
                              stderr=err)
        started = time.monotonic()
        try:
            drive, delay_s = _kill_and_watch(f"serial:{pty}?baud=250000", 2600, 3.0, AVR_WATCHDOG_MS)
        finally:
            simavr.send_signal(signal.SIGTERM)
            simavr.wait(timeout=30)  # it prints its cycle count on the way out
            wall_s = time.monotonic() - started
            reap(simavr, 10.0)
    cycles = re.search(r"^cycles (\d+)$", log.read_text(), re.M)
    assert cycles, log.read_text()
    speed = int(cycles.group(1)) / AVR_F_CPU / wall_s  # simulated seconds per wall second, on average
    bound_s = AVR_WATCHDOG_MS / 1000 / speed + SLACK_S
    print(f"\nAVR in simavr: outputs off {delay_s * 1000:.0f} ms (wall) after the host was killed; watchdog "
          f"{AVR_WATCHDOG_MS} ms of simulated time, simavr at {speed:.2f}x real time: bound {bound_s * 1000:.0f} ms")
    assert (drive.output_mode, drive.state, drive.fault) == (OUTPUT_OFF, STATE_FAULT, FAULT_WATCHDOG)
    assert delay_s <= bound_s
