"""The C loopback target (built from the C library only) against the Python codec over a real pty.

Expected Drive values follow the loopback mapping of PROTOCOL.md, with the sector from AN1017
Table 8 (C B A: 001->4, 010->2, 011->3, 100->0, 101->5, 110->1, else invalid 7).
"""

from __future__ import annotations

import os
import random
import select
import subprocess
import time
import tty
from pathlib import Path

import pytest

from c_build import FIRMWARE_DIR, LIBRARY_SOURCES, build_c
from hilbench.errors import VersionMismatch
from hilbench.link import open_link
from hilbench.processes import spawn
from hilbench.protocol.framing import check_bytes, crc16
from hilbench.protocol import (
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    AdcRole,
    Drive,
    ErrorCode,
    ErrorReport,
    FrameDecoder,
    HostHello,
    Input,
    OutputMode,
    ParamDescribe,
    ParamGet,
    ParamInfo,
    ParamSet,
    ParamSetResult,
    ParamValue,
    Result,
    Sensors,
    Start,
    State,
    Status,
    StatusRequest,
    Stop,
    TargetHello,
    TelemetryId,
    encode_frame,
)
from hilbench.targets.remote import RemoteTarget
from reference_codec import wire as ref_wire  # independent CRC and COBS

TABLE8 = {0b001: 4, 0b010: 2, 0b011: 3, 0b100: 0, 0b101: 5, 0b110: 1}


class PtyTarget:
    """The loopback_target process on a pty slave; the test talks through the master fd."""

    def __init__(self, exe: Path) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        path = os.ttyname(self.slave)
        # the parent keeps the slave open until close(): a pty whose slave nobody holds reads EIO
        self.proc = spawn([str(exe), path], stdin=subprocess.DEVNULL)
        self.decoder = FrameDecoder()
        self.pending: list = []

    def send(self, msg) -> None:
        os.write(self.master, encode_frame(msg))

    def recv(self, timeout_s: float = 5.0):
        deadline = time.monotonic() + timeout_s
        while not self.pending:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no frame from loopback_target")
            ready, _, _ = select.select([self.master], [], [], left)
            if ready:
                self.pending += self.decoder.feed(os.read(self.master, 4096))
        return self.pending.pop(0)

    def ask(self, msg):
        self.send(msg)
        return self.recv()

    def close(self) -> int:
        try:
            os.close(self.master)
            os.close(self.slave)
            return self.proc.wait(timeout=5)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait()


@pytest.fixture(scope="module")
def loopback_exe(tmp_path_factory, gcc: str) -> Path:
    out = tmp_path_factory.mktemp("loopback")
    return build_c([FIRMWARE_DIR / "examples" / "loopback_target.c", *LIBRARY_SOURCES], out / "loopback_target",
                   extra_flags=("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u"))


@pytest.fixture()
def target(loopback_exe: Path):
    t = PtyTarget(loopback_exe)
    try:
        yield t
    finally:
        t.close()


def expected_drive(s: Sensors, running: bool) -> Drive:
    adc = list(s.adc) + [0, 0, 0]
    hall = s.inputs & 0x07

    def i16(v: int) -> int:
        return v - 0x10000 if v >= 0x8000 else v

    return Drive(s.seq, adc[0], adc[1], adc[2],
                 OutputMode.PWM if running else OutputMode.OFF, State.RUNNING if running else State.STOPPED,
                 TABLE8.get(hall, 7), bool(s.inputs & Input.S3), False, 0,
                 (i16(s.encoder), i16(s.edges[0][0]) if s.edges else -1, s.seq))


@pytest.mark.slow
def test_handshake_params_and_periods(target: PtyTarget) -> None:
    hello = target.ask(HostHello(0, PROTOCOL_VERSION, 1000, 0, 100))
    assert hello == TargetHello(0, PROTOCOL_VERSION, SCHEMA_FINGERPRINT, 1, 1000, 20000, 3, 10, "loopback",
                                (AdcRole.POT, AdcRole.IBUS, AdcRole.VBUS),
                                (TelemetryId.ECHO_ENCODER, TelemetryId.ECHO_EDGE, TelemetryId.ECHO_SEQ))
    assert target.ask(ParamDescribe(1, 0)) == ParamInfo(1, 0, 0, 1, 0, 32767, 3277, "kp")
    assert target.ask(ParamDescribe(2, 1)) == ParamInfo(2, 1, 0, 1, 0, 32767, 328, "ki")
    assert target.ask(ParamDescribe(3, 2)) == ParamInfo(3, 2, 1, 0, 1, 1, 1, "version")
    assert target.ask(ParamDescribe(4, 3)) == ErrorReport(4, ErrorCode.UNKNOWN_PARAM, 3)
    assert target.ask(ParamGet(5, 1)) == ParamValue(5, 1, Result.OK, 328)
    assert target.ask(ParamGet(6, 9)) == ParamValue(6, 9, Result.UNKNOWN_ID, 0)
    assert target.ask(ParamSet(7, ((0, 20000), (1, 10000)))) == ParamSetResult(7, Result.OK, 0, 0)
    assert target.ask(ParamGet(8, 0)) == ParamValue(8, 0, Result.OK, 20000)
    assert target.ask(ParamSet(9, ((5, 1),))) == ParamSetResult(9, Result.UNKNOWN_ID, 5, 0)
    assert target.ask(ParamSet(10, ((2, 1),))) == ParamSetResult(10, Result.READ_ONLY, 2, 0)
    assert target.ask(ParamSet(11, ((0, 1), (1, -1)))) == ParamSetResult(11, Result.OUT_OF_RANGE, 1, 0)
    assert target.ask(ParamSet(12, ((1, 12768),))) == ParamSetResult(12, Result.CONSTRAINT, 0, 1)
    assert target.ask(ParamSet(13, ((0, 1), (0, 2)))) == ParamSetResult(13, Result.BAD_REQUEST, 0, 0)
    assert target.ask(ParamSet(14, ())) == ParamSetResult(14, Result.BAD_REQUEST, 0, 0)
    # all or nothing: none of the refused sets changed anything
    assert target.ask(ParamGet(15, 0)) == ParamValue(15, 0, Result.OK, 20000)
    assert target.ask(ParamGet(16, 1)) == ParamValue(16, 1, Result.OK, 10000)

    rng = random.Random(1234)
    running = False
    last_s2 = False
    for k in range(3000):
        if k == 500:
            target.send(Start(0))
            running = True
        if k == 1500:
            target.send(Stop(0))
            running = False
        inputs = rng.randrange(0, 0x40)
        if rng.random() < 0.97:
            inputs &= ~Input.S2  # S2 presses are rare
        s2 = bool(inputs & Input.S2)
        if s2 and not last_s2:
            running = not running
        last_s2 = s2
        n_adc = 3 if rng.random() < 0.9 else rng.randrange(0, 3)
        edges = tuple((rng.randrange(0, 0x10000), rng.randrange(0, 0x100)) for _ in range(rng.choice((0, 0, 1, 2, 16))))
        s = Sensors(k & 0xFF, inputs, edges, rng.randrange(0, 0x10000),
                    tuple(rng.randrange(0, 1024 if rng.random() < 0.95 else 0x10000) for _ in range(n_adc)))
        assert target.ask(s) == expected_drive(s, running), k
    status = target.ask(StatusRequest(17))
    assert isinstance(status, Status)
    assert (status.rx_errors, status.unknown, status.overruns) == (0, 0, 0)
    assert status.rx_frames == 17 + 2 + 3000 + 1
    assert target.decoder.counters["frames"] == 17 + 3000 + 1
    assert sum(target.decoder.counters[k] for k in ("crc_errors", "cobs_errors", "length_errors")) == 0


@pytest.mark.slow
def test_wrong_version_gets_error_report_and_no_hello(target: PtyTarget) -> None:
    reply = target.ask(HostHello(3, PROTOCOL_VERSION + 1, 1000, 0, 100))
    assert reply == ErrorReport(3, ErrorCode.VERSION, PROTOCOL_VERSION, SCHEMA_FINGERPRINT)
    # a frame whose check bytes match but whose COBS block runs past its end, then a good request:
    # the target resynchronises and counts the bad frame
    cobs = bytes([0x09, 0x0A, 0x30, 0x01, 0x0A])
    os.write(target.master, cobs + check_bytes(crc16(cobs)) + b"\x00")
    status = target.ask(StatusRequest(4))
    assert status.rx_errors == 1 and status.resyncs == 1 and status.last_error == ErrorCode.COBS


@pytest.mark.slow
def test_exits_on_hangup_and_rejects_a_missing_tty(loopback_exe: Path, tmp_path: Path) -> None:
    t = PtyTarget(loopback_exe)
    assert t.ask(StatusRequest(1)).rx_frames == 1
    assert t.close() == 0
    result = subprocess.run([str(loopback_exe), str(tmp_path / "no-such-tty")], capture_output=True,
                            text=True, timeout=10)
    assert result.returncode != 0 and "cannot open" in result.stderr


OTHER_FINGERPRINT = 0x0BADF00D  # a firmware built from another schema.toml


@pytest.fixture(scope="module")
def other_schema_exe(tmp_path_factory, gcc: str) -> Path:
    """The loopback target as if built from a different schema: only its fingerprint differs."""
    assert OTHER_FINGERPRINT != SCHEMA_FINGERPRINT
    out = tmp_path_factory.mktemp("other_schema")
    return build_c([FIRMWARE_DIR / "examples" / "loopback_target.c", *LIBRARY_SOURCES], out / "loopback_other",
                   extra_flags=("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u",
                                f"-DHBP_SCHEMA_FINGERPRINT={OTHER_FINGERPRINT:#010x}UL"))


@pytest.mark.slow
def test_other_schema_is_refused_at_the_handshake_naming_both_fingerprints(other_schema_exe: Path) -> None:
    # on the wire: ErrorReport(VERSION, its protocol version, its fingerprint) and no TargetHello
    t = PtyTarget(other_schema_exe)
    try:
        assert t.ask(HostHello(3, PROTOCOL_VERSION, 1000, 0, 100)) == ErrorReport(
            3, ErrorCode.VERSION, PROTOCOL_VERSION, OTHER_FINGERPRINT)
        # nothing else was sent: the next request gets its own answer
        assert isinstance(t.ask(StatusRequest(4)), Status)
    finally:
        t.close()
    # through the host's real handshake (RemoteTarget over a pty): one line naming both
    host_link = open_link("pty", timeout_s=1.0)
    proc = spawn([str(other_schema_exe), host_link.peer_path], stdin=subprocess.DEVNULL)
    try:
        with pytest.raises(VersionMismatch) as info:
            RemoteTarget(host_link, timeout_s=2.0).handshake(1000, attempts=3)
        text = str(info.value)
        assert "\n" not in text
        assert f"{OTHER_FINGERPRINT:#010x}" in text and f"{SCHEMA_FINGERPRINT:#010x}" in text, text
        assert f"protocol version {PROTOCOL_VERSION}" in text and "rebuild the firmware" in text
    finally:
        host_link.close()
        try:
            proc.wait(timeout=5)
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()


@pytest.mark.slow
def test_the_version_byte_is_checked_before_the_length(target: PtyTarget) -> None:
    """A HostHello of another protocol version may be longer: it still gets ErrorReport(VERSION)."""
    raw = bytes([0x01, 5, PROTOCOL_VERSION + 1]) + bytes(range(1, 20))  # a future, longer HostHello
    os.write(target.master, ref_wire(raw))
    assert target.recv() == ErrorReport(5, ErrorCode.VERSION, PROTOCOL_VERSION, SCHEMA_FINGERPRINT)
    raw = bytes([0x01, 6, PROTOCOL_VERSION]) + bytes(range(1, 20))  # our version, wrong length
    os.write(target.master, ref_wire(raw))
    assert target.recv() == ErrorReport(6, ErrorCode.LENGTH, 0x01, SCHEMA_FINGERPRINT)
