"""Issue 24: the dsPIC30F2010's board profile (`make PROFILE=lockstep`, that chip's default; docs/board.md
"Does it fit") run end to end. No dsPIC runs here, so the profile's runtime defines, read from the
port's Makefile (`make -n size`), build the same firmware and runtime sources for the host (SIL, on a
pty) and for the ATmega328P in simavr: their lockstep Drives and parameter replies equal the Python
model's, a whole bench session records what the model records, a killed host in lockstep gets the
outputs turned off, and what the profile leaves out (real time, batches, prediction, the
self-description beyond the HELLO, ParamDescribe included) is refused as the protocol says, the host
carrying on without it (the parameters described by the registered profile's model).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest

from _firmware import play, random_stream, require_file, require_tool
from hilbench.errors import HilbenchError, ParamError
from hilbench.link.pty import open_pty_pair
from hilbench.protocol import (
    MODE_LOCKSTEP,
    MODE_PREDICT,
    MODE_REALTIME,
    OUTPUT_OFF,
    PROTOCOL_VERSION,
    RESULT_OK,
    ErrorCode,
    ErrorReport,
    HostHello,
    ParamDescribe,
    ParamInfo,
)
from hilbench.targets.an1017.firmware import An1017Options
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.sil import FIRMWARE_DIR, SilTarget, build_avr, build_sil, start_sil, stop_sil
from hilbench.targets.starters import SimavrStarter, start_process
from test_firmware_sil import run_recording
from test_watchdog_kill import LOCKSTEP_FLOOR_S, _trip_after_kill

pytestmark = pytest.mark.slow

PORT = FIRMWARE_DIR / "ports" / "dspic30f2010"


def port_defines(*make_args: str) -> tuple[str, ...]:
    """The runtime and protocol defines (-DHRT_*, -DHBP_*) the dsPIC Makefile builds with, but the port's
    own HRT_PORT_HW (the host and AVR ports are not hardware ports)."""
    require_tool("make", "the dsPIC Makefile (apt: make)")
    done = subprocess.run(["make", "-s", "-n", "--no-print-directory", "-C", str(PORT), "size", *make_args],
                          capture_output=True, text=True, timeout=60, check=True)
    return tuple(f for f in shlex.split(done.stdout) if re.match(r"-D(HRT|HBP)_", f) and
                 not f.startswith("-DHRT_PORT_HW"))


@pytest.fixture(scope="module")
def profile() -> tuple[str, ...]:
    return port_defines()


@pytest.fixture(scope="module")
def profile_sil(tmp_path_factory, gcc: str, profile: tuple[str, ...]) -> Path:
    return build_sil(tmp_path_factory.mktemp("sil_profile"), defines=profile)


def test_the_profile_is_the_30f2010s_and_leaves_real_time_out(profile: tuple[str, ...]) -> None:
    assert "-DHRT_REALTIME=0" in profile, profile
    assert {"-DHRT_SPECULATE=0", "-DHRT_PREDICT_BYTES=0u", "-DHRT_DESCRIBE=0"} <= set(profile), profile
    assert "-DHRT_REALTIME=0" not in port_defines("DEVICE=30F4012")  # the 48 KB part: PROFILE=full
    assert "-DHRT_REALTIME=0" not in port_defines("PROFILE=full")


@pytest.mark.parametrize("variant,seed,period_us", [("seed", 11, 50), ("v11", 12, 50), ("seed", 13, 1000)])
def test_profile_sil_drive_for_drive_equals_python_model(profile_sil: Path, variant: str, seed: int,
                                                          period_us: int) -> None:
    with SilTarget.open(variant, exe=profile_sil) as sil:
        model = An1017Target(An1017Options(variant=variant))
        periods = 20000 if period_us == 50 else 6000
        n, seen = play(random_stream(seed, periods, period_us), [model, sil.target], period_us)
        assert n in (periods, periods + 1)
        assert {1, 2} <= {state for state, _, _ in seen}, seen


def test_profile_sil_session_recording_identical_to_python_model(profile_sil: Path, tmp_path: Path) -> None:
    """The default scenario with live parameter writes, through the bench: the session asks for
    PREDICT (refused, plain lockstep), TargetDescribe (refused: the registry's profile serves) and the
    parameters; every column equals the in-process model's."""
    expected = run_recording(tmp_path, "inprocess:an1017", "model", ())
    pair = open_pty_pair()
    process = start_sil(pair.slave_path, "seed", exe=profile_sil)
    try:
        os.close(pair.slave_fd)
        got = run_recording(tmp_path, f"fd:{pair.master_fd}", "sil", ())
    finally:
        stop_sil(process)
    header = expected[0].split(",")
    for i, (a, b) in enumerate(zip(expected, got)):
        assert a == b, (i, header, a, b)
    assert len(got) == len(expected) > 70000


def test_profile_refuses_what_it_leaves_out(profile_sil: Path) -> None:
    """Real time and PREDICT are refused at the HELLO (BAD_REQUEST); TargetDescribe and ParamDescribe
    answer BAD_REQUEST: the host has no TargetInfo, and the registered profile's model describes the
    parameters, with the values the firmware's ParamGet gives (after a write too)."""
    with SilTarget.open("seed", exe=profile_sil) as sil:
        t = sil.target
        for mode in (MODE_REALTIME, MODE_PREDICT):
            with pytest.raises(HilbenchError, match="BAD_REQUEST"):
                t.hello(HostHello(0, PROTOCOL_VERSION, 50, mode, 100))
        assert t.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 100)).firmware_name == "AN1017"
        assert t.describe_target() is None
        refused = t._request(ParamDescribe(t._next_seq(), 0), ParamInfo)
        assert type(refused) is ErrorReport and refused.code == ErrorCode.BAD_REQUEST, refused
        assert t.set_params(((4, 25),)).result == RESULT_OK
        model = An1017Target(An1017Options(variant="seed"))
        assert model.set_params(((4, 25),)).result == RESULT_OK
        assert [t.describe(i)[1:] for i in range(8)] == [model.describe(i)[1:] for i in range(8)]
        with pytest.raises(ParamError):
            t.describe(8)


def _profile_avr(profile: tuple[str, ...]):
    require_tool("avr-gcc", "the AVR build of the firmware (apt: gcc-avr avr-libc)")
    require_file("/usr/include/simavr/sim_avr.h", "libsimavr-dev", "the AVR build runs in simavr")
    return SimavrStarter(lambda options: build_avr("seed", profile), name="an1017-profile").start(None, None)


@pytest.mark.parametrize("where", ["sil", "simavr"])
def test_profile_killed_host_in_lockstep_gets_the_outputs_turned_off(where: str, profile: tuple[str, ...],
                                                                      profile_sil: Path) -> None:
    """As tests/test_watchdog_kill.py, lockstep (the profile's only mode), on the profile's builds."""
    firmware = start_process([str(profile_sil), "--pty"], "sil:an1017 profile --pty") if where == "sil" \
        else _profile_avr(profile)
    try:
        waited, trip, status = _trip_after_kill(firmware, MODE_LOCKSTEP)
    finally:
        firmware.close()
    assert trip.output_mode == OUTPUT_OFF, trip
    assert status.watchdog_trips == 1, status
    if where == "sil":
        assert waited >= LOCKSTEP_FLOOR_S * 0.9, f"tripped {waited * 1000:.0f} ms after the kill"


def test_profile_avr_in_simavr_drive_for_drive_on_a_seeded_stream(profile: tuple[str, ...]) -> None:
    from hilbench.link import open_link
    from hilbench.targets.remote import RemoteTarget

    firmware = _profile_avr(profile)
    try:
        link = open_link(firmware.tty_path, timeout_s=2.0)
        try:
            avr = RemoteTarget(link, timeout_s=2.0)
            model = An1017Target(An1017Options(variant="seed"))
            n, seen = play(random_stream(5, 1500, 1000), [model, avr], 1000)
            assert n >= 1500 and {1, 2} <= {state for state, _, _ in seen}, seen
            status = avr.status()
            assert status.rx_errors == 0 and status.overruns <= avr.retries, (status, avr.retries)
        finally:
            link.close()
    finally:
        firmware.close()
