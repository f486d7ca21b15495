"""`hilbench run` end to end: the default bench, determinism, faults, Ctrl-C, CLI errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO_ROOT, hurst_bench_config, run_cli
from hilbench.bench.recorder import MARKER_FAULT, read_recording
from hilbench.bench.run import RunRequest, load_run_config, run_bench


def test_inprocess_lockstep_is_byte_identical(tmp_path: Path) -> None:
    config = hurst_bench_config(tmp_path, 0.3)
    blobs = []
    for i in range(2):
        cfg = load_run_config(RunRequest(str(config), target="inprocess:an1017"))
        out = tmp_path / f"r{i}.csv"
        run_bench(cfg, record=out)
        blobs.append(out.read_bytes())
    assert blobs[0] == blobs[1]
    data = read_recording(tmp_path / "r0.csv")
    assert data.n_rows == 6000
    assert data.metadata["seed"] == 7
    assert data.metadata["target_hello"]["firmware_name"] == "AN1017"


@pytest.mark.slow
def test_emulator_process_run_matches_inprocess_bytes(tmp_path: Path) -> None:
    """The same bytes whether the firmware runs in-process or as its own process on a pty."""
    config = hurst_bench_config(tmp_path, 0.2)
    rows = {}
    for spec in ("inprocess:an1017", "emulator:an1017"):
        out = tmp_path / f"{spec.split(':')[0]}.csv"
        result = run_cli("run", str(config), "--target", spec, "--no-ui", "--no-control", "--record", str(out), timeout=120)
        assert result.returncode == 0, result.stderr
        rows[spec] = [ln for ln in out.read_text().splitlines() if not ln.startswith("# ")]
        assert len(rows[spec]) == 4001
    assert rows["inprocess:an1017"] == rows["emulator:an1017"]


@pytest.mark.slow
def test_default_run_follows_every_reference_within_2_percent() -> None:
    """README's main job: the default bench (emulator process, Hurst, default scenario)."""
    result = run_cli("run", "--json", "--no-control", timeout=600)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    refs = [s["ref_rpm"] for s in summary["segments"]]
    assert refs == [1500.0, 2500.0, -1500.0]
    for segment in summary["segments"]:
        assert abs(segment["error_pct"]) <= 2.0, segment
    assert summary["link"]["crc_errors"] == 0


def _start_run(tmp_path: Path, record: Path, *extra: str) -> subprocess.Popen[str]:
    config = hurst_bench_config(tmp_path, 60.0)
    return subprocess.Popen(
        [sys.executable, "-m", "hilbench", "run", str(config), "--no-ui", "--no-control",
         "--record", str(record), "--set", "link.timeout_ms=500", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT,
    )


def _wait_for_rows(record: Path, proc: subprocess.Popen[str], timeout_s: float = 60.0) -> None:
    """Poll (with a deadline) until the run has flushed its first chunk."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"run ended early: {proc.communicate()}")
        if record.exists() and record.stat().st_size > 50_000:
            return
        time.sleep(0.05)
    raise AssertionError("no rows recorded before the deadline")


def _children(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True, timeout=10)
    return [int(x) for x in out.stdout.split()]


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.slow
@pytest.mark.parametrize("how", ["kill", "silent"])
def test_target_fault_ends_run_with_one_line_and_marked_recording(tmp_path: Path, how: str) -> None:
    record = tmp_path / "fault.csv"
    proc = _start_run(tmp_path, record)
    child = None
    try:
        _wait_for_rows(record, proc)
        children = _children(proc.pid)
        assert len(children) == 1
        child = children[0]
        os.kill(child, signal.SIGKILL if how == "kill" else signal.SIGSTOP)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
        if child is not None and not _gone(child):
            os.kill(child, signal.SIGKILL)
    assert proc.returncode == 4
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    assert "link error" in lines[0] and "last good period" in lines[0]
    assert child is not None
    deadline = time.monotonic() + 10
    while not _gone(child) and time.monotonic() < deadline:  # reaped by the run before it exited
        time.sleep(0.02)
    assert _gone(child)
    data = read_recording(record)
    assert data.n_rows > 1000
    assert data.columns["marker"][-1] == MARKER_FAULT
    assert any(e.startswith("fault at period") for e in data.events)


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_ctrl_c_stops_cleanly(tmp_path: Path, suffix: str) -> None:
    """Ctrl-C: exit 130, one line, children reaped, the recording readable with its end noted (a
    CSV's rows written by its writer's thread up to the interrupt, events after them)."""
    record = tmp_path / f"int{suffix}"
    proc = _start_run(tmp_path, record)
    try:
        _wait_for_rows(Path(str(record) + ".journal") if suffix == ".npz" else record, proc)
        children = _children(proc.pid)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    assert proc.returncode == 130
    assert "Traceback" not in stderr
    assert stderr.strip() == "hilbench: interrupted"
    for child in children:
        assert _gone(child)
    data = read_recording(record)
    assert data.n_rows > 1000
    assert data.metadata["end"].startswith("interrupted") if suffix == ".npz" else \
        data.events[-1].startswith("interrupted")
    assert np.all(np.diff(data.columns["seq"]) == 1)  # every row up to the interrupt, none twice


@pytest.mark.parametrize(
    ("args", "code", "needle"),
    [
        (("run", "no/such/file.toml"), 2, "cannot read"),
        (("run", "--target", "emulator:nosuch"), 2, "unknown target"),
        (("run", "--target", "bogus"), 2, "unknown target spec"),
        (("run", "--target", "serial:/dev/ttyNOSUCH0"), 4, "/dev/ttyNOSUCH0"),
        (("run", "--set", "motor.rs_ohm=-1"), 2, "rs_ohm"),
        (("run", "--set", "nonsense"), 2, "TABLE.KEY=VALUE"),
        (("report", "no/such/run.csv"), 6, "no such file"),
    ],
)
def test_cli_errors_are_one_line_and_nonzero(args: tuple[str, ...], code: int, needle: str) -> None:
    result = run_cli(*args, "--no-ui", "--no-control") if args[0] == "run" else run_cli(*args)
    assert result.returncode == code, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr
    assert needle in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def test_bad_config_file_reports_every_problem(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[motor]\nrs_ohm = -2\npole_pairs = 5\nj_kgm2 = 1e-5\nl_h = 1e-3\nke_v_per_krpm = 7\n'
                   '[link]\nperiod_uss = 50\n[[scenario]]\nat_s = 0.1\nref_rpm = 1000\npress = "s2"\n')
    result = run_cli("run", str(bad), "--no-ui", "--no-control")
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "rs_ohm" in result.stderr and "period_uss" in result.stderr and "did you mean" in result.stderr
    assert "exactly one action" in result.stderr


def test_unreadable_recording_is_one_line(tmp_path: Path) -> None:
    junk = tmp_path / "junk.csv"
    junk.write_text("not,a,recording\n")
    result = run_cli("report", str(junk))
    assert result.returncode == 6
    assert "not a hilbench CSV" in result.stderr


@pytest.mark.parametrize("spec", ["sil:/tmp/a\\build/fw", 'exec:/tmp/with "quotes"/target', "sil:/tmp/tab\\there"])
def test_a_target_spec_reaches_the_config_as_written(spec: str) -> None:
    """--target and Bench(target=...) hand the spec over as a TOML string: its backslashes and quotes
    are the spec's own (``sil:/tmp/a\\build`` used to become "sil:/tmp/a" + a backspace + "uild",
    a quote a config error about the packaged config)."""
    import hilbench
    from hilbench.bench.bench import as_config

    assert load_run_config(RunRequest(target=spec)).link.target == spec
    assert as_config(None, spec, ()).link.target == spec
    assert hilbench.Bench(target=spec).config.link.target == spec
