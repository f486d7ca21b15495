"""The pytest plugin (hilbench.testing), run through pytester as a user runs it: options and ids,
hil_requires, one-line assertion failures that keep recording and plots, JUnit properties, a
killed emulator process, and the shipped examples on the in-process and emulator targets."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from conftest import REPO_ROOT

pytest_plugins = ["pytester"]

# Loaded here, before pytester's in-process runs: a module first imported inside one is dropped
# from sys.modules after it, while objects made of it live on (the target registry's profiles; a
# later matplotlib import mixing old and new classes: "... must be a three-digit integer, not GridSpec").
import hilbench.bench.bench  # noqa: E402,F401
import hilbench.testing.assertions  # noqa: E402,F401
import hilbench.testing.link  # noqa: E402,F401
import hilbench.testing.steps  # noqa: E402,F401
from hilbench.targets.registry import known_targets  # noqa: E402

known_targets()  # every built-in target's module imported now
try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401

    import hilbench.ui.plots  # noqa: F401
except ImportError:  # no plot extra: the plugin says the plots were skipped
    pass

INPROC = "inprocess:an1017"


def _xml(path: Path) -> ET.Element:
    return ET.parse(path).getroot()


def _suite_props(root: ET.Element) -> dict[str, str]:
    return {p.get("name"): p.get("value") for p in root.iter("testsuite") for p in p.findall("properties/property")}


def _cases(root: ET.Element) -> dict[str, ET.Element]:
    return {c.get("name"): c for c in root.iter("testcase")}


def _case_props(case: ET.Element) -> list[tuple[str, str]]:
    return [(p.get("name"), p.get("value")) for p in case.findall("properties/property")]


def test_tests_run_once_per_target_with_readable_ids(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_hilx_ids="""
        def test_a(bench, hil_target):
            assert bench.hello.firmware_name and hil_target.startswith("inprocess:")

        def test_plain():
            pass
    """)
    result = pytester.runpytest("--hil-target", INPROC, "--hil-target", "inprocess:loopback", "-v", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines(["*test_a?inprocess-an1017? PASSED*", "*test_a?inprocess-loopback? PASSED*",
                                 "*test_plain PASSED*"])


def test_the_target_comes_from_the_environment_then_the_config(pytester: pytest.Pytester,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    pytester.makepyfile(test_hilx_env="""
        def test_a(hil_target, hil_config):
            assert hil_config.link.target == hil_target
    """)
    monkeypatch.setenv("HILBENCH_TARGET", "inprocess:an1017, inprocess:loopback")
    result = pytester.runpytest("-v", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines(["*test_a?inprocess-an1017?*", "*test_a?inprocess-loopback?*"])
    monkeypatch.delenv("HILBENCH_TARGET")
    config = pytester.path / "bench.toml"
    config.write_text((REPO_ROOT / "bench_configs" / "hurst_mclv.toml").read_text()
                      + '\n[link]\ntarget = "inprocess:loopback"\n')
    result = pytester.runpytest("-v", "-p", "no:cacheprovider", "--hil-config", str(config))
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["*test_a?inprocess-loopback? PASSED*"])


def test_a_test_may_pin_its_own_targets_indirectly(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_hilx_pin="""
        import pytest

        @pytest.mark.parametrize("hil_target", ["inprocess:loopback"], indirect=True)
        def test_pinned(bench):
            assert bench.hello.firmware_name == "loopback"
    """)
    result = pytester.runpytest("--hil-target", INPROC, "-v", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)


def test_hil_requires_skips_with_the_reason(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_hilx_req="""
        from hilbench.testing import hil_requires

        @hil_requires("speed_loop")
        def test_loop(bench):
            pass

        @hil_requires(firmware="AN1017")
        def test_fw(hil_target):
            pass

        @hil_requires("link")
        def test_link(hil_target):
            pass
    """)
    result = pytester.runpytest("--hil-target", INPROC, "--hil-target", "inprocess:loopback", "-rs", "-p", "no:cacheprovider")
    # loopback: no speed loop, not AN1017; in-process targets have no link
    result.assert_outcomes(passed=2, skipped=4)
    result.stdout.fnmatch_lines([
        "*target inprocess:loopback lacks speed_loop (has: inprocess, link_check, realtime, tuning)*",
        "*target inprocess:loopback runs loopback, not AN1017*",
        "*target inprocess:an1017 lacks link*",
    ])


def test_a_failing_bound_fails_in_one_line_and_keeps_recording_and_plots(pytester: pytest.Pytester) -> None:
    """The acceptance's deliberately failing example: a band tighter than the firmware reaches."""
    pytester.makepyfile(test_hilx_tight="""
        from hilbench.testing import assert_settles

        def test_too_tight(bench):
            bench.set_reference(1500)
            bench.press("s2")
            bench.run(1.0)
            assert_settles(bench, "speed_rpm", 1500, band=1.0, by_s=0.8)

        def test_passes(bench):
            bench.run(0.01)
    """)
    result = pytester.runpytest("--hil-target", INPROC, "--junitxml", "r.xml", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=1)
    errors = [line for line in result.stdout.lines if line.startswith("E ")]
    assert len(errors) == 1, errors  # one line: signal, window, bound, worst value
    assert re.fullmatch(r"E\s+AssertionError: speed_rpm not within 1500 ± 1 rpm over 0\.800-1\.000 s: "
                        r"worst 1\d{3}\.\d+ rpm \([+-]\d+(\.\d+)?\) at 0\.\d{4} s", errors[0]), errors[0]
    case = _cases(_xml(pytester.path / "r.xml"))["test_too_tight[inprocess-an1017]"]
    props = _case_props(case)
    recordings = [v for k, v in props if k == "hil_recording"]
    plots = [v for k, v in props if k == "hil_plot"]
    assert len(recordings) == 1 and Path(recordings[0]).is_file()
    from hilbench.bench.recorder import read_recording

    data = read_recording(recordings[0])
    assert data.n_rows == 20_000  # 1 s at 50 us: the whole run is kept
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        assert not plots and "plots skipped" in result.stdout.str()
    else:
        assert plots and all(Path(p).is_file() and Path(p).stat().st_size > 1000 for p in plots)
    system_out = case.find("system-out").text
    for path in recordings + plots:
        assert f"[[ATTACHMENT|{path}]]" in system_out
    assert any(k == "hil.speed_rpm.dev_from_0.8s" for k, _ in props)  # the judged figure is a property
    # the passing test kept nothing (no --hil-record)
    passed = _cases(_xml(pytester.path / "r.xml"))["test_passes[inprocess-an1017]"]
    assert not [k for k, _ in _case_props(passed) if k == "hil_recording"]
    assert not Path(recordings[0]).parent.with_name("test_passes_inprocess-an1017").exists()


def test_hil_record_keeps_every_recording(pytester: pytest.Pytester, tmp_path: Path) -> None:
    pytester.makepyfile(test_hilx_rec="""
        def test_one(bench):
            bench.run(0.02)
    """)
    out = tmp_path / "recs"
    result = pytester.runpytest("--hil-target", INPROC, "--hil-record", str(out), "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)
    kept = sorted(out.rglob("*.npz"))
    assert [p.parent.name for p in kept] == ["test_one_inprocess-an1017"]
    from hilbench.bench.recorder import read_recording

    assert read_recording(kept[0]).n_rows == 400


def test_hil_record_onto_a_file_is_one_usage_error(pytester: pytest.Pytester, tmp_path: Path) -> None:
    """Third audit: every test errored with NotADirectoryError."""
    pytester.makepyfile(test_hilx_recfile="""
        def test_one(bench):
            bench.run(0.02)
    """)
    taken = tmp_path / "a_file"
    taken.write_text("mine\n")
    result = pytester.runpytest("--hil-target", INPROC, "--hil-record", str(taken), "-p", "no:cacheprovider")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"ERROR: --hil-record {taken}: not a folder*"])
    assert taken.read_text() == "mine\n"


def test_suite_and_test_properties_in_junit(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_hilx_props="""
        from hilbench.testing import assert_within

        def test_speed(bench):
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(0.3)
            worst = assert_within(bench, "speed_rpm", max=1100)  # with only a max: the top speed
            assert worst == bench.signals()["speed_rpm"].max()
    """)
    result = pytester.runpytest("--hil-target", INPROC, "--junitxml", "r.xml", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)
    root = _xml(pytester.path / "r.xml")
    suite = _suite_props(root)
    from hilbench import __version__
    from hilbench.protocol import PROTOCOL_VERSION

    assert suite["hil_target[inprocess-an1017]"] == INPROC
    assert suite["firmware[inprocess-an1017]"].startswith("AN1017 version ")
    assert suite["protocol_version"] == str(PROTOCOL_VERSION) and suite["hilbench_version"] == __version__
    assert re.fullmatch(r"[0-9a-f]{16}", suite["hil_config_sha256"])
    import hilbench.protocol as protocol

    if hasattr(protocol, "SCHEMA_FINGERPRINT"):  # host and target agree (the handshake checks it)
        assert suite["schema_fingerprint"] == f"0x{protocol.SCHEMA_FINGERPRINT:08x}"
        assert suite["schema_fingerprint[inprocess-an1017]"] == suite["schema_fingerprint"]
    props = dict(_case_props(_cases(root)["test_speed[inprocess-an1017]"]))
    assert props["hil_target"] == INPROC and 300 < float(props["hil.speed_rpm.worst_from_0s"]) < 1100


def _children_running(module: str) -> list[int]:
    """Processes whose parent is this one and whose command line names ``module`` (zombies too)."""
    found = []
    me = str(os.getpid())
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        ppid = stat.rsplit(")", 1)[1].split()[1]
        if ppid == me and (module in cmdline or " Z " in stat.rsplit(")", 1)[1][:3]):
            found.append(int(entry.name))
    return found


@pytest.mark.slow
def test_a_killed_emulator_fails_its_test_and_the_next_test_gets_a_fresh_one(pytester: pytest.Pytester) -> None:
    pids = pytester.path / "pids.txt"
    pytester.makepyfile(test_hilx_kill=f"""
        import os, signal
        from hilbench.testing import bench_process

        def test_killed(bench):
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(0.05)
            process = bench_process(bench)
            open({str(pids)!r}, "a").write(f"{{process.pid}}\\n")
            os.kill(process.pid, signal.SIGKILL)
            bench.run(0.05)

        def test_next(bench):
            process = bench_process(bench)
            open({str(pids)!r}, "a").write(f"{{process.pid}}\\n")
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(0.05)
            assert process.poll() is None
    """)
    before = _children_running("hilbench.targets.emulator")
    result = pytester.runpytest("--hil-target", "emulator:an1017", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["FAILED *test_killed* - hilbench.errors.Link*"])  # on the link, cleanly
    assert "error" not in result.parseoutcomes()  # no teardown error
    first, second = (int(x) for x in pids.read_text().split())
    assert first != second  # a fresh process for the next test
    for pid in (first, second):
        assert not Path(f"/proc/{pid}").exists(), f"emulator {pid} left behind (or not reaped)"
    assert _children_running("hilbench.targets.emulator") == before


@pytest.mark.slow
def test_the_examples_pass_on_both_targets_and_junit_carries_the_properties(tmp_path: Path) -> None:
    """The acceptance command, with this installation (a fresh venv's `pip install .` is the same
    plugin found through the same entry point)."""
    report = tmp_path / "r.xml"
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "examples/tests", "--hil-target", INPROC, "--hil-target", "emulator:an1017",
         "--junitxml", str(report), "-p", "no:cacheprovider", "-q"],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    root = _xml(report)
    suite = _suite_props(root)
    for tid, spec in (("inprocess-an1017", INPROC), ("emulator-an1017", "emulator:an1017")):
        assert suite[f"hil_target[{tid}]"] == spec
        assert suite[f"firmware[{tid}]"].startswith("AN1017 version ")
    assert {"protocol_version", "hil_config_sha256", "hilbench_version"} <= set(suite)
    cases = _cases(root)
    bench_cases = [name for name in cases if name.endswith(("[inprocess-an1017]", "[emulator-an1017]"))]
    assert len(bench_cases) == 2 * 5  # every bench example on both targets
    for name in bench_cases:
        metrics = [k for k, _ in _case_props(cases[name]) if k.startswith("hil.")]
        if "handshake" not in name:
            assert metrics, f"{name}: no metrics recorded"
    step = dict(_case_props(cases["test_step_1000_to_2000_rpm_within_limits[emulator-an1017]"]))
    assert 0.3 < float(step["hil.step.rise_time_s"]) < 0.45
    assert not list(root.iter("failure")) and not list(root.iter("error"))


@pytest.mark.slow
def test_a_timeout_that_raises_mid_run_still_reaps_the_emulator(pytester: pytest.Pytester) -> None:
    """What pytest-timeout's signal method does: pytest.fail from a SIGALRM handler, inside bench.run."""
    pids = pytester.path / "pids.txt"
    pytester.makepyfile(test_hilx_timeout=f"""
        import signal
        import pytest
        from hilbench.testing import bench_process

        def _timeout(signum, frame):
            pytest.fail("Timeout >0.5s")

        def test_slow(bench):
            open({str(pids)!r}, "a").write(f"{{bench_process(bench).pid}}\\n")
            signal.signal(signal.SIGALRM, _timeout)
            signal.setitimer(signal.ITIMER_REAL, 0.5)
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(60.0)  # far longer than the timeout
    """)
    before = _children_running("hilbench.targets.emulator")
    result = pytester.runpytest("--hil-target", "emulator:an1017", "-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["E       Failed: Timeout >0.5s", "FAILED *test_slow* - Failed: Timeout*"])
    pid = int(pids.read_text())
    assert not Path(f"/proc/{pid}").exists(), f"emulator {pid} left behind (or not reaped)"
    assert _children_running("hilbench.targets.emulator") == before


def test_hil_open_plays_the_config_scenario_and_its_checks(pytester: pytest.Pytester) -> None:
    """assert_config_checks judges the config's [[check]] tables on a bench that ran its scenario."""
    pytester.makepyfile(test_hilx_scenario="""
        import pytest
        from hilbench.testing import assert_config_checks

        def test_default_scenario_holds(hil_open):
            bench = hil_open(["run.duration_s=3.8"], scenario=True)
            bench.run()
            results = assert_config_checks(bench)
            assert len(results) == 5

        def test_a_runaway_fails_its_checks(hil_open):  # the board's protections off: the checks see it
            bench = hil_open(["protection.overspeed_rpm=0", "protection.overcurrent_a=0"], scenario=True)
            bench.run(0.8)
            bench.set_load(0.5)
            bench.run()
            assert_config_checks(bench)
    """)
    result = pytester.runpytest("--hil-target", INPROC, "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=1)
    errors = [line for line in result.stdout.lines if line.startswith("E ")]
    assert len(errors) == 1 and "check speed_error: worst" in errors[0] and "check speed_limit: max" in errors[0]
