"""Issue 24: the dsPIC30F2010's board profile (`make PROFILE=lockstep`, that chip's default; docs/board.md
"Does it fit") run end to end. No dsPIC runs here, so the profile's runtime defines, read from the
port's Makefile (`make -n size`), build the same firmware and runtime sources for the host (SIL, on a
pty) and for the ATmega328P in simavr: their lockstep Drives and parameter replies equal the Python
model's, a whole bench session records what the model records, a killed host in lockstep gets the
outputs turned off, and what the profile leaves out (real time, batches, prediction, the
self-description beyond the HELLO, ParamDescribe included) is refused as the protocol says (the
detail of a refused request: its type), the host carrying on without it (the parameters described by
the registered profile's model, only for a build whose HELLO is the model's: a renamed firmware or
another version is refused), and `hilbench conformance` reports it "not served", no failure.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from _firmware import play, port_defines, random_stream, require_file, require_tool
from hilbench.errors import HilbenchError, ParamError, TargetError
from hilbench.link.pty import open_pty_pair
from hilbench.protocol import (
    MODE_LOCKSTEP,
    MODE_PREDICT,
    MODE_REALTIME,
    PROTOCOL_VERSION,
    RESULT_OK,
    SCHEMA_FINGERPRINT,
    ErrorCode,
    ErrorReport,
    HostHello,
    ParamDescribe,
    ParamInfo,
    TargetDescribe,
    TelemetryDescribe,
)
from hilbench.targets.an1017.firmware import An1017Options
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.sil import SilTarget, build_avr, build_sil, start_sil, stop_sil
from hilbench.targets.starters import SimavrStarter, start_process
from test_firmware_sil import run_recording
from test_firmware_avr import assert_drive_for_drive
from test_watchdog_kill import LOCKSTEP_FLOOR_S, _trip_after_kill, assert_outputs_off

pytestmark = pytest.mark.slow

@pytest.fixture(scope="module")
def profile() -> tuple[str, ...]:
    return port_defines()


@pytest.fixture(scope="module")
def profile_sil(sil_builds: Path, gcc: str, profile: tuple[str, ...]) -> Path:
    return build_sil(sil_builds, defines=profile)


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
        for seq, mode in ((1, MODE_REALTIME), (2, MODE_PREDICT)):
            with pytest.raises(HilbenchError, match="BAD_REQUEST"):
                t.hello(HostHello(0, PROTOCOL_VERSION, 50, mode, 100))
            sil.link.send(HostHello(seq, PROTOCOL_VERSION, 50, mode, 100))  # PROTOCOL.md: a refused mode, detail 0
            assert sil.link.recv(2.0) == ErrorReport(seq, ErrorCode.BAD_REQUEST, 0, SCHEMA_FINGERPRINT)
        assert t.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 100)).firmware_name == "AN1017"
        assert t.describe_target() is None
        for request in (ParamDescribe(t._next_seq(), 0), TelemetryDescribe(t._next_seq(), 0),
                        TargetDescribe(t._next_seq())):  # PROTOCOL.md: detail = the request's type
            refused = t._request(request, ParamInfo)
            assert refused == ErrorReport(request.seq, ErrorCode.BAD_REQUEST, int(request.TYPE),
                                          SCHEMA_FINGERPRINT), refused
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
    assert_outputs_off(where, waited, trip, status, LOCKSTEP_FLOOR_S)


def test_profile_avr_in_simavr_drive_for_drive_on_a_seeded_stream(profile: tuple[str, ...]) -> None:
    firmware = _profile_avr(profile)
    try:
        assert_drive_for_drive(firmware.tty_path)
    finally:
        firmware.close()


@pytest.mark.parametrize("define,refusal", [
    ('-DAN1017_FIRMWARE_NAME="AN1017X"', "target 'AN1017X' does not describe its parameters (built without "
                                         "HRT_DESCRIBE?) and no registered firmware profile knows it"),
    ("-DAN1017_FIRMWARE_VERSION=0x0102u", "firmware_version 258 (model 257)"),
])
def test_profile_build_another_firmware_is_not_described_by_guess(sil_builds: Path, gcc: str,
                                                                 profile: tuple[str, ...], define: str,
                                                                 refusal: str) -> None:
    """The registered model describes a build's parameters only if its own TargetHello declares what the
    build's does: a renamed firmware or another version is refused (TargetError, one line naming both),
    before any parameter is read or written."""
    exe = build_sil(sil_builds, defines=(*profile, define))
    with SilTarget.open("seed", exe=exe) as sil:
        sil.target.handshake(50)
        with pytest.raises(TargetError) as refused:
            sil.target.describe(0)
    assert refusal in str(refused.value) and "\n" not in str(refused.value), refused.value
    assert not isinstance(refused.value, ParamError), refused.value


def test_profile_conformance_reports_what_it_leaves_out_as_not_served(profile_sil: Path) -> None:
    """`hilbench conformance` on the profile's build: real time and ParamDescribe are refused as the
    protocol says, so those checks are "not served", no failure; the ParamSet checks run with the
    declaration RemoteTarget.describe gives (the registered model's, the firmware's values)."""
    from hilbench.bench.conformance import run_checks

    firmware = start_process([str(profile_sil), "--pty"], "sil:an1017 profile --pty")
    try:
        results = {r.name: r for r in run_checks(f"serial:{firmware.tty_path}")}
    finally:
        firmware.close()
    not_served = {"parameters: describe and get", "watchdog (real time)"}
    assert {name for name, r in results.items() if r.status == "not served"} == not_served, results
    assert all(r.ok is True for name, r in results.items() if name not in not_served), results
    assert "ParamGet checked" in results["parameters: describe and get"].detail, results
    assert "all-or-nothing" in results["parameters: set, all or nothing"].detail, results
