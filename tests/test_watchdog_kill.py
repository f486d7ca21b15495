"""A host killed, in lockstep and in real time: the firmware turns its outputs off within the watchdog time (issues
24, 27). The firmware serves its own tty as a board does on a serial port (the SIL build with
--pty, the AVR build in simavr's UART pty), so it outlives the host; a host process agrees lockstep
or real time with a watchdog, starts the motor and exchanges periods until this test kills it with SIGKILL.
Then the test reads what the firmware sent on the tty: the Drives the host left unread, then one
unsolicited Drive with the outputs OFF and fault WATCHDOG, and Status counts one trip. In lockstep
the watchdog time is at least the runtime's HRT_LOCKSTEP_WATCHDOG_MIN_MS (1 s); in real time it is
the agreed watchdog_ms.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time

import pytest

from _firmware import require_file, require_tool
from hilbench.link import open_link
from hilbench.processes import spawn
from hilbench.protocol import FAULT_WATCHDOG, MODE_LOCKSTEP, MODE_REALTIME, OUTPUT_OFF, Drive, Status, StatusRequest
from hilbench.targets.registry import get_profile
from hilbench.targets.starters import Started, start_process

WATCHDOG_MS = 100
LOCKSTEP_FLOOR_S = 1.0  # HRT_LOCKSTEP_WATCHDOG_MIN_MS
WAIT_S = LOCKSTEP_FLOOR_S + 10.0  # how long the test waits for the trip (a deadline, not a figure)

#: the host: lockstep or real time (argv[3]) with a watchdog, Start, then periods with S2 released until killed
HOST = r"""
import sys
from hilbench.link import open_link
from hilbench.protocol import PROTOCOL_VERSION, MODE_LOCKSTEP, Drive, HostHello, Sensors, Start, TargetHello
link = open_link(sys.argv[1], timeout_s=2.0)
link.send(HostHello(1, PROTOCOL_VERSION, 50, int(sys.argv[3]), int(sys.argv[2])))
assert type(link.recv_or_none(10.0)) is TargetHello
link.reset_sequence()
link.send(Start(2))
k, on = 0, 0
while True:
    k += 1
    msg = Sensors(k & 0xFF, 0b001, (), 0, (700, 512, 512))
    link.send(msg)
    d = None
    while not (type(d) is Drive and d.seq == msg.seq):
        d = link.recv_or_none(0.5)
        if d is None:
            link.send(msg)
    if d.output_mode != 0:
        on += 1
    elif on or k % 50 == 0:  # stopped (this host stalled past the watchdog on a loaded machine): again
        on = 0
        link.send(Start(k & 0xFF))  # (only Sensors are sequenced)
    if on == 200:
        print("running", flush=True)
"""
#: how long the test waits for the host's 200 periods with the outputs on (a deadline, not a figure)
RUNNING_WAIT_S = 120.0


def _sil_on_own_pty() -> Started:
    require_tool("gcc", "the SIL build of the AN1017 firmware")
    require_tool("make", "the firmware Makefiles")
    profile = get_profile("an1017")
    starter = profile.starters["sil"]
    exe = starter.build(profile.default_options())  # type: ignore[attr-defined]
    return start_process([str(exe), "--pty"], "sil:an1017 --pty")


def _avr_in_simavr() -> Started:
    require_tool("avr-gcc", "the AVR build of the firmware (apt: gcc-avr avr-libc)")
    require_tool("make", "the firmware Makefiles")
    require_file("/usr/include/simavr/sim_avr.h", "libsimavr-dev", "the AVR build runs in simavr")
    profile = get_profile("an1017")
    return profile.starters["simavr"].start(profile.default_options(), None)


def _trip_after_kill(firmware: Started, mode: int) -> tuple[float, Drive, Status]:
    host = spawn([sys.executable, "-c", HOST, firmware.tty_path, str(WATCHDOG_MS), str(mode)], stdout=subprocess.PIPE,
                 stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        assert host.stdout is not None
        ready, _, _ = select.select([host.stdout], [], [], RUNNING_WAIT_S)
        line = host.stdout.readline() if ready else b""  # the motor runs: outputs on for 200 periods
        if line != b"running\n":
            host.kill()
            detail = host.stderr.read().decode(errors="replace")[-2000:] if host.stderr else ""
            pytest.fail(f"the host did not run 200 periods with the outputs on in {RUNNING_WAIT_S:.0f} s: {line!r} {detail}")
        os.kill(host.pid, signal.SIGKILL)
        killed_at = time.monotonic()
    finally:
        host.kill()
        host.wait(timeout=10)
    link = open_link(firmware.tty_path, timeout_s=2.0)
    try:
        deadline = killed_at + WAIT_S
        trip = None
        while trip is None and (remaining := deadline - time.monotonic()) > 0:
            msg = link.recv_or_none(remaining)
            if type(msg) is Drive and msg.fault == FAULT_WATCHDOG:
                trip = msg
        waited = time.monotonic() - killed_at
        assert trip is not None, f"no watchdog Drive {WAIT_S:.0f} s after the host was killed"
        link.reset_sequence()
        link.send(StatusRequest(9))
        status = None
        while type(status) is not Status:
            status = link.recv_or_none(5.0)
            assert status is not None, "no Status after the trip"
        return waited, trip, status
    finally:
        link.close()


def assert_outputs_off(where: str, waited: float, trip: Drive, status: Status, limit_s: float) -> None:
    """The watchdog's trip after the kill: outputs off, one trip counted, and on the SIL (whose clock
    is the host's) not before the watchdog time."""
    assert trip.output_mode == OUTPUT_OFF, trip
    assert status.watchdog_trips == 1, status
    if where == "sil":
        assert waited >= limit_s * 0.9, f"tripped {waited * 1000:.0f} ms after the kill"


@pytest.mark.slow
@pytest.mark.parametrize("mode", [MODE_LOCKSTEP, MODE_REALTIME], ids=["lockstep", "realtime"])
@pytest.mark.parametrize("where", ["sil", "simavr"])
def test_a_killed_host_gets_the_outputs_turned_off(where: str, mode: int) -> None:
    firmware = _sil_on_own_pty() if where == "sil" else _avr_in_simavr()
    try:
        waited, trip, status = _trip_after_kill(firmware, mode)
    finally:
        firmware.close()
    limit_s = LOCKSTEP_FLOOR_S if mode == MODE_LOCKSTEP else WATCHDOG_MS / 1000
    assert_outputs_off(where, waited, trip, status, limit_s)
    print(f"{where}: outputs off {waited * 1000:.0f} ms after SIGKILL (watchdog {limit_s * 1000:.0f} ms)")
