"""Issue 23: command-line repros. `link-test emulator:nope` is "unknown target" (exit 2) as in
`run`; a bad `--hil-target` is one usage error, not an error per test; `emulate --port tcp:0`
serves one host after another."""

from __future__ import annotations

import os
import select
import subprocess
import sys
from pathlib import Path

import pytest

from _hostile import REPO_ROOT, assert_one_line_error, hilbench
from hilbench.link import open_link
from hilbench.processes import reap
from hilbench.targets.remote import RemoteTarget

TIMEOUT_S = 30.0


def test_link_test_names_an_unknown_target_as_run_does() -> None:
    """Repro: `link-test emulator:nope` said "no TargetHello after 5 HostHello attempts" (exit 4)."""
    line = assert_one_line_error(hilbench("link-test", "emulator:nope"), 2, "unknown target 'nope'")
    run = hilbench("run", "--target", "emulator:nope", "--no-ui", "--no-control")
    assert_one_line_error(run, 2, "unknown target 'nope'")
    assert line.startswith("hilbench: config error:")


@pytest.mark.parametrize("kind", ["missing", "not executable"])
def test_link_test_names_an_exec_program_it_cannot_run(kind: str, tmp_path: Path) -> None:
    """Repro: `link-test exec:/nonexistent/target` printed "file error" with exit 1 (an OSError
    past the error hierarchy); a program that is missing or not executable is a config error, as
    `sil:PATH` says it."""
    program = str(tmp_path / "target")
    if kind == "not executable":
        Path(program).write_text("not a program\n")
        os.chmod(program, 0o644)
    line = assert_one_line_error(hilbench("link-test", f"exec:{program}", "--periods", "10"), 2,
                                 f"exec:{program}: no program to run there")
    assert line.startswith("hilbench: config error:")


@pytest.mark.slow
def test_link_test_starts_an_emulator_spec_as_run_does() -> None:
    """`link-test emulator:an1017` used to open a pty with nobody at its far end."""
    result = hilbench("link-test", "emulator:an1017", "--periods", "200")
    assert result.returncode == 0, result.stderr
    assert "200 / 200" in result.stdout


TINY_TEST = """
def test_one(bench):
    assert bench.hello

def test_two(bench):
    assert bench.hello
"""


@pytest.mark.parametrize("option, words", [
    (("--hil-target", "emulator:nope"), ("ERROR: --hil-target emulator:nope: unknown target 'nope'",)),
    (("--hil-target", "nonsense spec"), ("ERROR: --hil-target nonsense spec: unknown target spec",)),
    (("--hil-config", "/dev/zero"), ("ERROR: --hil-config: /dev/zero: more than the limit of 1 MiB",)),
])
def test_a_bad_hil_option_is_one_usage_error(tmp_path: Path, option: tuple[str, ...], words: tuple[str, ...]) -> None:
    """Repro: a bad `--hil-target` errored every test at setup with a traceback."""
    (tmp_path / "test_tiny.py").write_text(TINY_TEST)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *option, "test_tiny.py"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 4  # pytest's usage error
    assert "Traceback" not in result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and all(w in lines[0] for w in words), result.stderr
    assert "test_one" not in result.stdout  # no test ran


def _first_line(proc: subprocess.Popen[bytes]) -> str:
    assert proc.stdout is not None
    buf = b""
    while not buf.endswith(b"\n"):
        ready, _, _ = select.select([proc.stdout], [], [], TIMEOUT_S)
        assert ready, "emulate printed nothing"
        chunk = os.read(proc.stdout.fileno(), 1024)
        assert chunk, "emulate exited early"
        buf += chunk
    return buf.decode().strip()


@pytest.mark.slow
def test_emulate_on_tcp_keeps_serving_after_the_first_host() -> None:
    """Repro: `hilbench emulate --port tcp:0` ended after its first client."""
    proc = subprocess.Popen([sys.executable, "-P", "-m", "hilbench", "emulate", "an1017", "--port", "tcp:0", "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO_ROOT)
    try:
        url = _first_line(proc)
        assert url.startswith("socket://127.0.0.1:")
        for _ in range(3):  # one host after another
            link = open_link(url, timeout_s=2.0)
            try:
                hello = RemoteTarget(link, timeout_s=2.0).handshake(50)
                assert hello.firmware_name == "AN1017"
            finally:
                link.close()
        assert proc.poll() is None
    finally:
        reap(proc)
        assert b"Traceback" not in proc.stderr.read()  # type: ignore[union-attr]
        proc.stdout.close()  # type: ignore[union-attr]
        proc.stderr.close()  # type: ignore[union-attr]


@pytest.mark.slow
def test_emulate_on_tcp_once_ends_after_the_first_host() -> None:
    proc = subprocess.Popen([sys.executable, "-P", "-m", "hilbench", "emulate", "loopback", "--port", "tcp:0", "--once",
                             "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO_ROOT)
    try:
        link = open_link(_first_line(proc), timeout_s=2.0)
        try:
            assert RemoteTarget(link, timeout_s=2.0).handshake(50).firmware_name == "loopback"
        finally:
            link.close()
        assert proc.wait(TIMEOUT_S) == 0
    finally:
        reap(proc)
        proc.stdout.close()  # type: ignore[union-attr]
        proc.stderr.close()  # type: ignore[union-attr]


def _assert_usage_error(result: subprocess.CompletedProcess[str], *words: str) -> str:
    """click's usage error for an option value: exit 2, no traceback, one `Error:` line holding every word."""
    err = result.stderr
    assert "Traceback" not in err, err[-3000:]
    assert result.returncode == 2, f"exit {result.returncode}, stderr: {err[-2000:]}"
    errors = [line for line in err.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, err[-2000:]
    for word in words:
        assert word in errors[0], f"{word!r} not in {errors[0]!r}"
    return errors[0]


@pytest.mark.parametrize("value, words", [
    ("nan", ("'--timeout'", "nan is not a finite number of seconds")),
    ("inf", ("'--timeout'", "inf is not a finite number of seconds")),
    ("1e308", ("'--timeout'", "not in the range")),
])
def test_ctl_refuses_a_timeout_that_is_not_a_sane_number(value: str, words: tuple[str, ...], tmp_path: Path) -> None:
    """Repro: `ctl --timeout nan|inf|1e308 get` with a session running ended in a traceback at the
    socket's settimeout; the option is refused as it is parsed, before any session is looked up
    (HOME has none here: the lookup would fail with a link error instead)."""
    env = {**os.environ, "HOME": str(tmp_path), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    _assert_usage_error(hilbench("ctl", "--timeout", value, "get", env=env), *words)


@pytest.mark.parametrize("args, words", [
    (("step", "--from", "nan"), ("'--from'", "nan is not a finite number of rpm")),
    (("step", "--to", "inf"), ("'--to'", "inf is not a finite number of rpm")),
    (("step", "--from", "1e308"), ("'--from'", "not in the range -20000<=x<=20000")),
    (("step", "--after", "inf"), ("'--after'", "inf is not a finite number of seconds")),
    (("step", "--settle", "1e308"), ("'--settle'", "not in the range")),
    (("sweep", "--from", "nan"), ("'--from'", "nan is not a finite number of rpm")),
    (("sweep", "--to", "inf"), ("'--to'", "inf is not a finite number of rpm")),
    (("sweep", "--duration", "inf"), ("'--duration'", "inf is not a finite number of seconds")),
    (("sweep", "--step-at", "nan"), ("'--step-at'", "nan is not a finite number of seconds")),
])
def test_step_and_sweep_refuse_speeds_and_times_that_are_not_sane_numbers(args: tuple[str, ...],
                                                                          words: tuple[str, ...]) -> None:
    """Repro: `step --from nan`, `--to inf`, `--after inf`, `sweep --duration inf` ended in a
    ValueError or OverflowError traceback deep in the plant or the reference's pot code."""
    _assert_usage_error(hilbench(*args), *words)


@pytest.mark.slow
def test_link_test_fails_when_the_target_goes_silent() -> None:
    """Repro: a target silent after 5 frames gave periods 4/10 and "8 errors counted", exit 0. The
    table is still printed; the exit code is the link error's. (Silent after 12 frames: a slow start
    on a loaded machine costs a few HostHellos of them, not the whole handshake.)"""
    result = hilbench("link-test", "emulator:loopback?silent_after=12", "--periods", "20", "--timeout-ms", "250")
    assert_one_line_error(result, 4, "hilbench: link error: link-test emulator:loopback?silent_after=12",
                          "of 20 periods got no Drive")
    assert "periods (good / asked)" in result.stdout


@pytest.mark.parametrize("json_flag", [(), ("--json",)])
def test_conformance_refuses_an_only_that_names_no_check(json_flag: tuple[str, ...]) -> None:
    """Repro: `conformance inprocess:an1017 --only zzzz` printed an empty table and exited 0."""
    result = hilbench("conformance", "inprocess:an1017", "--only", "handshake", "--only", "zzzz", *json_flag)
    line = assert_one_line_error(result, 2, "hilbench: config error: conformance --only 'zzzz'", "'handshake'",
                                 "'stop and start'")
    assert "'handshake'" not in line.split(":")[2]  # a name that matches is not called unknown
    assert result.stdout == ""


@pytest.mark.parametrize("target, words", [
    ((), ("--option zz: not an option of target 'an1017'", "known: variant")),
    (("loopback",), ("--option zz: not an option of target 'loopback'", "it takes no options")),
])
def test_emulate_refuses_an_unknown_option_name(target: tuple[str, ...], words: tuple[str, ...]) -> None:
    """Repro: `emulate -o zz=1 --once` dropped the unknown name and served (a bad value was refused)."""
    assert_one_line_error(hilbench("emulate", *target, "-o", "zz=1", "--once", timeout_s=30), 2, *words)


@pytest.mark.parametrize("word, reason", [
    ("kp=abc", "expected a number, got str 'abc'"),
    ("kp=nan", "expected a finite number, got nan"),
    ("kp=5", "5.0 is out of range"),
])
def test_emulate_checks_an_option_value_as_the_config_does(word: str, reason: str) -> None:
    """Repro (second audit): `emulate -o kp=abc` (nan, 5) served with the value taken as it came."""
    assert_one_line_error(hilbench("emulate", "-o", word, "--once", timeout_s=30), 2, "-o kp [target] kp:", reason)
