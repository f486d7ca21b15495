"""Issue 16: CLI behaviour a user trips over (items 6, 11, 13, 14, 15, 16)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def _run(args: list[str], cwd: Path, timeout_s: float = 120) -> subprocess.CompletedProcess[str]:
    proc = subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


@pytest.mark.slow
def test_item6_a_hilbench_folder_in_the_working_directory_does_not_shadow_the_package(tmp_path: Path) -> None:
    """Item 6: `hilbench run` from a directory holding `hilbench/` failed (exit 4, ImportError in the
    emulator child: its `python -m` put the working directory first on the import path)."""
    shadow = tmp_path / "hilbench"
    shadow.mkdir()
    (shadow / "__init__.py").write_text("raise ImportError('the shadowing folder was imported')\n")
    result = _run([sys.executable, "-P", "-m", "hilbench", "run", "--target", "emulator:an1017", "--duration", "0.02",
                   "--no-ui", "--no-control"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "shadowing" not in result.stderr


def _scenario_config(tmp_path: Path, duration: str) -> Path:
    from hilbench.config import default_config_text

    path = tmp_path / "ends.toml"
    path.write_text(default_config_text() + f"""
[run]
{duration}

[[scenario]]
at_s = 0.0
ref_rpm = 1000.0

[[scenario]]
at_s = 0.01
press = "s2"

[[scenario]]
at_s = 0.1
end = true
""")
    return path


def test_item11_duration_wins_over_the_scenario_end(tmp_path: Path) -> None:
    """Item 11: `run --duration 20` stopped at the scenario's end (3.8 s) while the bar read /20 s."""
    from hilbench.bench.run import RunRequest, load_run_config, run_bench

    cfg = load_run_config(RunRequest(str(_scenario_config(tmp_path, "")), target="inprocess:an1017", duration_s=0.3))
    summary = run_bench(cfg)
    assert summary.sim_s == pytest.approx(0.3) and summary.end_reason == "completed"
    cfg = load_run_config(RunRequest(str(_scenario_config(tmp_path, "")), target="inprocess:an1017"))
    summary = run_bench(cfg)  # without a duration the scenario's end ends the run
    assert summary.sim_s == pytest.approx(0.1)


def test_item11_ctl_press_and_start() -> None:
    """Item 11: there was no way to restart the motor from `ctl` (no start, no press)."""
    from typing import Any

    import hilbench
    from hilbench.bench.control import parse_ctl_args, validate_request

    assert parse_ctl_args(["press", "S2"]) == {"cmd": "press", "button": "s2"}
    assert parse_ctl_args(["start"]) == {"cmd": "start"}
    with pytest.raises(ValueError):
        validate_request({"cmd": "press", "button": "s9"})

    class Request:
        def __init__(self, cmd: str, args: dict[str, Any]) -> None:
            self.cmd, self.args, self.replies = cmd, args, []

        def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None:
            self.replies.append((ok, text))

    with hilbench.Bench(target="inprocess:an1017") as bench:
        session = bench._session
        bench.set_reference(1200)
        press = Request("press", {"button": "s2"})
        session.handle_control(press, bench.t_s)
        bench.run(0.6)
        assert press.replies[0][0] and bench.speed_rpm > 600  # S2 from ctl started the motor
        session.handle_control(Request("press", {"button": "s2"}), bench.t_s)
        bench.run(0.6)
        assert bench.speed_rpm < 300  # and stopped it
        start = Request("start", {})
        session.handle_control(start, bench.t_s)
        bench.run(0.6)
        assert start.replies[0][0] and bench.speed_rpm > 600  # the Start command restarted it


def test_item13_ctl_save_answered_by_the_session_itself(tmp_path: Path) -> None:
    """Item 13: `save` was "not available in this session" when no dashboard was there to do it."""
    from typing import Any

    import hilbench

    class Request:
        def __init__(self, cmd: str, args: dict[str, Any]) -> None:
            self.cmd, self.args, self.replies = cmd, args, []

        def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None:
            self.replies.append((ok, text))

    with hilbench.Bench(target="inprocess:an1017") as bench:
        save = Request("save", {"file": str(tmp_path / "gains.toml")})
        bench._session.handle_control(save, bench.t_s)
        bad = Request("save", {"file": str(tmp_path / "gains.toml" / "x")})
        bench._session.handle_control(bad, bench.t_s)
    assert save.replies[0][0] and (tmp_path / "gains.toml").read_text().startswith("[target]\nkp = 0.100006")
    assert not bad.replies[0][0] and "\n" not in bad.replies[0][1]


def test_item15_sweep_save_leaves_no_empty_file_and_names_the_option(tmp_path: Path) -> None:
    """Item 15: `--save` left an empty file when nothing was simulated; a bad axis read
    "sweep ----kp '0.1:0.2'"."""
    from click.testing import CliRunner

    from hilbench.cli import cli

    save = tmp_path / "best.toml"
    result = CliRunner().invoke(cli, ["sweep", "-p", "kp=0.9", "-p", "ki=0.5", "-p", "kd=0", "--workers", "1",
                                      "--save", str(save)])
    assert result.exit_code == 2 and "no simulated parameter set" in result.stderr
    assert not save.exists()
    for word in ("--kp=0.1:0.2:2", "kp=0.1:0.2"):
        result = CliRunner().invoke(cli, ["sweep", "-p", word, "--workers", "1"])
        assert result.exit_code == 2 and "----" not in result.stderr and "sweep --param" in result.stderr


def test_item15_step_refuses_a_target_without_a_speed_loop() -> None:
    """Item 15: `step --target emulator:loopback` printed a 199.99 % steady-state error and exited 0."""
    from click.testing import CliRunner

    from hilbench.cli import cli

    result = CliRunner().invoke(cli, ["step", "--target", "inprocess:loopback"])
    assert result.exit_code != 0 and "speed" in result.stderr and len(result.stderr.splitlines()) == 1


@pytest.mark.slow
def test_item14_emulate_serves_host_after_host() -> None:
    """Item 14: `emulate` served one host session and exited ("far end hung up" twice)."""
    import queue
    import threading

    from hilbench.bench.linktest import run_link_test
    from hilbench.targets.emulator import serve_on_port

    paths: queue.Queue[str] = queue.Queue()
    stop = threading.Event()
    reports: list = []
    thread = threading.Thread(target=lambda: reports.append(serve_on_port(
        "loopback", "pty", None, None, announce=paths.put, stop_event=stop, keep_serving=True)), daemon=True)
    thread.start()
    try:
        path = paths.get(timeout=20)
        for _ in range(3):  # three hosts, one after another, each opening and closing the port
            result = run_link_test(f"serial:{path}", periods=200, period_us=50, timeout_s=2.0)
            assert result.good == 200 and result.timeouts == 0
        assert thread.is_alive()
    finally:
        stop.set()
        thread.join(timeout=20)
    assert not thread.is_alive() and reports and reports[0].reason == "stopped"
    assert reports[0].sensors == 600


def test_item12_impossible_and_doubtful_settings_said_before_the_run() -> None:
    """Item 12: realtime at 50 us ran with 97.5 % overruns and exited 0; at 1 ms periods the hall edge
    rate at 2500 rpm (2500/60 * 5 pole pairs * 6 = 1250 edges/s) exceeded 1000 exchanges/s silently."""
    from hilbench.bench.feasibility import check_run, overrun_warning
    from hilbench.bench.settings import load_config
    from hilbench.errors import ConfigError

    # protocol 3 carries every edge of a period: 1 ms at 2500 rpm (1250 edges/s) is fine now
    assert check_run(load_config(None, ["link.period_us=1000"])) == []
    assert check_run(load_config(None)) == []  # 50 us: 20000 exchanges/s
    # 6 ms at 2500 rpm on a 20-pole-pair motor: up to 32 edges, more than the 16 a Sensors carries
    warnings = check_run(load_config(None, ["link.period_us=6000", "motor.pole_pairs=20"]))
    assert any("holds up to 32 hall edges" in w and "link.period_us <= 2800" in w for w in warnings), warnings
    warnings = check_run(load_config(None, ['run.mode="realtime"']))
    assert any("real time at 50 us" in w for w in warnings)
    # 45 bytes per exchange (22 + 23 at their largest with an edge) * 10 bits at 9600 baud = 47 ms > 1 ms
    with pytest.raises(ConfigError, match="9600 baud"):
        check_run(load_config(None, ['run.mode="realtime"', 'link.target="serial:/dev/ttyX?baud=9600"',
                                     "link.period_us=1000"]))
    assert overrun_warning(1000, 975).startswith("real time NOT held: 975 of 1000 periods (97.5 %)")
    assert overrun_warning(1000, 10) is None


def test_item17_no_ui_summary_has_the_parameters_line(tmp_path: Path) -> None:
    """Item 17: --no-ui omitted the parameters line the dashboard's table has."""
    from click.testing import CliRunner

    from hilbench.cli import cli

    result = CliRunner().invoke(cli, ["run", "--no-ui", "--no-control", "--target", "inprocess:an1017", "--duration", "0.01"])
    assert result.exit_code == 0 and "parameters: kp 0.10001, ki 0.01001" in result.stdout


@pytest.mark.slow
def test_item18_link_test_keeps_its_figures_on_ctrl_c(monkeypatch: pytest.MonkeyPatch) -> None:
    """Item 18: Ctrl-C during `link-test` lost every figure; progress is reported as it goes."""
    from hilbench.bench.linktest import run_link_test
    from hilbench.targets.remote import RemoteTarget

    real_step = RemoteTarget.step
    calls = {"n": 0}

    def step(self: RemoteTarget, sensors):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == 501:
            raise KeyboardInterrupt
        return real_step(self, sensors)

    monkeypatch.setattr(RemoteTarget, "step", step)
    seen: list[int] = []
    result = run_link_test("pty", periods=2000, timeout_s=2.0, progress=seen.append)
    assert result.interrupted and result.attempted == 500 and result.good == 500
    assert result.rtt_p50_us > 0 and seen[:3] == [0, 20, 40]  # progress every 1 % of 2000


def test_item17_dashboard_fits_80x24_with_a_scale_and_no_stale_values() -> None:
    """Item 17: at 80x24 the dashboard wrapped rows; the sparkline had no scale; after a stop it
    showed stale firmware speed and duties as if they applied."""
    import io

    from rich.console import Console

    import hilbench
    from hilbench.ui.dashboard import render_snapshot

    snaps: list = []
    with hilbench.Bench(target="inprocess:an1017", observer=snaps.append) as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.6)
        bench.press("s2")  # stop
        bench.run(0.3)
    running, stopped = snaps[len(snaps) // 2], snaps[-1]
    for snap in (running, stopped):
        out = io.StringIO()
        Console(file=out, width=80, height=24, color_system=None).print(
            render_snapshot(snap, {"kp": 0.1, "ki": 0.01, "kd": 0.0}, "inprocess:an1017", 80))
        lines = out.getvalue().splitlines()
        assert all(len(line) <= 80 for line in lines) and len(lines) <= 24 - 3, lines  # + progress and prompt
        assert " rpm" in next(line for line in lines if "speed (plant), the last" in line).split("the last")[1]
    text = out.getvalue()
    assert stopped.output_mode == 0 and "(outputs off)" in text and "(held)" in text
