"""Issue 27, item 7: long exchange periods with the firmware in the loop.

- Every hall edge of a period reaches the firmware at its own time (protocol 3's Sensors.edges): the
  C AN1017 firmware (SIL) fed the same hall edges in 1 ms periods and in 50 us periods measures the
  same speed, count for count, at every millisecond, at the scenario's top speed and above.
- HostHello mode PREDICT: a Drive carries the duties the firmware is predicted to output over the
  next period (a speculative span on a copy of its state, put back after): the firmware's own state
  and telemetry are those of plain lockstep, only the duties differ; at 1 ms periods the default
  scenario then passes the config's checks on the SIL build and on the AVR in simavr (plain lockstep
  holds each period's last duties for 1 ms, 75 electrical degrees at 2500 rpm, and misses them).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO_ROOT
from hilbench.protocol import MODE_LOCKSTEP, MODE_PREDICT, PROTOCOL_VERSION, HostHello, Sensors
from hilbench.targets.sil import SilTarget, build_sil

pytestmark = pytest.mark.slow

HALL_OF_SECTOR = (0b100, 0b110, 0b010, 0b011, 0b001, 0b101)  # forward (CW) order, tests/_firmware.py
POLE_PAIRS = 5


@pytest.fixture(scope="module")
def sil_exe(tmp_path_factory, gcc: str) -> Path:
    return build_sil(tmp_path_factory.mktemp("sil"))


def hall_stream(rpm: float, period_us: int, total_ms: int, pot: int = 600) -> list[Sensors]:
    """Sensors of a rotor turning at ``rpm`` (edges at exact multiples of 100 ns from t = 0), in
    periods of ``period_us``: each edge in the period it falls in, at its offset."""
    step = round(1e7 * 60.0 / (rpm * POLE_PAIRS * 6))  # 100 ns units between hall edges
    period = period_us * 10
    n_periods = total_ms * 1000 // period_us
    edges_at = range(step // 3, n_periods * period, step)
    out, e, sector = [], 0, 0
    times = list(edges_at)
    for k in range(n_periods):
        start, end = k * period, (k + 1) * period
        mine = []
        while e < len(times) and times[e] < end:
            sector = (sector + 1) % 6
            mine.append((times[e] - start, HALL_OF_SECTOR[sector]))
            e += 1
        out.append(Sensors(k & 0xFF, HALL_OF_SECTOR[sector], tuple(mine), 0, (pot, 0, 0)))
    return out


def measured_every_ms(exe: Path, stream: list[Sensors], period_us: int, mode: int = MODE_LOCKSTEP) -> list:
    """The Drive at the end of every millisecond (telemetry: RefSpeed, MeasuredSpeed, ControlOutput)."""
    every = 1000 // period_us
    out = []
    with SilTarget.open("seed", exe=exe, timeout_s=5.0) as sil:
        t = sil.target
        t.hello(HostHello(0, PROTOCOL_VERSION, period_us, mode, 0))
        t.start()
        for k, s in enumerate(stream):
            d = t.step(s)
            if (k + 1) % every == 0:
                out.append(d)
    return out


@pytest.mark.parametrize("rpm", [2500.0, 5000.0])
def test_every_edge_of_a_long_period_reaches_the_firmware_at_its_time(sil_exe: Path, rpm: float) -> None:
    fine = measured_every_ms(sil_exe, hall_stream(rpm, 50, 400), 50)
    coarse = measured_every_ms(sil_exe, hall_stream(rpm, 1000, 400), 1000)
    assert len(fine) == len(coarse) == 400
    assert max(len(s.edges) for s in hall_stream(rpm, 1000, 400)) >= 2  # periods with several edges
    speeds = [(f.telemetry[1], c.telemetry[1]) for f, c in zip(fine, coarse)]
    held = speeds[50:]  # after the first edges set the measurement up
    assert all(abs(a - b) <= 1 for a, b in held), [(i, a, b) for i, (a, b) in enumerate(held) if abs(a - b) > 1][:5]
    q15_per_rpm = 1 / (9_375_000 / (POLE_PAIRS * (313 - 1) * 32768))
    assert abs(held[-1][0] - rpm * q15_per_rpm) <= 0.01 * rpm * q15_per_rpm  # and it is the rotor's speed


def test_predicted_duties_leave_the_firmware_as_plain_lockstep_leaves_it(sil_exe: Path) -> None:
    stream = hall_stream(2500.0, 1000, 200)
    plain = measured_every_ms(sil_exe, stream, 1000, MODE_LOCKSTEP)
    predicted = measured_every_ms(sil_exe, stream, 1000, MODE_PREDICT)
    assert [d[4:] for d in plain] == [d[4:] for d in predicted]  # mode, state, sector, ..., telemetry
    assert [d[1:4] for d in plain] != [d[1:4] for d in predicted]  # the duties: predicted, not the last ones


def _run(*args: str, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", "run", *args, "--no-ui", "--no-control"],
                          capture_output=True, text=True, timeout=timeout, cwd=REPO_ROOT)


def test_the_default_scenario_at_1ms_passes_its_checks_on_sil() -> None:
    result = _run("--target", "sil:an1017", "--set", "link.period_us=1000")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "predicted duties" in result.stdout and "check speed_error: PASS" in result.stdout


@pytest.mark.skipif(shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file(),
                    reason="avr-gcc and libsimavr-dev are needed")
def test_the_default_scenario_at_1ms_passes_its_checks_on_the_avr() -> None:
    result = _run("--target", "simavr:an1017", "--set", "link.period_us=1000")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "predicted duties" in result.stdout and "check settling_time: PASS" in result.stdout
