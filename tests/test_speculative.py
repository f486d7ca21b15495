"""Twin-speculative lockstep ([link] twin = "auto", hilbench.bench.speculative) as `hilbench run` runs it.

Each case runs the same config twice as a real process, per-period lockstep (twin off) and
speculative (twin auto), and the recordings must be the same row for row (the metadata lines
differ only in the config's twin key). Live parameter writes are in every scenario. A firmware
built with a deliberate one-LSB difference under a rare condition is caught, and the report names
the first period and field in which its Drives differ from the twin's, which the test finds itself
from two per-period recordings. Frames dropped and bits flipped on a throttled wire are resent and
the recording is still the per-period one. Simulations are kept short (tenths of a second).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from _firmware import require_tool

REPO = Path(__file__).resolve().parents[1]
SERVO = REPO / "bench_configs" / "servo_200w.toml"
AN1017_WRITES = """
[[scenario]]
at_s = 0.0
press = "s2"
[[scenario]]
at_s = 0.005
ref_rpm = 1500.0
ramp_s = 0.05
[[scenario]]
at_s = 0.03
set = { kp = 0.2, ki = 0.03 }
[[scenario]]
at_s = 0.07
set = { kd = 0.01 }
"""
FOC_WRITES = """
[[scenario]]
at_s = 0.0
ref_rpm = 0.0
[[scenario]]
at_s = 0.02
ref_rpm = 600.0
[[scenario]]
at_s = 0.06
set = { spd_kp = 0.9 }
"""


def _run(tmp: Path, name: str, target: str, twin: str, duration_s: float, scenario: str,
         config: Path | None = None, extra: tuple[str, ...] = ()) -> tuple[int, dict, list[str], str]:
    scenario_file = tmp / f"{name}-scenario.toml"
    scenario_file.write_text(scenario)
    record = tmp / f"{name}-{twin}.csv"
    argv = [sys.executable, "-m", "hilbench", "run", *([str(config)] if config else []), "--target", target,
            "--set", f"link.twin={twin}", "--set", "link.timeout_ms=10000", "--duration", str(duration_s),
            "--scenario", str(scenario_file), "--record", str(record), "--no-ui", "--no-control", "--json", *extra]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=900)
    summary = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
    rows = [line for line in record.read_text().splitlines() if not line.startswith("#")] if record.exists() else []
    return done.returncode, summary, rows, done.stderr


CASES = [
    pytest.param("sil:an1017", 0.1, AN1017_WRITES, None, ("gcc",), id="sil-an1017"),
    pytest.param("sil:foc", 0.1, FOC_WRITES, SERVO, ("gcc",), id="sil-foc"),
    pytest.param("sil:an1017?twin=auto", 0.05, AN1017_WRITES, None, ("gcc",), id="sil-an1017-spec-key"),
    pytest.param("simavr:an1017", 0.1, AN1017_WRITES, None, ("avr-gcc", "simavr"), id="simavr-an1017",
                 marks=pytest.mark.slow),
    pytest.param("simavr:foc", 0.1, FOC_WRITES, SERVO, ("avr-gcc", "simavr"), id="simavr-foc", marks=pytest.mark.slow),
    pytest.param("qemu:an1017", 0.1, AN1017_WRITES, None, ("arm-none-eabi-gcc", "qemu-system-arm"), id="qemu-an1017",
                 marks=pytest.mark.slow),
    pytest.param("qemu:foc", 0.1, FOC_WRITES, SERVO, ("arm-none-eabi-gcc", "qemu-system-arm"), id="qemu-foc",
                 marks=pytest.mark.slow),
]


@pytest.mark.parametrize("target, duration_s, scenario, config, tools", CASES)
def test_speculative_recording_is_the_per_period_one(tmp_path: Path, target: str, duration_s: float, scenario: str,
                                                      config: Path | None, tools: tuple[str, ...]) -> None:
    for tool in tools:
        require_tool(tool, f"the {target} build")
    code_off, off, rows_off, err_off = _run(tmp_path, "case", target.split("?")[0], "off", duration_s, scenario,
                                            config)
    # the spec's key wins over the config's: ?twin=auto with [link] twin = "off" speculates too
    code_on, on, rows_on, err_on = _run(tmp_path, "case", target, "off" if "twin=" in target else "auto",
                                        duration_s, scenario, config)
    assert code_off == 0, err_off
    assert code_on == 0, err_on
    periods = round(duration_s / 50e-6)
    assert off["periods"] == on["periods"] == periods
    assert on["link"]["speculative_periods"] == periods  # every period was committed by a digest
    assert "speculative_periods" not in off["link"]
    assert len(rows_on) == periods + 1  # the header and one row a period
    first = next((k for k, (a, b) in enumerate(zip(rows_off, rows_on)) if a != b), None)
    assert first is None, f"row {first} differs:\n{rows_off[first]}\n{rows_on[first]}"
    assert rows_off == rows_on


def _first_difference(rows_a: list[str], rows_b: list[str]) -> tuple[int, set[str]]:
    """The first data row (= period) whose Drive columns differ, and those columns' names."""
    header = rows_a[0].split(",")
    drive_cols = [i for i, name in enumerate(header) if name.split("[")[0] in
                  ("duty_a", "duty_b", "duty_c", "output_mode", "state", "fault", "measured_speed_rpm",
                   "ref_speed_rpm", "control_output_q15")]
    for k, (a, b) in enumerate(zip(rows_a[1:], rows_b[1:])):
        va, vb = a.split(","), b.split(",")
        differ = {header[i].split("[")[0] for i in drive_cols if va[i] != vb[i]}
        if differ:
            return k, differ
    raise AssertionError("the one-LSB build never differed in these periods")


def test_a_one_lsb_difference_is_caught_and_located(tmp_path: Path, sil_builds: Path) -> None:
    """A SIL build whose PWM ISR adds one count to duty A when the rotor's phase passes one value:
    per-period lockstep against the twin's build finds the first differing period; the speculative
    run must end with a divergence (exit code 10) naming that period and field."""
    require_tool("gcc", "the SIL build")
    from hilbench.targets.sil import build_sil

    exe = build_sil(sil_builds, defines=("-DAN1017_TEST_ONE_LSB_PHASE=40000u",))
    duration = "0.2"
    good_code, _, good_rows, err = _run(tmp_path, "good", "sil:an1017", "off", float(duration), AN1017_WRITES)
    assert good_code == 0, err
    bad_spec = f"sil:{exe}"
    extra = ("--set", "link.firmware=an1017")
    bad_code, _, bad_rows, err = _run(tmp_path, "bad", bad_spec, "off", float(duration), AN1017_WRITES, extra=extra)
    assert bad_code == 0, err
    period, fields = _first_difference(good_rows, bad_rows)
    code, _, _, err = _run(tmp_path, "spec", bad_spec, "auto", float(duration), AN1017_WRITES, extra=extra)
    assert code == 10, err
    line = err.strip().splitlines()[0]
    assert line.startswith("hilbench: divergence: first differing period ")
    assert f"first differing period {period} " in line, (line, period)
    named = line.split("field ")[1].split(":")[0]
    assert named in fields | {"duty_a"} and named.startswith("duty_a"), (line, fields)
    assert len(err.strip().splitlines()) == 1, err
    # a run that ends a few periods after it: the difference is in the batches still in flight at the
    # end, which the end confirms before it stops the target (never a "completed" run)
    code, _, _, err = _run(tmp_path, "end", bad_spec, "auto", (period + 5) * 50e-6, AN1017_WRITES, extra=extra)
    assert code == 10, err
    assert f"first differing period {period} " in err.strip().splitlines()[0], err


def test_on_divergence_continue_goes_on_per_period_and_ends_with_exit_code_10(tmp_path: Path, sil_builds: Path) -> None:
    """[link] on_divergence = "continue": the run records every period (after the difference one
    exchange a period, the target's own Drives) and ends with the divergence's line and exit code 10;
    its rows up to the first difference are the per-period run's."""
    require_tool("gcc", "the SIL build")
    from hilbench.targets.sil import build_sil

    exe = build_sil(sil_builds, defines=("-DAN1017_TEST_ONE_LSB_PHASE=40000u",))
    extra = ("--set", "link.firmware=an1017")
    code_off, _, rows_off, err = _run(tmp_path, "off", f"sil:{exe}", "off", 0.2, AN1017_WRITES, extra=extra)
    assert code_off == 0, err
    code, _, rows, err = _run(tmp_path, "on", f"sil:{exe}", "auto", 0.2, AN1017_WRITES,
                              extra=(*extra, "--set", "link.on_divergence=continue"))
    assert code == 10, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("hilbench: divergence: first differing period "), err
    period = int(line.split("first differing period ")[1].split()[0])
    assert len(rows) == len(rows_off) == 4001  # every period recorded
    assert rows[:period + 1] == rows_off[:period + 1]  # the header and the periods before the difference
    assert rows[period + 1] != rows_off[period + 1]  # the twin's Drive there, not the target's
    # the recording says which rows are the twin's, unconfirmed: from the diverged batch's first period
    events = [line for line in (tmp_path / "on-auto.csv").read_text().splitlines()
              if line.startswith("# event:") and "twin-speculative divergence" in line]
    assert len(events) == 1, events
    first, last = (int(v) for v in events[0].split("periods ")[1].split(" ")[0].split(".."))
    assert first <= period <= last < first + 400, events


@pytest.mark.parametrize("build", ["emulator", "sil-without-batches"])
def test_a_target_that_refuses_batches_runs_per_period_with_the_same_recording(tmp_path: Path, build: str,
                                                                               sil_builds: Path) -> None:
    """The Python emulator process and a SIL build with -DHRT_SPECULATE=0 answer a SensorsBatch with an
    ErrorReport: the periods the twin ran ahead go to them one by one (checked), then the run goes on
    per period, and the recording is the per-period one."""
    extra: tuple[str, ...] = ()
    target = "emulator:an1017"
    if build != "emulator":
        require_tool("gcc", "the SIL build")
        from hilbench.targets.sil import build_sil

        target = f"sil:{build_sil(sil_builds, defines=('-DHRT_SPECULATE=0',))}"
        extra = ("--set", "link.firmware=an1017")
    code_off, off, rows_off, err = _run(tmp_path, "off", target, "off", 0.05, AN1017_WRITES, extra=extra)
    assert code_off == 0, err
    code, on, rows, err = _run(tmp_path, "on", target, "auto", 0.05, AN1017_WRITES, extra=extra)
    assert code == 0, err
    assert on["link"]["speculative_periods"] == 0 and on["link"]["speculative_batches"] == 1
    assert rows == rows_off


def test_lost_and_corrupted_frames_on_a_throttled_wire_are_resent_never_committed_wrong(tmp_path: Path) -> None:
    """A 1 Mbaud wire that drops 10 % of the host's frames and flips bits both ways at 5e-4 (a batch
    frame in 4, an answer in 9): batches are resent, answers lost on the way back are recovered, and
    the recording is the per-period one."""
    require_tool("gcc", "the SIL build")
    clean_code, _, clean_rows, err = _run(tmp_path, "clean", "sil:an1017", "off", 0.1, AN1017_WRITES)
    assert clean_code == 0, err
    target = "sil:an1017?wire_baud=1000000&drop=0.1&corrupt=5e-4&fault_seed=11"
    code, summary, rows, err = _run(tmp_path, "faulty", target, "auto", 0.1, AN1017_WRITES,
                                    extra=("--set", "link.retry_ms=20"))
    assert code == 0, err
    link = summary["link"]
    assert link["speculative_resends"] > 0 and link["frame_errors"] > 0, link
    assert link["speculative_periods"] == 2000
    assert link["wire_rx_overrun_bytes"] == 0  # the throttle's figure is in the summary (nothing lost to it here)
    assert rows == clean_rows


def test_a_divergence_on_a_board_port_names_its_batch_and_says_why_it_is_not_located(tmp_path: Path,
                                                                                     sil_builds: Path) -> None:
    """A far end on a port (here the one-LSB SIL build on its own pty, as a board on a serial port) is
    not started by the host, so nothing can reset it for the replay: the run still ends with exit code
    10, one line naming the periods of the batch whose digest differed and why the first differing
    period is not named (opening the port again would have failed on the run's own lock)."""
    require_tool("gcc", "the SIL build")
    from hilbench.processes import reap
    from hilbench.targets.sil import build_sil
    from test_board_guide import _start

    exe = build_sil(sil_builds, defines=("-DAN1017_TEST_ONE_LSB_PHASE=40000u",))
    board, pty = _start([str(exe), "--pty"])
    try:
        code, _, _, err = _run(tmp_path, "board", f"serial:{pty}", "auto", 0.2, AN1017_WRITES,
                               extra=("--set", "link.firmware=an1017"))
    finally:
        reap(board, 10.0)
    assert code == 10, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("hilbench: divergence: ") and "cannot be reset from here" in line, err
    assert "Traceback" not in err


def _sensor_stream(n: int) -> list:
    """Sensors of n periods from period 0: the first carries three hall edges beside every ADC code
    (19 bytes of record: more than the 17 a first batch may hold), then halls that step every 7
    periods, ADC noise and the S2 press that starts the firmware."""
    from hilbench.protocol import Sensors

    sectors = (0b001, 0b011, 0b010, 0b110, 0b100, 0b101)
    out = [Sensors(0, sectors[0] | 0x08, ((100, sectors[1]), (200, sectors[2]), (300, sectors[3])), 0, (600, 500, 640))]
    for k in range(1, n):
        halls = sectors[(3 + k // 7) % 6]
        edges = ((250, halls),) if k % 7 == 0 else ()
        out.append(Sensors(k & 0xFF, halls | (0x08 if k < 40 else 0), edges, 0, (600 + k % 3, 500 - k % 2, 640)))
    return out


def test_a_period_whose_record_fits_no_batch_goes_alone_and_batches_go_on(gcc: str) -> None:
    """A first period with 19 bytes of record (17 fit a first batch) goes as a per-period Sensors, its
    Drive checked against the twin's; the batches then start afresh and the Drives stay those of
    per-period lockstep. (It ended the run with a ProtocolError before, exit 3.)"""
    from hilbench.bench.speculative import SpeculativeTarget, locate_divergence
    from hilbench.bench.launcher import open_target
    from hilbench.protocol import MODE_LOCKSTEP, PROTOCOL_VERSION, HostHello
    from hilbench.targets.registry import get_profile

    stream = _sensor_stream(600)
    hello = HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0)
    drives = []
    for twin in (False, True):
        with open_target("sil:an1017", timeout_s=5.0) as handle:
            profile = get_profile("an1017")
            target = SpeculativeTarget(handle.target, profile.twin(profile.default_options()), period_us=50) \
                if twin else handle.target
            target.hello(hello)
            got = [target.step(s) for s in stream]
            if twin:
                target.drain()
                stats, log = target.stats, list(target._log.items())
        drives.append(got)

    def reopen() -> tuple:
        handle = open_target("sil:an1017", timeout_s=5.0)
        return handle.target, handle.close

    # the replay that locates a divergence goes through the period that went alone: none found
    assert [kind for kind, _ in log[:3]] == ["hello", "step", "batch"]
    assert locate_divergence(log, reopen, lambda: profile.twin(profile.default_options()), len(stream) - 1, 50) is None
    assert drives[1] == drives[0]
    assert len({(d.duty_a, d.duty_b, d.duty_c) for d in drives[0]}) > 20  # the firmware drives: not a constant answer
    assert stats.alone == 1 and stats.batches > 5 and stats.periods == len(stream) - 1


def test_a_run_that_predicts_duties_says_why_the_twin_stayed_off(tmp_path: Path, gcc: str) -> None:
    """twin = auto at 100 us periods: the session asks for predicted duties, the twin does not
    predict, and the summary says so (it said '0 of N periods confirmed' before, with no reason)."""
    argv = [sys.executable, "-m", "hilbench", "run", "--target", "sil:an1017?twin=auto", "--set", "link.period_us=100",
            "--duration", "0.02", "--no-ui", "--no-control"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "speculative: off: the duties were predicted over each period" in done.stdout
    assert "link.predict_duties=false" in done.stdout
