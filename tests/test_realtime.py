"""Real-time mode: pacing to the wall clock, lateness/RTT/overrun reporting, stalls and the abort policy.

Nothing here asserts a wall-clock figure: the stalls are made by a target that holds the CPU for a
known number of periods, and the assertions are about what the session does with them.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conftest import hurst_bench_config, run_cli
from hilbench.bench.launcher import open_target
from hilbench.bench.recorder import MARKER_SKIPPED, Recorder, read_recording
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.bench.scenario import Event
from hilbench.bench.session import Session, SessionAborted, SessionOptions
from hilbench.bench.settings import load_config
from hilbench.config import plant_params_from_config
from hilbench.plant.model import Plant

PERIOD_US = 1000


class StallingTarget:
    """An in-process target that holds the CPU for ``stall_periods`` inside the exchanges of the
    periods in ``stall_at`` (the first exchange at or after each, should the machine's own stalls
    have skipped that period)."""

    def __init__(self, inner: Any, stall_at: set[int], stall_periods: float) -> None:
        self._inner = inner
        self._pending = sorted(stall_at)
        self._stall_s = stall_periods * PERIOD_US * 1e-6
        self.exchanges = 0
        self.stalled_periods: list[int] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def step(self, sensors: Any) -> Any:
        if self._pending and sensors.seq >= self._pending[0]:  # periods < 256 here: seq is k
            while self._pending and sensors.seq >= self._pending[0]:
                self._pending.pop(0)
            self.stalled_periods.append(sensors.seq)
            until = time.perf_counter() + self._stall_s
            while time.perf_counter() < until:  # a stall: the CPU is taken, as a hypervisor would
                pass
        self.exchanges += 1
        return self._inner.step(sensors)


def _session(target: Any, tmp_path: Path, seconds: float, **options: Any) -> tuple[Session, Recorder]:
    cfg = load_config(None)
    plant = Plant(plant_params_from_config(cfg), seed=0)
    events = (Event(at_s=0.0, ref_rpm=1000.0), Event(at_s=0.005, press="s2"))
    opts = SessionOptions(period_us=PERIOD_US, mode="realtime", duration_s=seconds, **options)
    recorder = Recorder(tmp_path / "rt.npz", {"test": True})
    return Session(target, plant, events, opts, recorder=recorder, target_label="stalling"), recorder


def test_a_stall_past_whole_periods_skips_them_holding_the_drive(tmp_path: Path) -> None:
    with open_target("inprocess:an1017", timeout_s=2.0) as handle:
        target = StallingTarget(handle.target, stall_at={40}, stall_periods=4.5)
        session, _ = _session(target, tmp_path, 0.1)
        summary = session.run()
    data = read_recording(tmp_path / "rt.npz")
    skipped_rows = np.flatnonzero(data.columns["marker"] == MARKER_SKIPPED)
    # the exchange of period s (40, or later if the machine's own stalls skipped 40) ends 4.5
    # periods after its start: periods s+1..s+3 start 3.5, 2.5 and 1.5 periods late, so they are
    # not exchanged (the machine may add stalls of its own)
    (s,) = target.stalled_periods
    assert {s + 1, s + 2, s + 3} <= set(skipped_rows.tolist())
    assert summary.skipped_periods == len(skipped_rows)
    assert target.exchanges == summary.periods - summary.skipped_periods  # skipped = no exchange
    assert summary.overruns >= summary.skipped_periods + 1  # period 40 itself ended late too
    for row in skipped_rows:  # the Drive is held: the duties of the period before
        for name in ("duty_a", "duty_b", "duty_c", "output_mode"):
            assert data.columns[name][row] == data.columns[name][row - 1]
        assert data.columns["rtt_us"][row] == 0.0
        assert data.columns["lateness_us"][row] >= PERIOD_US
    # the plant kept to the wall clock: one row per period, no gaps
    assert list(data.columns["seq"]) == list(range(summary.periods))
    assert summary.as_dict()["skipped_periods"] == summary.skipped_periods
    # the longest run of skipped periods is at least this stall's three (the machine may add longer ones)
    runs = np.split(skipped_rows, np.flatnonzero(np.diff(skipped_rows) != 1) + 1) if len(skipped_rows) else []
    longest = max(runs, key=len)
    assert summary.longest_stall_periods == len(longest) >= 3
    assert summary.longest_stall_at_s == pytest.approx(data.columns["t_s"][longest[0]])


def test_a_stall_of_two_hall_sectors_is_real_time_not_held() -> None:
    """Few overruns in all, but one stall that held the Drive for two hall sectors or more: the
    firmware drove 120 degrees behind the rotor, so the run is not a real-time one from there."""
    from hilbench.bench.feasibility import overrun_warning

    sector_s = 60.0 / (2500.0 * 5 * 6)  # 800 us: 2500 rpm, 5 pole pairs, 6 hall edges an electrical turn
    text = overrun_warning(3750, 23, stall_periods=6, stall_at_s=1.8, period_us=800, sector_s=sector_s)
    assert text is not None and text.startswith("real time NOT held: the host stalled 6 periods in a row at 1.800 s")
    assert "6.0 hall sectors" in text
    assert overrun_warning(3750, 23, stall_periods=1, stall_at_s=1.8, period_us=800, sector_s=sector_s) is None
    assert overrun_warning(3750, 23, stall_periods=6, stall_at_s=1.8, period_us=800, sector_s=None) is None


def test_abort_policy_stops_after_consecutive_overruns(tmp_path: Path) -> None:
    with open_target("inprocess:an1017", timeout_s=2.0) as handle:
        target = StallingTarget(handle.target, stall_at=set(range(30, 250)), stall_periods=1.2)
        session, _ = _session(target, tmp_path, 0.3, overrun_policy="abort", max_consecutive_overruns=5)
        with pytest.raises(SessionAborted, match="5 consecutive overruns"):
            session.run()
    data = read_recording(tmp_path / "rt.npz")  # closed, with the fault marked
    assert data.n_rows >= 5  # the stall starts at period 30; a loaded machine may overrun 5 in a row sooner
    assert "fault" in data.metadata["end"]


@pytest.mark.slow
def test_realtime_against_the_emulator_process_reports_timing(tmp_path: Path) -> None:
    """1 kHz against the emulator on a pty: lateness, RTT and overruns are measured and reported."""
    config = hurst_bench_config(tmp_path, 0.5)
    cfg = load_run_config(RunRequest(str(config), overrides=(f"link.period_us={PERIOD_US}",),
                                     target="emulator:an1017", mode="realtime", duration_s=0.5))
    summary = run_bench(cfg, record=tmp_path / "rt.csv")
    assert summary.mode == "realtime" and summary.periods == 500
    assert set(summary.rtt_us) >= {"p50", "p99", "max"} and summary.rtt_us["p50"] > 0
    assert set(summary.lateness_us) >= {"p50", "p99", "max"}
    assert 0 <= summary.skipped_periods <= summary.overruns <= summary.periods
    data = read_recording(tmp_path / "rt.csv")
    exchanged = data.columns["marker"] != MARKER_SKIPPED
    assert (data.columns["rtt_us"][exchanged] > 0).all()  # every exchange was timed
    assert data.columns["t_s"][-1] == pytest.approx(0.499)


@pytest.mark.slow
def test_realtime_cli_summary_names_overruns(tmp_path: Path) -> None:
    config = hurst_bench_config(tmp_path, 0.3)
    result = run_cli("run", str(config), "--mode", "realtime", "--set", f"link.period_us={PERIOD_US}",
                     "--no-ui", timeout=60)
    assert result.returncode == 0, result.stderr
    assert "lateness_us: p50" in result.stdout and "overruns" in result.stdout
    assert "rtt_us: p50" in result.stdout


def test_cpu_latency_request_holds_the_value_and_releases_it(tmp_path: Path) -> None:
    """The PM QoS request writes a 32-bit 0 and keeps the file open until the run ends."""
    from hilbench.bench.clock import CpuLatencyRequest

    qos_file = tmp_path / "cpu_dma_latency"  # a plain file stands in for the device
    qos_file.write_bytes(b"")
    driver = tmp_path / "current_driver"  # and one for the kernel's cpuidle driver
    driver.write_text("haltpoll\n")
    with CpuLatencyRequest(path=str(qos_file), driver_path=str(driver)) as request:
        assert request.held
        assert request.status == f"held at 0 us ({qos_file})"
        assert qos_file.read_bytes() == b"\x00\x00\x00\x00"
    assert not request.held


def test_cpu_latency_request_says_when_the_kernel_cannot_honour_it(tmp_path: Path) -> None:
    """With no cpuidle driver (a VM's kernel may have none) idle CPUs halt whatever is asked."""
    from hilbench.bench.clock import CpuLatencyRequest

    qos_file = tmp_path / "cpu_dma_latency"
    qos_file.write_bytes(b"")
    driver = tmp_path / "current_driver"
    driver.write_text("none\n")
    with CpuLatencyRequest(path=str(qos_file), driver_path=str(driver)) as request:
        assert request.held
        assert request.status.startswith("held at 0 us") and "without effect" in request.status
    with CpuLatencyRequest(path=str(qos_file), driver_path=str(tmp_path / "missing")) as request:
        assert request.status == f"held at 0 us ({qos_file})"  # not known: not said


def test_cpu_latency_request_without_the_device_says_why(tmp_path: Path) -> None:
    from hilbench.bench.clock import CpuLatencyRequest

    with CpuLatencyRequest(path=str(tmp_path / "missing")) as request:
        assert not request.held
        assert request.status.startswith("not held:") and "missing" in request.status


def test_realtime_summary_says_whether_cpus_were_kept_awake(tmp_path: Path) -> None:
    with open_target("inprocess:an1017", timeout_s=2.0) as handle:
        session, _ = _session(handle.target, tmp_path, 0.02, cpu_latency_qos=False)
        summary = session.run()
    assert summary.cpu_latency.startswith("not requested")
    with open_target("inprocess:an1017", timeout_s=2.0) as handle:
        session, _ = _session(handle.target, tmp_path, 0.02)
        summary = session.run()
    assert summary.cpu_latency.startswith(("held at 0 us", "not held:"))  # root or not
    assert summary.as_dict()["cpu_latency"] == summary.cpu_latency


def test_cpu_pinning_puts_host_and_child_on_one_cpu_and_restores_the_host() -> None:
    import subprocess
    import sys

    from hilbench.bench.cpus import CpuPinning

    before = os.sched_getaffinity(0)
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        with CpuPinning([child.pid]) as pinning:
            assert os.sched_getaffinity(0) == {pinning.cpu} == os.sched_getaffinity(child.pid)
            assert pinning.cpu == max(before)
            assert pinning.status == f"host and pid {child.pid} on CPU {pinning.cpu}"
        assert os.sched_getaffinity(0) == before
    finally:
        child.communicate(b"", timeout=10)  # end of input: the child exits and is reaped


def test_fifo_priority_raises_host_and_child_and_restores_the_host() -> None:
    """As root (or with CAP_SYS_NICE) both run SCHED_FIFO for the run; otherwise the status says why."""
    import subprocess
    import sys

    from hilbench.bench.cpus import FifoPriority

    before = os.sched_getscheduler(0)
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        with FifoPriority([child.pid], 10) as priority:
            if priority.status.startswith("normal scheduling (SCHED_FIFO 10: "):  # not permitted here
                assert os.sched_getscheduler(0) == before
            else:
                assert priority.status == f"SCHED_FIFO 10: host, pid {child.pid}"
                for pid in (0, child.pid):
                    assert os.sched_getscheduler(pid) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
                    assert os.sched_getparam(pid).sched_priority == 10
        assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == before & ~os.SCHED_RESET_ON_FORK
    finally:
        child.communicate(b"", timeout=10)  # end of input: the child exits and is reaped


def test_the_pacer_spins_less_under_a_realtime_policy_and_the_session_picks_it() -> None:
    """A SCHED_FIFO thread's sleeps have no timer slack: its pacer spins REALTIME_POLICY_SPIN_S; a
    normal thread keeps the pacer's own spin (and so does one where FIFO is not permitted)."""
    from hilbench.bench.cpus import FifoPriority
    from hilbench.bench.pacing import REALTIME_POLICY_SPIN_S, RealtimePacing, spin_for_this_thread

    normal = RealtimePacing(PERIOD_US, abort_after=None, label="t")
    default_s = normal.pacer.spin_s
    normal.start_at(0)
    assert normal.pacer.spin_s == spin_for_this_thread(default_s) == default_s
    with FifoPriority([], 10) as priority:
        pacing = RealtimePacing(PERIOD_US, abort_after=None, label="t")
        pacing.start_at(5)
        fifo = not priority.status.startswith("normal scheduling")
        assert pacing.pacer.spin_s == (REALTIME_POLICY_SPIN_S if fifo else default_s)
    normal.start_at(7)  # the policy back to normal: the pacer's own spin again
    assert normal.pacer.spin_s == default_s


def test_overrun_episodes_close_together_say_the_cpu_is_contended() -> None:
    """CONTENDED_EPISODES episodes within CONTENDED_WINDOW_S say contended; as many spread wider
    (an idle VM's stalls now and then) do not."""
    from hilbench.bench.pacing import CONTENDED_EPISODES, CONTENDED_WINDOW_S, ContentionWatch

    watch = ContentionWatch(PERIOD_US * 1e-6)
    window = round(CONTENDED_WINDOW_S / (PERIOD_US * 1e-6))
    spread = window // (CONTENDED_EPISODES - 1) + 1  # the first and the last of any 8 one window apart or more
    assert not any(watch.overrun(i * spread) for i in range(3 * CONTENDED_EPISODES))
    k = (3 * CONTENDED_EPISODES - 1) * spread + window  # a window after the last of them
    close = [watch.overrun(k + i * 10) for i in range(CONTENDED_EPISODES)]
    assert close == [False] * (CONTENDED_EPISODES - 1) + [True]


def test_a_run_of_consecutive_overruns_is_one_episode() -> None:
    """The pacing counts an episode where overruns begin: three stalls of 50 periods (150 overruns)
    do not say contended; eight single overruns close together do, once."""
    from hilbench.bench.pacing import CONTENDED_EPISODES, RealtimePacing

    calls: list[float] = []
    pacing = RealtimePacing(PERIOD_US, abort_after=None, label="t", on_contended=calls.append)
    period_s = pacing.period_s

    def period(k: int, late: bool) -> None:  # period k's work ends now: two periods after its slot, or
        # well inside it (a second to spare: a loaded machine may hold this thread between the lines)
        pacing.pacer.t0 = time.perf_counter() - (k + 2 if late else k - 1000) * period_s
        pacing.finished(k)

    stalls = [range(start, start + 50) for start in (100, 300, 500)]
    for k in range(700):
        period(k, any(k in stall for stall in stalls))
    assert pacing.overruns == 150 and calls == []
    singles = [1600 + 3 * i for i in range(CONTENDED_EPISODES + 3)]  # (a window after the stalls' episodes)
    for k in range(700, 1700):
        period(k, k in singles)
    assert calls == [singles[CONTENDED_EPISODES - 1] * period_s]


def test_a_contended_cpu_raises_the_run_once_and_its_pacer_spins_less(tmp_path: Path) -> None:
    """Overruns one after another (a target that holds the CPU 1.5 periods every 18th period) call
    the session's on_contended once, with the run's time; the pacer's spin follows the thread's
    policy from then on."""
    from hilbench.bench.cpus import FifoPriority
    from hilbench.bench.pacing import CONTENDED_EPISODES, REALTIME_POLICY_SPIN_S

    stalls = {30 + 18 * i for i in range(CONTENDED_EPISODES + 4)}  # (all below 256: seq is k)
    calls: list[float] = []
    before = os.sched_getscheduler(0)
    with open_target("inprocess:an1017", timeout_s=2.0) as handle:
        target = StallingTarget(handle.target, stall_at=stalls, stall_periods=1.5)
        session, _ = _session(target, tmp_path, 0.4)
        fifo = FifoPriority([], 10, when="contended").__enter__()
        try:
            def engage(at_s: float) -> None:
                calls.append(at_s)
                fifo.engage(at_s)

            session.on_contended = engage
            summary = session.run()
            raised = fifo.status.startswith("SCHED_FIFO 10 from ")
            spin_s = session.pacing.pacer.spin_s if session.pacing is not None else None
        finally:
            fifo.__exit__(None, None, None)
    assert len(calls) == 1, calls
    eighth = sorted(target.stalled_periods)[CONTENDED_EPISODES - 1]
    assert 0 < calls[0] <= (eighth + 2) * PERIOD_US * 1e-6  # by the eighth stall (the machine may add overruns)
    assert "(the CPU was contended)" in fifo.status
    if raised:  # permitted here (root or CAP_SYS_NICE): the pacer spins as a FIFO thread does
        assert spin_s == REALTIME_POLICY_SPIN_S
    assert summary.overruns >= CONTENDED_EPISODES
    assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == before & ~os.SCHED_RESET_ON_FORK


def test_fifo_when_contended_waits_for_engage_and_restores_the_host() -> None:
    import subprocess
    import sys

    from hilbench.bench.cpus import FifoPriority

    before = os.sched_getscheduler(0)
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        with FifoPriority([child.pid], 10, when="contended") as priority:
            assert priority.status == "normal scheduling (SCHED_FIFO 10 once the CPU is contended: not needed)"
            assert os.sched_getscheduler(0) == before
            assert os.sched_getscheduler(child.pid) & ~os.SCHED_RESET_ON_FORK == before & ~os.SCHED_RESET_ON_FORK
            priority.engage(1.5)
            priority.engage(2.5)  # once
            if priority.status.startswith("SCHED_FIFO"):  # permitted here (root, CAP_SYS_NICE or RLIMIT_RTPRIO)
                assert priority.status.startswith("SCHED_FIFO 10 from 1.500 s (the CPU was contended): host")
                assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
            else:
                assert priority.status.startswith("normal scheduling (SCHED_FIFO 10 from 1.500 s (the CPU was contended): ")
        assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == before & ~os.SCHED_RESET_ON_FORK
    finally:
        child.communicate(b"", timeout=10)
    with pytest.raises(ValueError, match="when='sometimes'"):
        FifoPriority([], 10, when="sometimes")


@pytest.mark.slow
def test_a_cpu_bound_process_on_the_runs_cpu_raises_the_run_to_fifo(tmp_path: Path) -> None:
    """[link] realtime_fifo = "contended" (the default) against the emulator process, with a
    CPU-bound process pinned to the run's CPU: the run is raised to SCHED_FIFO as it goes, and the
    summary says when (or why it could not be)."""
    import subprocess
    import sys

    from hilbench.bench.cpus import default_cpu

    config = hurst_bench_config(tmp_path, 1.0)
    cfg = load_run_config(RunRequest(str(config), overrides=(f"link.period_us={PERIOD_US}",),
                                     target="emulator:an1017", mode="realtime", duration_s=1.0))
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        os.sched_setaffinity(hog.pid, {default_cpu()})
        summary = run_bench(cfg)
    finally:
        hog.kill()
        hog.wait(timeout=10)
    assert "(the CPU was contended)" in summary.cpus, summary.cpus


def test_a_cpu_this_process_may_not_use_is_a_config_error() -> None:
    from hilbench.bench.cpus import CpuPinning
    from hilbench.errors import ConfigError

    with pytest.raises(ConfigError, match=r"\[link\] realtime_cpu 4095: not one of this process's CPUs"):
        CpuPinning([], cpu=4095)


@pytest.mark.slow
def test_realtime_run_pins_the_emulator_with_the_host(tmp_path: Path) -> None:
    config = hurst_bench_config(tmp_path, 0.2)
    cfg = load_run_config(RunRequest(str(config), overrides=(f"link.period_us={PERIOD_US}",),
                                     target="emulator:an1017", mode="realtime", duration_s=0.2))
    before = os.sched_getaffinity(0)
    summary = run_bench(cfg)
    assert summary.cpus.startswith("host and pid ") and f"on CPU {max(before)}; " in summary.cpus
    pid = summary.cpus.split()[3]
    scheduling = summary.cpus.split("; ", 1)[1]  # raised from the start, once the CPU was contended (a loaded
    assert re.fullmatch(rf"SCHED_FIFO 10( from [0-9.]+ s \(the CPU was contended\))?: host, pid {pid}", scheduling) \
        or scheduling.endswith(")"), scheduling  # machine), or normal scheduling and why, in parentheses
    assert os.sched_getaffinity(0) == before  # the caller's CPUs are back
    assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_OTHER  # and its scheduling
    no_pin = load_run_config(RunRequest(str(config), overrides=(f"link.period_us={PERIOD_US}", "link.pin_realtime=false",
                                                                "link.realtime_priority=0"),
                                        target="emulator:an1017", mode="realtime", duration_s=0.2))
    assert run_bench(no_pin).cpus == ""
