"""Issue 4 acceptance over a pty: the AN1017 emulator as its own process (`python -m hilbench
emulate an1017 --port PTY`) driven by a scripted Sensors stream, no plant.

Expectations come from the issue and brief texts, the design contract and hand arithmetic:
- HELLO: PWM period 1000 counts = 100 % (design.md "AN1017: 1000"), PWM ISR 20 kHz, 8 declared
  parameters, the pot among the ADC roles (RefSpeed from AN2), RefSpeed / MeasuredSpeed /
  ControlOutput telemetry.
- Parameters, ids in this order: kp, ki, kd, ph_adv_on, ph_adv_deg, ref_ovr_on, ref_override,
  stall_ms. Gain constraints (AN1017): Kp+Ki+Kd < 0.9999 and -Kp-2Kd > -1.0; in Q15
  0.9999 * 32768 = 32764.7 and -1.0 = -32768, so a gain sum of 32760 passes and 32767 fails, and
  Kp+2Kd = 32766 passes and 32768 fails. Constraint numbers are the issue's order (1, 2, 3).
- S2 acts on release (press, then let go). ChargeBootstraps holds the low sides on for 10 ms
  = 200 PWM periods of 50 us; lockstep advances exactly one 50 us period per Sensors and applies
  the inputs at the start of it, so exactly 200 Drives report LOW_SIDE, then PWM; S2 again: OFF.
- Real time, watchdog 50 ms: when Sensors stop, a Drive with outputs OFF and fault WATCHDOG comes.
"""

from __future__ import annotations

import time

import pytest

from hilbench.bench.linktest import _Spawned
from hilbench.errors import ParamError
from hilbench.protocol import (
    ACCESS_RW,
    ADC_POT,
    FAULT_NONE,
    FAULT_WATCHDOG,
    INPUT_S2,
    MODE_LOCKSTEP,
    MODE_REALTIME,
    OUTPUT_LOW_SIDE,
    OUTPUT_OFF,
    OUTPUT_PWM,
    PROTOCOL_VERSION,
    PTYPE_BOOL,
    PTYPE_Q15,
    RESULT_CONSTRAINT,
    RESULT_OK,
    RESULT_OUT_OF_RANGE,
    RESULT_UNKNOWN_ID,
    STATE_BOOTSTRAP,
    STATE_RUNNING,
    STATE_STOPPED,
    TELEMETRY_CONTROL_OUTPUT,
    TELEMETRY_MEASURED_SPEED,
    TELEMETRY_REF_SPEED,
    ErrorCode,
    Sensors,
)
from hilbench.targets.remote import RemoteTarget

pytestmark = pytest.mark.slow

PARAM_NAMES = ("kp", "ki", "kd", "ph_adv_on", "ph_adv_deg", "ref_ovr_on", "ref_override", "stall_ms")
KP, KI, KD, PH_ADV_ON = 0, 1, 2, 3
HALLS = 0b001  # a valid hall state (sector 4 by Table 8); the rotor never moves in these scripts
POT_CODE = 712  # pot above mid-scale: a positive speed reference
WATCHDOG_MS = 50


class Emulator:
    """The AN1017 emulator process on a pty this test made, with a RemoteTarget on our end."""

    def __init__(self, *emulate_args: str) -> None:
        self.spawned = _Spawned("an1017", 2.0, emulate_args=emulate_args)
        self.remote = RemoteTarget(self.spawned.link, timeout_s=2.0)
        self.seq = 0

    def sensors(self, inputs: int = HALLS) -> Sensors:
        self.seq = (self.seq + 1) & 0xFF
        return Sensors(self.seq, inputs, (), 0, (POT_CODE, 0, 700))

    def close(self) -> None:
        self.spawned.close()  # closes our end: the emulator sees the hang-up and exits; reaped


@pytest.fixture
def lockstep():
    emu = Emulator("--mode", "lockstep")
    try:
        yield emu
    finally:
        emu.close()


def test_handshake_declares_the_an1017_profile(lockstep: Emulator) -> None:
    hello = lockstep.remote.handshake(50, MODE_LOCKSTEP, 0, attempts=5)
    assert hello.protocol_version == PROTOCOL_VERSION
    assert hello.firmware_name.upper().startswith("AN1017")
    assert hello.pwm_period_counts == 1000
    assert hello.pwm_freq_hz == 20_000
    assert hello.n_params == 8
    assert ADC_POT in hello.adc_roles
    assert {TELEMETRY_REF_SPEED, TELEMETRY_MEASURED_SPEED, TELEMETRY_CONTROL_OUTPUT} <= set(hello.telemetry_ids)


def test_parameter_table_and_gain_writes(lockstep: Emulator) -> None:
    remote = lockstep.remote
    remote.handshake(50, MODE_LOCKSTEP, 0, attempts=5)
    table = remote.describe_all()
    assert [p.name for p in table] == list(PARAM_NAMES)
    assert [p.param_id for p in table] == list(range(8))
    for p in (table[KP], table[KI], table[KD]):
        assert p.ptype == PTYPE_Q15 and 0 <= p.min_value and p.max_value <= 32767
    for p in (table[PH_ADV_ON], table[5]):
        assert p.ptype == PTYPE_BOOL and (p.min_value, p.max_value) == (0, 1)
    # the model declares no read-only parameter, so READ_ONLY cannot be provoked here
    assert all(p.access == ACCESS_RW for p in table)
    with pytest.raises(ParamError):
        remote.describe(8)

    def gains() -> tuple[int, int, int]:
        return tuple(remote.get_param(pid).value for pid in (KP, KI, KD))  # type: ignore[return-value]

    ok = remote.set_params(((KP, 8000), (KI, 1000), (KD, 2000)))
    assert ok.result == RESULT_OK
    assert gains() == (8000, 1000, 2000)

    # out of range, unknown id: refused, naming the parameter, nothing written
    r = remote.set_params(((KP, -1),))
    assert (r.result, r.param_id) == (RESULT_OUT_OF_RANGE, KP)
    r = remote.set_params(((KI, 100), (PH_ADV_ON, 2)))
    assert (r.result, r.param_id) == (RESULT_OUT_OF_RANGE, PH_ADV_ON)
    r = remote.set_params(((KI, 100), (8, 1)))
    assert (r.result, r.param_id) == (RESULT_UNKNOWN_ID, 8)
    assert remote.get_param(8).result == RESULT_UNKNOWN_ID
    assert gains() == (8000, 1000, 2000)

    # constraint 1: Kp+Ki+Kd < 0.9999 (32764.7 in Q15); Kp+2Kd stays below 32768 in both
    r = remote.set_params(((KP, 12767), (KI, 10000), (KD, 10000)))  # sum 32767
    assert (r.result, r.detail) == (RESULT_CONSTRAINT, 1)
    assert r.param_id in (KP, KI, KD)
    r = remote.set_params(((KP, 20000), (KI, 10000), (KD, 3000)))  # sum 33000
    assert (r.result, r.detail) == (RESULT_CONSTRAINT, 1)
    assert gains() == (8000, 1000, 2000)
    assert remote.set_params(((KP, 12760), (KI, 10000), (KD, 10000))).result == RESULT_OK  # sum 32760
    assert gains() == (12760, 10000, 10000)

    # constraint 2: -Kp-2Kd > -1.0, i.e. Kp+2Kd < 32768; the gain sum stays below 32764
    r = remote.set_params(((KP, 16000), (KI, 0), (KD, 8384)))  # Kp+2Kd = 32768
    assert (r.result, r.detail) == (RESULT_CONSTRAINT, 2)
    assert r.param_id in (KP, KD)
    r = remote.set_params(((KP, 16000), (KI, 0), (KD, 8400)))  # Kp+2Kd = 32800
    assert (r.result, r.detail) == (RESULT_CONSTRAINT, 2)
    assert gains() == (12760, 10000, 10000)
    assert remote.set_params(((KP, 16000), (KI, 0), (KD, 8383))).result == RESULT_OK  # Kp+2Kd = 32766
    assert gains() == (16000, 0, 8383)
    # constraint 3 (Kd < 0.9999) cannot break alone: with Kp, Ki >= 0, Kd >= 32765 breaks 1 first


def test_start_bootstrap_pwm_stop_via_s2(lockstep: Emulator) -> None:
    emu = lockstep
    step = emu.remote.step
    emu.remote.handshake(50, MODE_LOCKSTEP, 0, attempts=5)
    for _ in range(5):
        d = step(emu.sensors())
        assert (d.output_mode, d.state, d.fault) == (OUTPUT_OFF, STATE_STOPPED, FAULT_NONE)
    for _ in range(2):  # S2 held down: nothing happens until it is released
        d = step(emu.sensors(HALLS | INPUT_S2))
        assert d.output_mode == OUTPUT_OFF
    drives = [step(emu.sensors()) for _ in range(260)]  # released: RunMotor
    modes = [(d.output_mode, d.state) for d in drives]
    assert modes[:200] == [(OUTPUT_LOW_SIDE, STATE_BOOTSTRAP)] * 200
    assert modes[200:] == [(OUTPUT_PWM, STATE_RUNNING)] * 60
    assert all(d.fault == FAULT_NONE for d in drives)
    assert all(0 <= x <= 1023 for d in drives for x in (d.duty_a, d.duty_b, d.duty_c))
    step(emu.sensors(HALLS | INPUT_S2))
    stopped = [step(emu.sensors()) for _ in range(3)]
    assert [(d.output_mode, d.state) for d in stopped] == [(OUTPUT_OFF, STATE_STOPPED)] * 3
    status = emu.remote.status()
    assert status.rx_errors == 0 and status.last_error == ErrorCode.NONE
    assert emu.remote.stale_frames == 0 and emu.spawned.link.stats.seq_gaps == 0


def test_realtime_watchdog_turns_outputs_off(record_property) -> None:
    emu = Emulator("--mode", "realtime")
    try:
        remote = emu.remote
        remote.handshake(50, MODE_REALTIME, WATCHDOG_MS, attempts=5)
        step = remote.step
        step(emu.sensors())
        step(emu.sensors(HALLS | INPUT_S2))
        # run on the emulator's wall clock until the 10 ms bootstrap is over and PWM is on
        deadline = time.monotonic() + 10.0
        drive = step(emu.sensors())
        while drive.output_mode != OUTPUT_PWM:
            assert time.monotonic() < deadline, f"no PWM after S2 within 10 s (last {drive})"
            drive = step(emu.sensors())
        # silence: the emulator's watchdog must turn the outputs off by itself; RemoteTarget waits
        # at most watchdog_ms + its 2 s timeout, a generous bound for a loaded 2-core VM
        t_silent = time.monotonic()
        tripped = remote.watchdog_trip()
        delay_ms = (time.monotonic() - t_silent) * 1000.0
        record_property("watchdog_delay_ms", round(delay_ms, 2))
        print(f"watchdog Drive {delay_ms:.1f} ms after the last Sensors (watchdog {WATCHDOG_MS} ms)")
        assert tripped.output_mode == OUTPUT_OFF
        assert tripped.fault == FAULT_WATCHDOG
        status = remote.status()
        assert status.watchdog_trips >= 1
        assert status.last_error == ErrorCode.WATCHDOG
    finally:
        emu.close()
