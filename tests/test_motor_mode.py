"""Issue 24, the real motor tested without a board, at the pin level: the AVR real-motor build
(make MODE=motor: halls on INT0..2, the duties on Timer3's compare units, HostHello mode MONITOR)
runs free on its own simulated timers in simavr, its pins wired to hilbench's plant by run_motor.c;
hilbench talks to it in monitor mode over the pty: a live gain write and a speed step, recorded.
The same scenario runs in lockstep HIL (the same firmware source in process, the same plant config,
a period of one PWM period: the plant steps as in the harness) and the step's figures, from the
firmware's own measured speed in both, must agree within the tolerances below.

Why the tolerance is not zero (each a real difference between a chip and a lockstep exchange):
- hall edges: lockstep hands the firmware every edge's exact time; on the pins the firmware reads
  Timer1 in the INT0..2 interrupt, which waits for a running PWM interrupt (~26 us at 80 MHz): the
  measured period, hence the measured speed and the loop, jitter by up to that much;
- duties: the AVR's compare units have 4 000 steps per period at 80 MHz against the firmware's 1 000
  counts (exact), but the compare takes the registers at the timer's BOTTOM while the ISR writes them
  some microseconds later than a lockstep span's boundary: the same one-period latency, not the same
  instant;
- the Timer1 speed loop is served at PWM-period resolution in real time (the runtime's soft timer:
  up to 50 us late), in lockstep at its exact tick;
- the host writes the step's reference when it reads the row at the step's time: the board's clock
  has moved on by the link's latency (in simulated time small, the simulation being slower than the
  wall), and rows come every 5 ms (the figures are read on that grid), lockstep's every 50 us.
Rise time within 10 ms + 15 %, overshoot within 5 percentage points, the final speed within 2 % of
the step.
"""

from __future__ import annotations

import json
import math
import os
import select
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _firmware import python_config, require_file, require_tool
from hilbench.bench.control import ControlRequest
from hilbench.bench.monitorrun import analyse_measured
from hilbench.bench.recorder import read_recording
from hilbench.bench.steptest import StepTest
from hilbench.processes import reap, spawn
from hilbench.targets.an1017 import PROFILE, pot_code_for_rpm, rpm_for_pot_code
from hilbench.targets.sil import FIRMWARE_DIR

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
AVR_DIR = FIRMWARE_DIR / "ports" / "avr"
#: the step's speeds, each exactly on a pot code (lockstep's reference is the pot, monitor's the override)
FROM_RPM = rpm_for_pot_code(pot_code_for_rpm(1000.0))
TO_RPM = rpm_for_pot_code(pot_code_for_rpm(1500.0))
SETTLE_S = 1.0
AFTER_S = 0.8
KP_LIVE = 0.15  # written live at 0.5 s (the firmware's default is 0.1)
#: the stream's period: the simulated board sends one Drive every ~3.5 ms at most (docs/board.md,
#: "The AVR real-motor build"), so 5 ms loses no slot
PERIOD_MONITOR_US = 5000
RISE_TOL_S = 0.010
RISE_TOL_FRACTION = 0.15
OVERSHOOT_TOL_PCT = 5.0
FINAL_TOL_FRACTION = 0.02


def _config(path: Path) -> Path:
    """The packaged config with [[check]] tables a monitor run can judge (no plant columns)."""
    path.write_text('extends = "packaged"\n\n[[check]]\nkind = "speed_error"\nmax_pct = 5.0\nmin_hold_s = 0.5\n\n'
                    '[[check]]\nkind = "no_fault"\n', encoding="utf-8")
    return path


def _scenario(path: Path) -> Path:
    path.write_text(
        "[[scenario]]\nat_s = 0.0\nref_rpm = %r\n\n[[scenario]]\nat_s = 0.0\npress = \"s2\"\n\n"
        "[[scenario]]\nat_s = 0.5\nset = { kp = %r }\n\n[[scenario]]\nat_s = %r\nref_rpm = %r\n\n"
        "[[scenario]]\nat_s = %r\nend = true\n" % (FROM_RPM, KP_LIVE, SETTLE_S, TO_RPM, SETTLE_S + AFTER_S),
        encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def motor_build(tmp_path_factory) -> Path:
    """The AVR real-motor build and its harness, made once for the session (~2 s of compiling)."""
    require_tool("avr-gcc", "the AVR real-motor build (apt: gcc-avr avr-libc)")
    require_tool("make", "the AVR build's Makefile")
    require_tool("simavr", "the pin-level harness (apt: simavr)")
    require_file("/usr/include/simavr/parts/uart_pty.h", "libsimavr-dev", "the harness's UART pty")
    config = python_config("the harness embeds this Python (its hilbench plant)")
    out = tmp_path_factory.mktemp("motor")
    result = subprocess.run(["make", "-C", str(AVR_DIR), f"OUT={out}", "MODE=motor", f"PYTHON_CONFIG={config}"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return out


def _start_harness(build: Path) -> tuple[subprocess.Popen[bytes], str]:
    env = dict(os.environ, VIRTUAL_ENV=sys.prefix, PYTHONPATH=str(REPO))  # this interpreter's hilbench and numpy
    process = spawn([str(build / "run_motor"), "--realtime", str(build / "an1017_avr_motor_seed.elf")],
                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    assert process.stdout is not None
    fd = process.stdout.fileno()
    seen = b""
    deadline = time.monotonic() + 60.0
    while b"\nready " not in b"\n" + seen or not seen.split(b"ready ", 1)[1].count(b"\n"):
        ready, _, _ = select.select([fd], [], [], max(deadline - time.monotonic(), 0.0))
        chunk = os.read(fd, 4096) if ready else b""
        if not chunk:
            reap(process)
            pytest.fail(f"run_motor said no 'ready' line: {seen!r} {process.stderr.read() if process.stderr else b''!r}")
        seen += chunk
    return process, seen.split(b"ready ", 1)[1].split(b"\n", 1)[0].decode()


def _hilbench(*args: str, timeout_s: float = 900.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", *args], capture_output=True, text=True,
                          timeout=timeout_s)


def test_monitor_mode_live_gain_and_step_agree_with_lockstep(motor_build: Path, tmp_path: Path) -> None:
    scenario = _scenario(tmp_path / "step.toml")
    config = _config(tmp_path / "bench.toml")
    test = StepTest(FROM_RPM, TO_RPM, SETTLE_S, AFTER_S)
    harness, pty = _start_harness(motor_build)
    try:
        monitor = _hilbench("run", str(config), "--target", pty, "--mode", "monitor", "--scenario", str(scenario),
                            "--set", f"link.period_us={PERIOD_MONITOR_US}", "--set", "link.watchdog_ms=500",
                            "--record", str(tmp_path / "motor.csv"), "--no-ui", "--no-control")
    finally:
        reap(harness)
    assert monitor.returncode == 0, monitor.stdout + monitor.stderr
    assert "check speed_error: PASS" in monitor.stdout and "check no_fault: PASS" in monitor.stdout, monitor.stdout
    # the session never sent a frame while the board still held one (it keeps one: a second is lost)
    assert "board_overruns 0," in monitor.stdout, monitor.stdout
    lockstep = _hilbench("run", str(config), "--target", "inprocess:an1017", "--scenario", str(scenario),
                         "--set", "link.period_us=50", "--record", str(tmp_path / "hil.csv"), "--no-ui", "--no-control")
    assert lockstep.returncode == 0, lockstep.stdout + lockstep.stderr

    for name in ("motor", "hil"):  # `report` reads both alike, plots included
        shown = _hilbench("report", str(tmp_path / f"{name}.csv"), "--plot", str(tmp_path / f"{name}-plots"))
        assert shown.returncode == 0 and (tmp_path / f"{name}-plots" / f"{name}_speed.png").exists(), shown.stderr
    shown = _hilbench("report", str(tmp_path / "motor.csv"), "--plot", str(tmp_path / "both"),
                      "--overlay", str(tmp_path / "hil.csv"))  # the two runs on one time axis
    assert shown.returncode == 0 and (tmp_path / "both" / "motor_overlay_speed.png").exists(), shown.stderr
    real = read_recording(tmp_path / "motor.csv")
    hil = read_recording(tmp_path / "hil.csv")
    assert real.metadata["mode"] == "monitor"
    # every slot of the stream from the live write on arrived (the start may miss a few: the board
    # answers the start's parameter writes while it starts its motor)
    t_real = real.columns["t_s"]
    assert np.allclose(np.diff(t_real[t_real >= 0.4]), PERIOD_MONITOR_US / 1e6), np.diff(t_real)
    assert any("kp" in text for text in real.events), real.events  # the live write, recorded at its time
    # the same format: every column of the monitor recording is a column of the HIL one, same units
    assert set(real.columns) <= set(hil.columns), set(real.columns) - set(hil.columns)
    assert all(real.units.get(name) == hil.units.get(name) for name in real.columns)
    fig_real = analyse_measured(real.columns, test, PROFILE, "measured_speed_rpm", {"kp": KP_LIVE}, monitor=True).metrics
    fig_hil = analyse_measured(hil.columns, test, PROFILE, "measured_speed_rpm", {"kp": KP_LIVE}, monitor=False).metrics
    print(f"monitor: {fig_real}\nlockstep: {fig_hil}")
    assert fig_hil.rise_time_s is not None and fig_real.rise_time_s is not None
    assert math.isclose(fig_real.rise_time_s, fig_hil.rise_time_s,
                        abs_tol=RISE_TOL_S + RISE_TOL_FRACTION * fig_hil.rise_time_s)
    assert abs(fig_real.overshoot_pct - fig_hil.overshoot_pct) <= OVERSHOOT_TOL_PCT
    step = abs(TO_RPM - FROM_RPM)
    final_real = fig_real.y_final_ref - fig_real.ss_error
    final_hil = fig_hil.y_final_ref - fig_hil.ss_error
    assert abs(final_real - final_hil) <= FINAL_TOL_FRACTION * step


def test_motor_build_refuses_frames_and_stops_when_the_host_goes_silent(motor_build: Path) -> None:
    """A real-motor build agrees to monitor mode only (its motor never runs from a simulated rotor:
    a lockstep HostHello and a Sensors are refused; a write or a Start before the MONITOR hello
    that agrees its watchdog too), and when the host falls silent its watchdog
    stops the motor: the stream says outputs OFF, fault WATCHDOG, about watchdog_ms of the board's
    time after the host's last frame."""
    from hilbench.link import open_link
    from hilbench.protocol import Drive, ErrorCode, ErrorReport, Fault, HostHello, MODE_LOCKSTEP, MODE_MONITOR, \
        OutputMode, ParamSet, PROTOCOL_VERSION, Sensors, Start, Status, StatusRequest
    from hilbench.targets.remote import RemoteTarget

    harness, pty = _start_harness(motor_build)
    link = open_link(pty, timeout_s=5.0)
    try:
        target = RemoteTarget(link, timeout_s=5.0, retry_s=1.0)
        # before a MONITOR hello has agreed a watchdog: no write and no Start (the motor would run with none)
        for request in (ParamSet(3, ((5, 1), (6, 5000))), Start(4)):
            link.send(request)
            refusal = target._await(request, (ErrorReport,), time.monotonic(), 10.0, "refusal")
            assert type(refusal) is ErrorReport and refusal.code == int(ErrorCode.BAD_REQUEST), refusal
        refused = target._request(HostHello(1, PROTOCOL_VERSION, 1000, MODE_LOCKSTEP, 500), ErrorReport)
        assert type(refused) is ErrorReport, refused
        watchdog_ms, period_us = 300, 5000
        target.handshake(period_us, MODE_MONITOR, watchdog_ms)
        link.send(Sensors(1, 0, (), 0, ()))
        assert type(target._await(Sensors(1, 0, (), 0, ()), (ErrorReport,), time.monotonic(), 10.0, "refusal")) \
            is ErrorReport
        target.set_params(((5, 1), (6, 5000)))  # ref_ovr_on, ref_override: ~900 rpm
        target.start()
        # The board's time when it took the host's last frame: the seq of the Drive it streamed just
        # before its answer (its own clock: the figure does not depend on how late this host reads)
        last_seq, taken_seq, drives = None, None, 0

        def receive(timeout_s: float) -> object:
            nonlocal last_seq, taken_seq, drives
            msg = link.recv_or_none(timeout_s)
            if type(msg) is Drive:
                last_seq, drives = msg.seq, drives + 1
            elif type(msg) is Status:
                taken_seq = last_seq
            return msg

        # Keep the host alive until the motor runs: a StatusRequest, the next one after its answer
        # (a frame sent while the board still holds one is lost), or after 20 streamed Drives without
        # one (100 ms of the board's own time: that one was lost; the watchdog is 300 ms). Counted in
        # the board's Drives, not in wall time: on a loaded machine the simulated board runs at a few
        # per cent of real time, and a wall-clock resend fell while it still held the last request.
        running = False

        def take(timeout_s: float) -> object:
            nonlocal running
            msg = receive(timeout_s)
            running = running or (type(msg) is Drive and msg.output_mode == int(OutputMode.PWM))
            return msg

        deadline = time.monotonic() + 120.0
        while not (running and taken_seq is not None) and time.monotonic() < deadline:
            while take(0.0) is not None:  # what is here already was streamed before our next frame
                pass
            link.send(StatusRequest(2))
            sent_at = drives
            while drives - sent_at < 20 and time.monotonic() < deadline:
                if type(take(1.0)) is Status:
                    break
        assert running, "the motor never ran"
        while time.monotonic() < deadline:  # the host falls silent
            msg = receive(1.0)
            if type(msg) is not Drive:
                continue
            if msg.fault == int(Fault.WATCHDOG):
                assert msg.output_mode == int(OutputMode.OFF)
                assert taken_seq is not None, "no Status answered between the motor running and the watchdog"
                board_ms = ((msg.seq - taken_seq) & 0xFF) * period_us / 1000.0
                print(f"outputs OFF, fault WATCHDOG {board_ms:g} ms of the board's time after it took the last frame")
                assert watchdog_ms - period_us / 1000.0 <= board_ms <= watchdog_ms + 2 * period_us / 1000.0, board_ms
                return
        pytest.fail("no watchdog Drive")
    finally:
        link.close()
        reap(harness)


@pytest.mark.parametrize("edges, said", [
    ("tuple((1e-6 * i, i % 8) for i in range(100))", "100 hall edges in one PWM period"),  # more than it holds
    ("(('soon', 1),)", "the plant's edge is not (seconds >= 0, hall bits 0..7)"),
    ("((1e-6, 9),)", "the plant's edge is not (seconds >= 0, hall bits 0..7)"),
])
def test_harness_refuses_what_the_plant_gives_that_it_cannot_wire(motor_build: Path, tmp_path: Path, edges: str,
                                                                   said: str) -> None:
    """run_motor never drops a hall edge nor wires a value it could not convert: a plant (here a
    stand-in module on PYTHONPATH) whose period gives more edges than the harness holds, or an edge
    that is not (seconds, bits 0..7), ends the harness with one line and exit 1."""
    package = tmp_path / "stand_in" / "hilbench" / "bench"
    package.mkdir(parents=True)
    (package.parent / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "pinplant.py").write_text(
        "class PinPlant:\n"
        "    hall_bits = 1\n"
        "    def __init__(self, config, overrides, period_us):\n"
        "        pass\n"
        "    def pot_mv(self):\n"
        "        return 0\n"
        f"    def period(self, a, b, c, enabled):\n        return {edges}\n")
    env = {k: v for k, v in os.environ.items() if k != "VIRTUAL_ENV"}
    env["PYTHONPATH"] = str(tmp_path / "stand_in")
    done = subprocess.run([str(motor_build / "run_motor"), str(motor_build / "an1017_avr_motor_seed.elf")],
                          capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 1 and said in done.stderr, (done.returncode, done.stderr[-2000:])


def test_ctl_tunes_the_real_motor_live(motor_build: Path, tmp_path: Path) -> None:
    """`hilbench ctl set` during `hilbench run --mode monitor`: a checked write on the running board
    (the guard then watches the new gains), its answer, the values read back by `ctl get`, the write
    in the recording at the board's time; a write the firmware's constraints refuse is refused; `ctl
    stop` ends the run (it runs until then, however long the commands take on a loaded machine)."""
    harness, pty = _start_harness(motor_build)
    run = spawn([sys.executable, "-m", "hilbench", "run", "--target", pty, "--mode", "monitor", "--no-ui",
                 "--set", f"link.period_us={PERIOD_MONITOR_US}", "--set", "link.watchdog_ms=500",
                 "--set", "run.duration_s=600", "--record", str(tmp_path / "motor.csv")],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300.0
        while _hilbench("ctl", "get", timeout_s=60).returncode != 0:  # until the session's socket answers
            assert time.monotonic() < deadline and run.poll() is None, "no monitor session answered ctl get"
        done = _hilbench("ctl", "set", "kp=0.12", "ki=0.012", timeout_s=120)
        assert done.returncode == 0, done.stdout + done.stderr
        refused = _hilbench("ctl", "set", "kp=0.9", "ki=0.2", timeout_s=120)
        assert refused.returncode != 0 and "Kp + Ki + Kd" in refused.stdout + refused.stderr, refused
        from hilbench.bench.control import ControlClient

        stream = ControlClient().request({"cmd": "stream", "since": -1, "columns": ["measured_speed_rpm", "duty_a"]},
                                         timeout_s=120)  # what the scope asks for, every 100-200 ms
        assert stream["ok"], stream
        meta = stream["data"]["meta"]
        assert meta["mode"] == "monitor" and ["measured_speed_rpm", "rpm"] in meta["columns"], meta
        got = _hilbench("ctl", "get", timeout_s=120)  # piped: the JSON
        assert got.returncode == 0, got.stderr
        params = json.loads(got.stdout)["params"]
        assert abs(params["kp"] - 0.12) < 1e-4 and abs(params["ki"] - 0.012) < 1e-4, params
        assert run.poll() is None, "the run ended before ctl stop"
        stopped = _hilbench("ctl", "stop", timeout_s=120)
        assert stopped.returncode == 0, stopped.stdout + stopped.stderr
        out, err = run.communicate(timeout=300)
        assert run.returncode in (0, 9), (out, err)  # the config's checks judge a run ctl changed and stopped
        assert b"ended: stopped by ctl" in out, out
    finally:
        reap(run, 10.0)
        reap(harness)
    events = read_recording(tmp_path / "motor.csv").events
    assert any("kp=0.12" in text for text in events), events


def test_dashboard_shows_the_real_motor_live(motor_build: Path, tmp_path: Path) -> None:
    """`hilbench run --mode monitor` on a terminal (tmux, 100x40): the live dashboard follows the
    board's stream (the firmware's speed near its reference, state RUNNING), then the summary."""
    from test_dashboard_tmux import Tmux

    tmux = require_tool("tmux", "the dashboard's test in a real terminal")
    harness, pty = _start_harness(motor_build)
    runtime = tmp_path / "xdg"
    runtime.mkdir(mode=0o700)
    env = {**os.environ, "XDG_RUNTIME_DIR": str(runtime), "TERM": "xterm-256color"}
    done = tmp_path / "done"
    command = (f"cd {REPO} && {sys.executable} -m hilbench run --target {pty} --mode monitor "
               f"--set link.period_us={PERIOD_MONITOR_US} --set link.watchdog_ms=500 --set run.duration_s=2.0; "
               f"echo $? > {done}; sleep 600")
    pane = Tmux(tmux, f"hbm-{os.getpid()}", 100, 40, command, env)
    try:
        screen = pane.wait_for(lambda s: "RUNNING" in s and "speed (firmware)" in s, "the running motor", 300.0)
        assert "hilbench run" in screen and "ref_override" in screen, screen
        deadline = time.monotonic() + 600.0
        while not done.exists() or not done.read_text().strip():  # the run's exit status, written at its end
            assert time.monotonic() < deadline, pane.screen()
            time.sleep(0.2)  # polling the file the pane's shell writes: the condition the test waits on
        assert done.read_text().strip() == "0", pane.screen()
        assert "check speed_error: PASS" in pane.screen(), pane.screen()
    finally:
        pane.close()
        reap(harness)


def test_monitor_options_refuse_a_watchdog_the_keep_alives_cannot_feed() -> None:
    """Keep-alives go every quarter of the watchdog, each after two streamed Drives: a watchdog
    shorter than 8 stream periods always stopped the motor; refused in one line with the least."""
    from hilbench.bench.monitor import monitor_options
    from hilbench.errors import ConfigError

    with pytest.raises(ConfigError, match=r"watchdog_ms=100 is less than 8 stream periods.*>= 520"):
        monitor_options(65_000, 100, None, 5.0)
    with pytest.raises(ConfigError, match="must be > 0"):
        monitor_options(5_000, 0, None, 5.0)
    assert monitor_options(5_000, 100, None, 5.0).watchdog_ms == 100


#: the scope test's run: it ends off an observe row (495, not a multiple of OBSERVE_EVERY_ROWS), so
#: only the display's take at the close (`closing`) gives it the last rows
SCOPE_RUN_S = 2.475


class _Scope:
    """A control source with a scope's `stream` requests, one every ``every_s`` (as the page asks;
    a scope that stops asking lets the display go idle), each from the last answer's seq on; the
    frames of every answer kept."""

    def __init__(self, columns: list[str], every_s: float = 0.2) -> None:
        self.columns, self.every_s = columns, every_s
        self.seq = -1
        self.frames: list[dict[str, Any]] = []
        self._asked_s = -math.inf

    def poll(self) -> list[ControlRequest]:
        if time.monotonic() - self._asked_s < self.every_s:
            return []
        self._asked_s = time.monotonic()
        return [ControlRequest("stream", {"since": self.seq, "columns": self.columns}, self._asked_s, _send=self.took)]

    def took(self, line: bytes) -> None:
        answer = json.loads(line)
        assert answer["ok"], answer
        self.take(answer["data"])

    def take(self, data: dict[str, Any]) -> None:
        self.frames += data["frames"]
        self.seq = data["seq"]


def test_a_scope_watching_the_real_motor_gets_every_row(motor_build: Path, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The scope on a monitor run (the real motor's stream, recorded in chunks of one second): the
    display takes the rows before each flush lets them go (`flush_coming`) and the last ones before
    the close writes them out (`closing`), so its frames follow each other without a gap up to the
    recording's last row, each bucket the envelope of the recorded rows."""
    from test_scope_stream import decode
    from hilbench.bench import display as display_module
    from hilbench.bench.monitorrun import run_monitor_session
    from hilbench.bench.run import RunRequest, load_run_config
    from hilbench.bench.scenario import Event

    monkeypatch.setattr(display_module, "IDLE_AFTER_S", math.inf)  # the scope stays attached however slow the stop
    harness, pty = _start_harness(motor_build)
    cfg = load_run_config(RunRequest(overrides=(f"link.period_us={PERIOD_MONITOR_US}", "link.watchdog_ms=500"),
                                     target=pty, mode="monitor"))
    scope = _Scope(["t_s", "measured_speed_rpm"])
    sessions: list[Any] = []
    events = (Event(at_s=0.0, ref_rpm=FROM_RPM), Event(at_s=0.0, press="s2"), Event(at_s=SCOPE_RUN_S, end=True))
    try:
        summary, _ = run_monitor_session(cfg, events, record=tmp_path / "motor.npz", duration_s=SCOPE_RUN_S,
                                         control=scope, on_ready=sessions.append)
    finally:
        reap(harness)
    assert summary.periods >= 400, summary
    display = sessions[0].display
    assert display is not None and display.error is None, display.error
    scope.take(display.request(scope.seq, scope.columns, sessions[0].t_s))  # the rows the close's take added
    recording = read_recording(tmp_path / "motor.npz")
    t_rec, speed = recording.columns["t_s"], recording.columns["measured_speed_rpm"]
    frames = scope.frames
    starts = [int(np.searchsorted(t_rec, f["t0"] - 1e-9)) for f in frames]
    assert starts[0] == 0, (frames[0]["t0"], t_rec[:3])
    ends = starts[1:] + [len(t_rec)]
    for frame, start, end in zip(frames, starts, ends):  # each frame's rows: the next one starts after them
        bucket = int(round(frame["dt"] * 1e6 / PERIOD_MONITOR_US))
        assert frame["n"] == -(-(end - start) // bucket), (frame["t0"], frame["n"], start, end)
        for name, values in (("measured_speed_rpm", speed), ("t_s", t_rec)):  # t_s: each bucket's first and last row
            lo, hi = display_module.envelope(values[start:end], bucket)
            assert np.array_equal(decode(frame["cols"][name][0]), lo.astype(np.float32)), (name, frame["t0"])
            assert np.array_equal(decode(frame["cols"][name][1]), hi.astype(np.float32)), (name, frame["t0"])
