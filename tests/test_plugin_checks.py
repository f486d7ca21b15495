"""[[check]] tables: each kind judged against hand-derived figures on synthetic signals, the
config's validation, and the CLI's exit code 9 (the runaway and the servo-with-AN1017 runs)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import BENCH_CONFIGS, REPO_ROOT
from hilbench.bench.checks import CheckEntry, checks_text, run_checks
from hilbench.bench.summary import Segment, Summary
from hilbench.bench.settings import load_config
from hilbench.errors import CheckFailed, ConfigError

DT = 1e-4


def _synthetic() -> tuple[Summary, dict[str, np.ndarray]]:
    """1 s at 10 kHz: speed 1000 * (1 - exp(-t / 0.1)), 2 A three-phase currents at 50 Hz."""
    t = np.arange(10_000) * DT
    w = 2 * math.pi * 50
    columns = {
        "t_s": t,
        "speed_rpm": 1000.0 * (1.0 - np.exp(-t / 0.1)),
        "ia_a": 2.0 * np.sin(w * t),
        "ib_a": 2.0 * np.sin(w * t - 2 * math.pi / 3),
        "ic_a": 2.0 * np.sin(w * t + 2 * math.pi / 3),
        "fault": np.zeros_like(t),
    }
    summary = Summary("synthetic", "lockstep", 100, periods=10_000, sim_s=1.0)
    summary.segments = [Segment(0.0, 1.0, 1000.0, plant_rpm=1010.0, measured_rpm=1009.0)]
    return summary, columns


def _judge(**keys: object) -> "object":
    summary, columns = _synthetic()
    return run_checks([CheckEntry(**keys)], summary, lambda: columns)[0]  # type: ignore[arg-type]


def test_settling_time_is_tau_ln20_for_a_first_order_response_in_a_5_percent_band() -> None:
    result = _judge(kind="settling_time", max_s=0.25)
    assert not result.passed
    assert result.value == pytest.approx(0.1 * math.log(20), abs=2 * DT)  # 0.2996 s
    assert "segment 1" in result.figure and "> 0.25 s" in result.figure
    assert _judge(kind="settling_time", max_s=0.31).passed
    # a 1 % band: tau ln 100 = 0.4605 s
    assert _judge(kind="settling_time", max_s=1.0, band_pct=1.0).value == pytest.approx(0.1 * math.log(100), abs=2 * DT)


def test_peak_current_speed_limit_and_any_signal() -> None:
    peak = _judge(kind="peak_current", max_a=1.9)
    assert not peak.passed and peak.value == pytest.approx(2.0, abs=1e-6)
    assert "> 1.9 A" in peak.figure
    assert _judge(kind="peak_current", max_a=2.01).passed
    # the window: over the first 1 ms (18° at 50 Hz) |ia| <= 0.62, |ic| falls from 1.73 and |ib|
    # rises towards its peak at 30°: the largest is |ib| at 1 ms, 2 |sin(18° - 120°)| = 1.956 A
    early = _judge(kind="peak_current", max_a=5.0, to_s=0.00105)
    assert early.value == pytest.approx(2.0 * abs(math.sin(math.radians(18 - 120))), abs=1e-9)
    top = _judge(kind="speed_limit", max_rpm=999.0)
    assert not top.passed and top.value == pytest.approx(1000.0 * (1 - math.exp(-0.9999 / 0.1)), rel=1e-9)
    signal = _judge(kind="signal", signal="ia_a", min=-1.0)
    assert not signal.passed and signal.value == pytest.approx(-2.0, abs=1e-6) and "ia_a" in signal.figure
    missing = _judge(kind="signal", signal="nope", max=1.0)
    assert not missing.passed and "no column 'nope'" in missing.figure


def test_speed_error_per_segment_and_segments_too_short_to_judge() -> None:
    result = _judge(kind="speed_error", max_pct=0.5)
    assert not result.passed and result.value == pytest.approx(1.0)  # (1010 - 1000) / 1000
    assert "+1.00 %" in result.figure and "segment 1" in result.figure
    assert _judge(kind="speed_error", max_pct=1.5).passed
    short = _judge(kind="speed_error", max_pct=0.5, min_hold_s=2.0)
    assert short.passed and short.figure.startswith("not judged")
    assert not _judge(kind="speed_error", max_pct=0.5, segment=2).passed  # asked for, absent


def test_checks_written_for_one_firmware_are_not_judged_on_another() -> None:
    summary, columns = _synthetic()
    summary.firmware = "TINY"
    result = run_checks([CheckEntry(kind="peak_current", max_a=1.0, firmware="AN1017")], summary, lambda: columns)[0]
    assert result.passed and result.figure == "not judged: written for AN1017, the run's firmware is TINY"
    summary.firmware = "an1017"  # the HELLO's name, compared without case
    assert not run_checks([CheckEntry(kind="peak_current", max_a=1.0, firmware="AN1017")], summary, lambda: columns)[0].passed


def test_a_column_the_run_cannot_have_is_skip_with_its_reason_and_no_other() -> None:
    """A monitor-mode run records no plant: a check reading the phase currents says SKIP with why
    (`absent`); a column missing from any other run is not turned into a pass."""
    summary, columns = _synthetic()
    for name in ("ia_a", "ib_a", "ic_a"):
        del columns[name]
    why = "a monitor-mode run records no plant"
    entries = [CheckEntry(kind="peak_current", max_a=1.0), CheckEntry(kind="signal", signal="ia_a", max=1.0),
               CheckEntry(kind="speed_limit", max_rpm=2000.0)]
    skipped, signal, limit = run_checks(entries, summary, lambda: columns, absent={"ia_a": why, "ib_a": why})
    assert skipped.passed and skipped.skipped and skipped.figure == f"not judged: no column 'ia_a': {why}"
    assert signal.skipped and why in signal.figure
    assert limit.passed and not limit.skipped  # the columns it reads are there: judged
    with pytest.raises(KeyError):  # not monitor mode: a missing column is no SKIP
        run_checks(entries[:1], summary, lambda: columns)


def test_no_fault_and_overruns() -> None:
    summary, columns = _synthetic()
    columns["fault"][5000:5010] = 3
    summary.overruns = 5
    results = run_checks([CheckEntry(kind="no_fault"), CheckEntry(kind="overruns", max_pct=0.01),
                          CheckEntry(kind="overruns", max=5)], summary, lambda: columns)
    assert [r.passed for r in results] == [False, False, True]
    assert "code 3 at 0.5000 s" in results[0].figure and "10 periods" in results[0].figure
    assert "5 overruns (0.05 % of 10000 periods)" in results[1].figure
    summary.end_reason, summary.fault = "fault", "link pty: hung up"
    assert "ended on a fault" in run_checks([CheckEntry(kind="no_fault")], summary, lambda: columns)[0].figure
    text = checks_text(results)
    assert text.splitlines()[0].startswith("check no_fault: FAIL ")


def test_signals_are_read_only_when_a_kind_needs_them() -> None:
    summary, _ = _synthetic()

    def no_signals() -> dict[str, np.ndarray]:
        raise AssertionError("signals read")

    assert run_checks([CheckEntry(kind="speed_error", max_pct=2.0), CheckEntry(kind="overruns", max=0)],
                      summary, no_signals)[0].passed


def test_check_tables_are_validated_with_the_config(tmp_path: Path) -> None:
    base = (BENCH_CONFIGS / "hurst_mclv.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(base + '\n[[check]]\nkind = "speed_error"\n\n[[check]]\nkind = "peak_current"\nmax_a = 2\nmax_rpm = 3\n'
                   '\n[[check]]\nkind = "settle"\nmax_s = 1\n')
    with pytest.raises(ConfigError) as info:
        load_config(bad)
    text = str(info.value)
    assert "needs max_pct" in text and "max_rpm: not used by kind 'peak_current'" in text
    assert "'settle' is not one of" in text


def test_the_packaged_default_config_carries_checks_that_hold(tmp_path: Path) -> None:
    cfg = load_config(None)
    assert {c.kind for c in cfg.check} >= {"speed_error", "settling_time", "peak_current", "no_fault"}
    assert (REPO_ROOT / "hilbench" / "data" / "hurst_mclv.toml").read_text() == (BENCH_CONFIGS / "hurst_mclv.toml").read_text()


def _cli(*args: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO_ROOT)


def test_run_shows_each_check_and_exits_0_when_they_hold(tmp_path: Path) -> None:
    run = _cli("run", "--target", "inprocess:an1017", "--json", "--no-control", "--record", str(tmp_path / "run.npz"))
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["checks_passed"] is True and len(summary["checks"]) == 5
    assert all(c["passed"] and c["figure"] for c in summary["checks"])
    assert all("not judged" not in c["figure"] for c in summary["checks"])
    plain = _cli("run", "--target", "inprocess:an1017", "--no-ui", "--no-control")  # no rows kept:
    assert plain.returncode == 0 and "check speed_error: PASS worst -0." in plain.stdout  # the summary's kinds
    assert "check peak_current: SKIP not judged: no rows were kept" in plain.stdout  # issue 22: not "PASS"
    assert "check no_fault: PASS no fault seen live" in plain.stdout  # judged from the live state


def test_a_faulted_run_without_rows_fails_no_fault(tmp_path: Path) -> None:
    """Issue 22, item 4: a run whose firmware faulted ended "completed" with no_fault PASS when it
    kept no rows. Gains that trip the board's comparator (kp=0.05 ki=0.9 at 1500 rpm, written by a
    scenario; the guard restores them, the firmware stays in FAULT) latch fault OVERCURRENT; no_fault
    fails from the live state, the signal kinds SKIP."""
    config = tmp_path / "trip.toml"
    scenario = "".join(f"\n[[scenario]]\nat_s = {at}\n{action}\n" for at, action in (
        (0.0, "ref_rpm = 1500.0"), (0.01, 'press = "s2"'), (0.6, "set = { kp = 0.05, ki = 0.9 }"), (1.2, "end = true")))
    config.write_text((BENCH_CONFIGS / "hurst_mclv.toml").read_text() + scenario)
    run = _cli("run", str(config), "--target", "inprocess:an1017", "--no-ui", "--no-control")
    assert run.returncode == 9, run.stderr
    assert "check no_fault: FAIL firmware fault code 3 at 0.7" in run.stdout and "no rows kept" in run.stdout
    assert "check peak_current: SKIP" in run.stdout


def test_the_runaway_and_the_servo_with_the_an1017_firmware_exit_7(tmp_path: Path) -> None:
    """The issue's cases: a 0.5 N*m load at 0.8 s in the default scenario (-218 895 rpm), and the
    servo motor run with the AN1017 firmware (+59 % speed error); the servo config's own firmware passes."""
    runaway = tmp_path / "runaway.toml"
    scenario = "".join(f"\n[[scenario]]\nat_s = {at}\n{action}\n" for at, action in (
        (0.0, "ref_rpm = 1500.0\nramp_s = 0.3"), (0.03, 'press = "s2"'), (0.8, "load_nm = 0.5"),
        (1.2, "ref_rpm = 2500.0"), (2.2, "ref_rpm = -1500.0"), (3.6, 'press = "s2"'), (3.8, "end = true")))
    runaway.write_text((BENCH_CONFIGS / "hurst_mclv.toml").read_text() + scenario)
    # with the board's protections the run is stopped by them (overcurrent trip, overspeed limit)
    protected = _cli("run", str(runaway), "--target", "inprocess:an1017", "--no-ui", "--no-control")
    assert protected.returncode != 0, protected.stdout
    # without them, the checks catch it
    run = _cli("run", str(runaway), "--target", "inprocess:an1017", "--no-ui", "--no-control",
               "--set", "protection.overcurrent_a=0", "--set", "protection.overspeed_rpm=0",
               "--record", str(tmp_path / "runaway.npz"))  # the signal kinds are judged on the recording
    assert run.returncode == CheckFailed.exit_code == 9, run.stderr
    assert "check speed_limit: FAIL" in run.stdout and "check speed_error: FAIL" in run.stdout
    assert run.stderr.startswith("hilbench: check failed: ") and len(run.stderr.strip().splitlines()) == 1
    # the servo config names its own firmware's options now: with the AN1017 target it is refused
    as_is = _cli("run", str(BENCH_CONFIGS / "servo_200w.toml"), "--target", "inprocess:an1017", "--no-ui", "--no-control")
    assert as_is.returncode == 2 and "[target]" in as_is.stderr
    # its motor, inverter, sensors and checks alone (no [target], [link], [[scenario]]), as the issue ran it
    kept, table = [], ""
    for line in (BENCH_CONFIGS / "servo_200w.toml").read_text().splitlines():
        if line.startswith("["):
            table = line.strip("[] ")
        if table not in ("target", "link", "scenario"):
            kept.append(line)
    motor_only = tmp_path / "servo_motor.toml"
    motor_only.write_text("\n".join(kept) + "\n")
    refused = _cli("run", str(motor_only), "--target", "inprocess:an1017", "--no-ui", "--no-control")
    assert refused.returncode == 2 and "pole pairs" in refused.stderr  # the bench's own check, first
    servo = _cli("run", str(motor_only), "--target", "inprocess:an1017", "--json", "--no-control",
                 "--set", "link.allow_pole_pair_mismatch=true", "--set", "protection.overspeed_rpm=0",
                 "--set", "protection.overcurrent_a=0")
    assert servo.returncode == 9, servo.stderr
    failed = [c for c in json.loads(servo.stdout)["checks"] if not c["passed"]]
    assert failed[0]["kind"] == "speed_error" and failed[0]["value"] > 50
    own = _cli("run", str(BENCH_CONFIGS / "servo_200w.toml"), "--json", "--no-control")
    assert own.returncode == 0 and json.loads(own.stdout)["checks_passed"], own.stderr


def test_step_judges_the_step_kinds(tmp_path: Path) -> None:
    config = tmp_path / "step.toml"
    config.write_text((BENCH_CONFIGS / "hurst_mclv.toml").read_text()
                      + '\n[[check]]\nkind = "step_rise_time"\nmax_s = 0.2\n\n[[check]]\nkind = "step_peak_current"\nmax_a = 2.0\n')
    step = _cli("step", str(config), "--json")
    assert step.returncode == 9, step.stderr
    rows = json.loads(step.stdout)
    verdicts = {c["kind"]: c for c in rows[0]["checks"]}
    assert not verdicts["step_rise_time"]["passed"] and verdicts["step_peak_current"]["passed"]
    assert verdicts["step_rise_time"]["value"] == pytest.approx(rows[0]["rise_time_s"])
    default = _cli("step")  # the default config has no step checks: nothing judged, exit 0
    assert default.returncode == 0, default.stderr


def test_the_last_hold_of_a_run_the_user_stopped_early_is_not_judged() -> None:
    """A run ended by `ctl stop` (or the scope's stop) cut its last hold short: its speed is not a
    steady state, so a speed_error check does not judge it (the scope's stop gave exit 9)."""
    summary, columns = _synthetic()  # one segment, 1 % off
    strict = CheckEntry(kind="speed_error", max_pct=0.5)
    assert not run_checks([strict], summary, lambda: columns)[0].passed
    summary.end_reason = "stopped by ctl"
    result = run_checks([strict], summary, lambda: columns)[0]
    assert result.passed and result.figure.startswith("not judged")
