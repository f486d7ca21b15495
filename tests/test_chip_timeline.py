"""Acceptance (issue 11, finding 1): lockstep adds no latency to the chip's own timeline.

The reference here is a loop written for this test, on the dsPIC's timeline and nothing else:
at every PWM boundary the ADC ISR reads the pot, PDC1..3 latch what the PWM ISR wrote one period
earlier (PWMCON2.IUE = 0) and the PWM ISR writes the next ones; during the period the plant runs
on the latched registers, and the Timer1 and hall ISRs run at their own times inside it (a hall
edge at the time the plant crossed it). It calls the Python firmware model only for its
ISR-level routines (Timer1, hall capture/ISRs, RunMotor, StopMotor) and the SVM table; the
PWM ISR, the ADC ISR, the register latch and the ordering of events are this file's own.

That loop and a lockstep session over the emulator process (`emulator:an1017`) run the default
scenario on the packaged Hurst config; their step responses must agree: rise and settling times
within 5 %, phase-current peaks within 5 %. The lockstep run must still follow each reference
within 2 %. Before the fix (Drive = the registers latched at the start of the span) the step
settled 14-16 % slower and the current peaks were 16-28 % lower (issue 11).
"""

from __future__ import annotations

import numpy as np
import pytest

from hilbench.bench.bench import Bench
from hilbench.bench.settings import load_config
from hilbench.config import plant_params_from_config
from hilbench.plant.model import Plant
from hilbench.targets.an1017.firmware import An1017Firmware
from hilbench.targets.an1017.svm import svm

TCY_PER_S = 20_000_000  # FCY = 20 MHz
PWM_TCY = 1000  # 20 kHz centre-aligned PWM: 2·(PTPER+1) Tcy
PERIOD_S = PWM_TCY / TCY_PER_S
ADC_ROLES = (1, 2, 3)  # the channels AN1017's HELLO declares: pot, bus current, bus voltage
OFF, PWM, LOW_SIDE = 0, 1, 2  # output modes (docs/design.md)

# The application note's speed scale, derived by hand: MeasuredSpeed = 312·32768/Period with Period
# in TMR3 ticks (Tcy/64 = 3.2 µs) between two hall-B edges (IC7 captures both), i.e. half an
# electrical revolution; a 10-pole motor then turns 60/(2·5·Period·3.2e-6) = 1 875 000/Period rpm,
# so one Q15 step of speed is 1 875 000/(312·32768) rpm. The pot's code gives RefSpeed = (code − 512)·64.
RPM_PER_Q15 = 60.0 / (2 * 5 * 3.2e-6) / (312 * 32768)

# the default scenario (hilbench/bench/scenario.py default_scenario), restated
RAMP_S, START_S, STEP_S, REVERSE_S, STOP_S, END_S = 0.3, 0.03, 1.2, 2.2, 3.6, 3.8
BUTTON_HOLD_S = 0.002  # S2 is released 2 ms after the press; the firmware starts on the release


def reference_rpm(t_s: float) -> float:
    if t_s < RAMP_S:
        return 1500.0 * t_s / RAMP_S
    if t_s < STEP_S:
        return 1500.0
    if t_s < REVERSE_S:
        return 2500.0
    return -1500.0


def pot_code(rpm: float) -> int:
    return min(1023, max(0, 512 + round(rpm / RPM_PER_Q15 / 64)))


def pwm_isr(fw: An1017Firmware) -> tuple[int, int, int]:
    """The note's PWM ISR: Phase advances by PhaseInc in the running direction (not while the
    requested direction differs: the motor is braking), then SVM(ControlOutput, Phase + advance);
    a CCW request drives with −(ControlOutput + 1) (the one's complement of the negative output)."""
    co = fw.control_output
    if fw.req_ccw:
        volts = -(co + 1)
        if fw.cur_ccw:
            fw.phase = (fw.phase - fw.phase_inc) & 0xFFFF
    else:
        volts = co
        if not fw.cur_ccw:
            fw.phase = (fw.phase + fw.phase_inc) & 0xFFFF
    a, b, c = svm(volts, (fw.phase + fw.phase_adv) & 0xFFFF)
    return min(a, 1000), min(b, 1000), min(c, 1000)


def chip_timeline_run(plant: Plant) -> dict[str, np.ndarray]:
    """The default scenario on the chip's timeline; per period: t_s, speed_rpm, max |i_phase|."""
    fw = An1017Firmware()
    n = round(END_S / PERIOD_S)
    pdc_written = (500, 500, 500)  # PDC = PTPER after reset (50 %): outputs are off anyway
    speed = np.empty(n)
    i_peak = np.empty(n)
    started = stopped = False
    for k in range(n):
        t0 = k * PWM_TCY
        t_s = k * PERIOD_S
        plant.pot_fraction = pot_code(reference_rpm(t_s)) / 1023
        if not started and t_s >= START_S + BUTTON_HOLD_S:
            started = True
            fw.t = t0
            fw.press_start()  # ChargeBootstraps: 10 ms of low-side switches, then RunMotor
        if not stopped and t_s >= STOP_S + BUTTON_HOLD_S:
            stopped = True
            fw.press_stop()
        # ---- the boundary at t0: ADC ISR, register latch, PWM ISR
        fw.pot_code = plant.adc_codes(ADC_ROLES)[0]  # (all three sampled, as a board's ADC does)
        fw.ref_speed = ((fw.pot_code & 0x3FF) - 512) << 6  # ADC ISR at the PWM rate (the note)
        pdc_active = pdc_written  # IUE = 0: what the ISR wrote one period ago takes effect now
        if fw.running:
            pdc_written = pwm_isr(fw)
        # ---- the period [t0, t0 + PWM_TCY): the plant on the latched registers ...
        mode = fw.output_mode
        plant.step(pdc_active[0] / 1000, pdc_active[1] / 1000, pdc_active[2] / 1000, mode, PERIOD_S)
        # ... and the other ISRs at their own times inside it (Timer1 before a hall ISR on a tie)
        events: list[tuple[int, int]] = []
        if plant.hall_bits != fw.hall:  # (before the first edge: the inputs as they are at power-on)
            edge_s = plant.last_edge_s or 0.0
            events.append((t0 + min(int(edge_s * TCY_PER_S), PWM_TCY - 1), 2))
        if fw.booting and fw.boot_end < t0 + PWM_TCY:
            events.append((fw.boot_end, 0))
        for at, kind in sorted(events):
            while fw.running and fw.t1_next <= at:
                fw.t1_next += 20096  # Timer1: (PR1 + 1)·64 Tcy
                fw._timer1()
            if kind == 0:
                fw._run_motor()
            else:
                fw._apply_hall(plant.hall_bits, at)
        while fw.running and fw.t1_next < t0 + PWM_TCY:
            fw.t1_next += 20096
            fw._timer1()
        fw.t = t0 + PWM_TCY
        speed[k] = plant.speed_rpm
        i_peak[k] = max(abs(i) for i in plant.i_abc)
    return {"t_s": np.arange(n) * PERIOD_S, "speed_rpm": speed, "i_peak_a": i_peak}


def step_figures(t_s: np.ndarray, speed: np.ndarray, i_peak: np.ndarray, at_s: float, until_s: float,
                 before: float, after: float) -> dict[str, float]:
    """Rise time (10→90 % of the change), settling time (from the step to the last exit from a
    band of 2 % of the change around the final value, the mean of the segment's last 0.1 s), and
    the phase-current peak, of one step."""
    sel = (t_s >= at_s) & (t_s < until_s)
    t, w = t_s[sel] - at_s, speed[sel]
    final = float(w[t >= t[-1] - 0.1].mean())
    change = after - before
    frac = (w - before) / change
    rise = t[np.argmax(frac >= 0.9)] - t[np.argmax(frac >= 0.1)]
    outside = np.abs(w - final) > 0.02 * abs(change)
    settle = t[np.nonzero(outside)[0][-1] + 1]
    return {"rise_s": float(rise), "settle_s": float(settle), "i_peak_a": float(i_peak[sel].max())}


@pytest.fixture(scope="module")
def both_runs() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    cfg = load_config(None)
    chip = chip_timeline_run(Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps))
    with Bench(None, target="emulator:an1017", scenario=True) as bench:
        bench.run()
        s = bench.signals()
        currents = np.max(np.abs(np.stack([s["ia_a"], s["ib_a"], s["ic_a"]])), axis=0)
        lockstep = {"t_s": np.asarray(s["t_s"]), "speed_rpm": np.asarray(s["speed_rpm"]), "i_peak_a": currents}
    return chip, lockstep


def _segment_mean(run: dict[str, np.ndarray], t0: float, t1: float) -> float:
    sel = (run["t_s"] >= t0) & (run["t_s"] < t1)
    return float(run["speed_rpm"][sel].mean())


@pytest.mark.parametrize("at_s,until_s,before,after", [(STEP_S, REVERSE_S, 1500.0, 2500.0),
                                                       (REVERSE_S, STOP_S, 2500.0, -1500.0)])
def test_lockstep_step_response_matches_the_chip_timeline(both_runs, at_s, until_s, before, after):
    chip, lockstep = both_runs
    fig_chip = step_figures(chip["t_s"], chip["speed_rpm"], chip["i_peak_a"], at_s, until_s, before, after)
    fig_lock = step_figures(lockstep["t_s"], lockstep["speed_rpm"], lockstep["i_peak_a"], at_s, until_s, before, after)
    for name in ("rise_s", "settle_s", "i_peak_a"):
        assert fig_lock[name] == pytest.approx(fig_chip[name], rel=0.05), (name, fig_lock, fig_chip)


def test_start_current_peak_matches_the_chip_timeline(both_runs):
    chip, lockstep = both_runs
    peaks = [float(run["i_peak_a"][(run["t_s"] >= START_S) & (run["t_s"] < STEP_S)].max()) for run in both_runs]
    assert peaks[1] == pytest.approx(peaks[0], rel=0.05)
    assert chip is both_runs[0] and lockstep is both_runs[1]


@pytest.mark.parametrize("t0,t1,ref_rpm", [(1.0, STEP_S, 1500.0), (2.0, REVERSE_S, 2500.0), (3.3, STOP_S, -1500.0)])
def test_default_run_follows_each_reference(both_runs, t0, t1, ref_rpm):
    chip, lockstep = both_runs
    assert _segment_mean(lockstep, t0, t1) == pytest.approx(ref_rpm, rel=0.02)
    assert _segment_mean(chip, t0, t1) == pytest.approx(ref_rpm, rel=0.02)
