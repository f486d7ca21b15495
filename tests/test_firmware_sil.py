"""Issue 12, SIL: the C AN1017 firmware (firmware/an1017, host port) against the Python model.

The Python model (hilbench/targets/an1017_firmware.py, in-process) is the independent reference:
every Drive, parameter reply and recording column of the C firmware over a pty must equal it, on
seeded random streams and on whole bench sessions, for both variants. The Q15 helpers and the SVM
are checked against hand-derived values and the SVM reference vectors of docs/board.md.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from _firmware import play, random_stream
from c_build import build_c
from conftest import BENCH_CONFIGS
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.link.pty import open_pty_pair
from hilbench.processes import spawn
from hilbench.protocol import (
    FAULT_WATCHDOG,
    MODE_LOCKSTEP,
    MODE_REALTIME,
    OUTPUT_OFF,
    PROTOCOL_VERSION,
    RESULT_CONSTRAINT,
    RESULT_OK,
    STATE_FAULT,
    Drive,
    HostHello,
    Sensors,
)
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.an1017.firmware import An1017Options
from hilbench.targets.sil import FIRMWARE_DIR, RUNTIME_DIR, SilTarget, build_sil, start_sil, stop_sil

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def sil_exe(sil_builds: Path, gcc: str) -> Path:
    return build_sil(sil_builds)


@pytest.mark.parametrize("variant", ["seed", "v11"])
@pytest.mark.parametrize("seed,period_us", [(1, 50), (2, 50), (3, 100), (4, 1000)])
def test_sil_drive_for_drive_equals_python_model(sil_exe: Path, variant: str, seed: int, period_us: int) -> None:
    with SilTarget.open(variant, exe=sil_exe) as sil:
        model = An1017Target(An1017Options(variant=variant))
        periods = 30000 if period_us == 50 else 8000
        n, seen = play(random_stream(seed, periods, period_us), [model, sil.target], period_us)
        assert n in (periods, periods + 1)  # (+ the S2 press that may open the stream)
        # the stream did what it is for: bootstrap and running (both ways and stalls in most seeds)
        assert {1, 2} <= {state for state, _, _ in seen}, seen


def test_sil_parameters_and_constraints_refused_by_the_firmware(sil_exe: Path) -> None:
    """Declared table and the note's constraints, asked of the C firmware directly (no host check)."""
    with SilTarget.open("seed", exe=sil_exe) as sil:
        t = sil.target
        t.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0))
        names = [t.describe(i).name for i in range(8)]
        assert names == ["kp", "ki", "kd", "ph_adv_on", "ph_adv_deg", "ref_ovr_on", "ref_override", "stall_ms"]
        assert [t.get_param(i).value for i in range(8)] == [3277, 328, 0, 0, 40, 0, 0, 100]
        # Kp + Ki + Kd < 0.9999 (Q15 32764): 32000 + 764 = 32764 is refused, constraint 1, named kp
        r = t.set_params(((0, 32000), (1, 764)))
        assert (r.result, r.param_id, r.detail) == (RESULT_CONSTRAINT, 0, 1)
        assert t.get_param(0).value == 3277  # all or nothing
        # -Kp - 2Kd > -1.0: Kp = 20000, Kd = 6384 -> 32768, refused; Kp + Ki + Kd = 26712 passes rule 1
        r = t.set_params(((2, 6384), (0, 20000)))
        assert (r.result, r.param_id, r.detail) == (RESULT_CONSTRAINT, 2, 2)
        r = t.set_params(((2, 6383), (0, 20000)))
        assert (r.result, r.param_id) == (RESULT_OK, 0)
        assert (t.get_param(0).value, t.get_param(2).value) == (20000, 6383)


def test_sil_realtime_watchdog_turns_pwm_off(sil_exe: Path) -> None:
    with SilTarget.open("seed", exe=sil_exe) as sil:
        t = sil.target
        t.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_REALTIME, 50))
        t.start()
        d = t.step(Sensors(1, 0b100, (), 0, (700, 512, 512)))
        assert d.fault == 0
        msg = sil.link.recv(2.0)  # nothing more is sent: the firmware's watchdog speaks after 50 ms
        assert isinstance(msg, Drive)
        assert (msg.seq, msg.output_mode, msg.state, msg.fault) == (1, OUTPUT_OFF, STATE_FAULT, FAULT_WATCHDOG)
        assert t.status().watchdog_trips == 1


def test_sil_exits_on_hangup_and_rejects_a_missing_tty(sil_exe: Path, tmp_path: Path) -> None:
    sil = SilTarget.open("seed", exe=sil_exe)
    assert sil.target.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0)).firmware_name == "AN1017"
    sil.link.close()
    assert sil.process.wait(timeout=5) == 0
    stop_sil(sil.process)
    result = subprocess.run([str(sil_exe), str(tmp_path / "no-such-tty")], capture_output=True, text=True, timeout=10)
    assert result.returncode == 1 and "cannot open" in result.stderr
    result = subprocess.run([str(sil_exe), "--variant", "v2", "x"], capture_output=True, text=True, timeout=10)
    assert result.returncode == 2


# The default scenario (hilbench.bench.scenario.default_scenario) written out, plus live writes of
# the gains and the phase advance while the motor runs (the firmware takes gains at its next Timer1 ISR).
DEFAULT_SCENARIO_WITH_TUNING = """
[[scenario]]
at_s = 0.0
ref_rpm = 1500.0
ramp_s = 0.3

[[scenario]]
at_s = 0.03
press = "s2"

[[scenario]]
at_s = 1.0
set = { kp = 0.12, ki = 0.012 }

[[scenario]]
at_s = 1.6
set = { ph_adv_on = 1, ph_adv_deg = 30 }

[[scenario]]
at_s = 1.2
ref_rpm = 2500.0

[[scenario]]
at_s = 2.6
set = { kd = 0.01 }

[[scenario]]
at_s = 2.2
ref_rpm = -1500.0

[[scenario]]
at_s = 3.6
press = "s2"

[[scenario]]
at_s = 3.8
end = true
"""


def run_recording(tmp_path: Path, spec: str, name: str, overrides: tuple[str, ...]) -> list[str]:
    config = tmp_path / "default_tuned.toml"
    config.write_text((BENCH_CONFIGS / "hurst_mclv.toml").read_text() + DEFAULT_SCENARIO_WITH_TUNING)
    cfg = load_run_config(RunRequest(str(config), overrides=overrides, target=spec))
    out = tmp_path / f"{name}.csv"
    run_bench(cfg, record=out)
    return [ln for ln in out.read_text().splitlines() if not ln.startswith("# ")]


@pytest.mark.parametrize("variant", ["seed", "v11"])
def test_sil_session_recording_identical_to_python_model(sil_exe: Path, tmp_path: Path, variant: str) -> None:
    """The default scenario (3.8 s, 76 000 lockstep periods) with live parameter writes: every column."""
    overrides = (f'target.variant="{variant}"',)
    expected = run_recording(tmp_path, "inprocess:an1017", "model", overrides)
    pair = open_pty_pair()
    process = start_sil(pair.slave_path, variant, exe=sil_exe)
    try:
        os.close(pair.slave_fd)  # the firmware holds the slave now
        got = run_recording(tmp_path, f"fd:{pair.master_fd}", "sil", overrides)  # the link closes the master
    finally:
        stop_sil(process)
    assert len(expected) == 76001
    header = expected[0].split(",")
    assert {"duty_a[counts]", "speed_rpm[rpm]", "control_output_q15[q15]", "state"} <= set(header)
    for i, (a, b) in enumerate(zip(expected, got)):
        assert a == b, (i, header, a, b)
    assert len(got) == len(expected)


def test_q15_helpers_and_svm_against_hand_derived_values(tmp_path: Path, gcc: str) -> None:
    """DSP-engine semantics (DS70062) and the SVM reference vectors of docs/board.md §SVM."""
    src = tmp_path / "t.c"
    src.write_text(r'''
#include <stdio.h>
#include "q15.h"
#include "an1017.h"
int main(void) {
    uint16_t d[3];
    static const int16_t v[8] = {0, 16384, 16384, 28300, 32767, 16384, 10000, 20000};
    static const uint16_t a[8] = {0x0000u, 0x0000u, 0x1555u, 0x1555u, 0x4000u, 0x8000u, 0xE000u, 0x0AAAu};
    int i;
    printf("%d %d %d %d\n", q15_mul(-32768, -32768), q15_mul(16384, 16384), q15_mul(-16384, 3), q15_mul(16384, -1));
    printf("%d %d %d\n", q15_divf(312, 313), q15_divf(312, 31250), q15_divf(-1, 2));
    printf("%d %d %ld\n", q15_sac(-1), q15_sac(0x7FFFFFFF), (long)q15_mac_sata(0x7FFF0000, 32767, 32767));
    printf("%ld %d %d\n", (long)q15_mac_sata(0, -32768, -32768), q15_wrap(32768), q15_sat(-40000));
    for (i = 0; i < 8; i++) { an1017_svm(v[i], a[i], d); printf("%u,%u,%u ", d[0], d[1], d[2]); }
    printf("\n%d %d %d\n", an1017_max_ph_adv(40), an1017_max_ph_adv(60), an1017_max_ph_adv(1));
    return 0;
}
''')
    exe = build_c([src, FIRMWARE_DIR / "an1017.c", RUNTIME_DIR / "hrt.c"], tmp_path / "t",
                  extra_flags=(f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}"))
    lines = subprocess.run([str(exe)], capture_output=True, text=True, timeout=10, check=True).stdout.splitlines()
    # -1*-1 saturates; 0.5*0.5 = 0.25; -0.5 * 3/32768 = -1.5/32768 truncates (floors) to -2; 0.5 * -1/32768 -> -1
    assert lines[0] == "32767 8192 -2 -1"
    # DIVF: 312*32768/313 = 32663.3 -> 32663 (0x7F97), 312*32768/31250 = 327.1 -> 327 (0x0147); -0.5
    assert lines[1] == "32663 327 -16384"
    # SAC floors -1 (bits 31:16 of 0xFFFFFFFF = -1); MAC with SATA clamps at 0x7FFFFFFF = 2147483647
    assert lines[2] == "-1 32767 2147483647"
    assert lines[3] == "2147483647 -32768 -32768"
    assert lines[4].split() == ["499,499,499", "714,284,284", "747,499,251", "927,499,71", "499,927,71",
                                "284,714,714", "644,354,567", "791,361,207"]
    # MAX_PH_ADV = (int)(deg / 360 * 65536): 7281.78 -> 7281, 10922.67 -> 10922, 182.04 -> 182
    assert lines[5] == "7281 10922 182"


def test_sil_on_its_own_pty_serves_the_cli_like_a_board(sil_exe: Path) -> None:
    """docs/board.md's "without a board" commands: link-test and run against `an1017_sil --pty`."""
    from conftest import run_cli

    process = spawn([str(sil_exe), "--pty"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE)
    try:
        assert process.stdout is not None
        line = process.stdout.readline().decode().split()  # blocking: the first line comes at once
        assert line[0] == "ready", line
        port = f"serial:{line[1]}"
        result = run_cli("link-test", port, "--periods", "500", timeout=120)
        assert result.returncode == 0, result.stderr
        assert "500 / 500" in result.stdout and "AN1017" in result.stdout
        # a second session on the same port: the firmware stays up between sessions, like a board
        result = run_cli("run", "--target", port, "--no-ui", "--no-control", "--json", "--set",
                         "run.duration_s=0.3", timeout=120)
        assert result.returncode == 0, result.stderr
        assert '"end_reason": "completed"' in result.stdout and '"crc_errors": 0' in result.stdout
    finally:
        stop_sil(process)


def test_sil_refuses_another_protocol_or_schema(sil_exe: Path) -> None:
    """HELLO with another version or schema fingerprint: ErrorReport VERSION naming the firmware's."""
    from hilbench.protocol import SCHEMA_FINGERPRINT, ErrorCode, ErrorReport, TargetHello

    with SilTarget.open("seed", exe=sil_exe) as sil:
        link = sil.link
        for hello in (HostHello(3, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0, SCHEMA_FINGERPRINT ^ 1),
                      HostHello(4, PROTOCOL_VERSION + 1, 50, MODE_LOCKSTEP, 0)):
            link.send(hello)
            reply = link.recv(2.0)
            assert reply == ErrorReport(hello.seq, ErrorCode.VERSION, PROTOCOL_VERSION, SCHEMA_FINGERPRINT)
        link.send(HostHello(5, PROTOCOL_VERSION, 70, MODE_LOCKSTEP, 0))  # not a multiple of 50 us
        assert link.recv(2.0) == ErrorReport(5, ErrorCode.BAD_REQUEST, 0, SCHEMA_FINGERPRINT)
        link.send(HostHello(6, PROTOCOL_VERSION, 100, MODE_LOCKSTEP, 0))
        reply = link.recv(2.0)
        assert isinstance(reply, TargetHello) and reply.schema_fingerprint == SCHEMA_FINGERPRINT
        assert reply.adc_bits == 10 and reply.seq == 6


def test_sil_describes_itself_as_the_in_process_target_does(sil_exe: Path) -> None:
    """Protocol 3's self-description from the C declaration (the runtime answers it) equals what the
    in-process target says: TargetInfo but max_edges (the SIL build's HBP_MAX_EDGES = 3), every
    TelemetryInfo, every ParamInfo with its unit; an index past the last telemetry slot is refused."""
    from hilbench.errors import TargetError
    from hilbench.protocol import TargetInfo

    model = An1017Target(An1017Options())
    model.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0))
    with SilTarget.open("seed", exe=sil_exe) as sil:
        t = sil.target
        t.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0))
        info = t.describe_target()
        assert isinstance(info, TargetInfo) and info.max_edges == 3
        assert info._replace(seq=0, max_edges=16) == model.describe_target()
        for i in range(3):
            assert t.describe_telemetry(i)._replace(seq=0) == model.describe_telemetry(i)
        with pytest.raises(TargetError, match="UNKNOWN_TELEMETRY"):
            t.describe_telemetry(3)
        for i in range(8):
            assert t.describe(i)._replace(seq=0) == model.describe(i)


def test_streamed_frames_equal_the_encoded_ones(tmp_path: Path, gcc: str) -> None:
    """The runtime's link streams every reply (hbp_send_frame: lengths, COBS and check bytes made as
    they go, no wire buffer): the bytes must equal hbp_encode_frame's, for every length and zero
    pattern, and hbp_encode_frame in place (the message at out + 2) must give them too."""
    from c_build import LIBRARY_SOURCES

    src = tmp_path / "stream.c"
    src.write_text(r'''
#include <stdio.h>
#include <string.h>
#include "hbp.h"
static uint8_t sent[HBP_MAX_WIRE + 8];
static unsigned n_sent;
static void put(const hbp_u8 *bytes, hbp_u8 n) {
    while (n--) sent[n_sent++] = *bytes++;
}
int main(void) {
    uint8_t frame[HBP_MAX_FRAME], out[HBP_MAX_WIRE], wire[HBP_MAX_WIRE];
    uint32_t x = 12345u;
    unsigned bad = 0u, n = 0u;
    uint8_t len, i, k;
    for (len = 2u; len <= (uint8_t)HBP_MAX_FRAME; len++) {
        for (k = 0u; k < 200u; k++) {
            for (i = 0u; i < len; i++) {
                x = x * 1103515245u + 12345u;
                frame[i] = (uint8_t)((x >> 16) % 4u == 0u ? 0u : (x >> 8));  /* zeros one byte in four */
            }
            uint8_t a = hbp_encode_frame(frame, len, out);
            n_sent = 0u;
            hbp_send_frame(frame, len, put);
            memcpy(&wire[2], frame, len);
            uint8_t b = hbp_encode_frame(&wire[2], len, wire);
            if (a != n_sent || memcmp(out, sent, a) != 0 || a != b || memcmp(out, wire, a) != 0) bad++;
            n++;
        }
    }
    printf("%u %u\n", n, bad);
    return 0;
}
''')
    exe = build_c([src, *LIBRARY_SOURCES], tmp_path / "stream")
    n, bad = subprocess.run([str(exe)], capture_output=True, text=True, timeout=30, check=True).stdout.split()
    assert int(n) == 61 * 200 and bad == "0"


def test_sil_under_address_and_undefined_behaviour_sanitizers(tmp_path: Path, gcc: str) -> None:
    """The firmware built with ASan + UBSan (any overflow, bad shift or out-of-bounds read aborts it)
    through a random stream with every kind of event, both variants."""
    from c_build import build_c
    from hilbench.targets.sil import CFLAGS, SOURCES, PROTOCOL_DIR

    defines = tuple(f for f in CFLAGS if f.startswith("-D"))
    exe = build_c(SOURCES, tmp_path / "an1017_sil_sanitized", sanitize=True,
                  extra_flags=(*defines, f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}", f"-I{PROTOCOL_DIR}"))
    for variant in ("seed", "v11"):
        with SilTarget.open(variant, exe=exe) as sil:
            model = An1017Target(An1017Options(variant=variant))
            n, _ = play(random_stream(21, 6000, 100), [model, sil.target], 100)
            assert n >= 6000
            assert sil.process.poll() is None  # still alive: no sanitizer report
