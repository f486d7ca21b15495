"""Sensor faults: each kind a class whose filter changes what the target gets of the Sensors.

The filters on Sensors tuples, exactly; then on a bench, through the loopback target, whose Drive
echoes its inputs (duties = ADC codes, telemetry = encoder, edge time, seq): what it echoes is
what the fault left.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import hilbench
from hilbench.bench.faults import FAULT_KINDS, SensorFaults
from hilbench.protocol import Input, Sensors

S2 = int(Input.S2)
Edges = tuple[tuple[int, int], ...]


def sensors(inputs: int, edges: Edges | None = None, encoder: int = 1000, adc: tuple[int, ...] = (512, 300, 640)) -> Sensors:
    """A period's Sensors; its one edge at 123 x 100 ns to the halls of ``inputs`` unless ``edges``."""
    return Sensors(7, inputs, ((123, inputs & 7),) if edges is None else edges, encoder, adc)


def test_every_kind_is_a_class_and_clear_ends_them() -> None:
    assert FAULT_KINDS[-1] == "clear"
    assert {"hall_a_high", "hall_c_low", "hall_missing_edge", "encoder_glitch"} <= set(FAULT_KINDS)


def test_a_stuck_hall_line_changes_that_bit_only() -> None:
    faults = SensorFaults()
    faults.apply("hall_b_high", 0.0, None)
    assert faults.filter(sensors(0b001 | S2)) == sensors(0b011 | S2)  # on every edge too
    faults.apply("hall_a_low", 0.0, None)  # a new fault replaces the passing one
    assert faults.filter(sensors(0b101)) == sensors(0b100)
    assert faults.filter(sensors(0b101, edges=((5, 0b001), (90, 0b101)))) == sensors(0b100, edges=((5, 0b000), (90, 0b100)))
    assert faults.filter(sensors(0b010)) == sensors(0b010)


def test_a_missing_edge_swallows_the_next_hall_change_once() -> None:
    faults = SensorFaults()
    faults.halls.last = 0b001
    faults.apply("hall_missing_edge", 0.0, None)
    assert faults.filter(sensors(0b001, edges=())) == sensors(0b001, edges=())  # no change yet
    two = ((400, 0b011), (410, 0b010))  # this period's edges: none reaches the target
    assert faults.filter(sensors(0b010 | S2, edges=two)) == sensors(0b001 | S2, edges=())
    assert not faults.on  # spent: the next change reaches the target


def test_an_encoder_glitch_loses_counts_for_good() -> None:
    faults = SensorFaults()
    faults.apply("encoder_glitch", 0.0, None)
    assert faults.filter(sensors(0, encoder=65530)).encoder == (65530 + 7) & 0xFFFF
    faults.apply("hall_c_high", 1.0, 0.5)
    assert faults.clear_at_s == 1.5
    assert faults.filter(sensors(0, encoder=10)) == sensors(0b100, encoder=17)
    faults.apply("clear", 1.5, None)
    assert faults.on and faults.filter(sensors(0, encoder=10)) == sensors(0, encoder=17) and faults.clear_at_s == math.inf


def test_the_target_gets_what_the_fault_leaves() -> None:
    """The loopback target echoes the encoder: 7 counts lost from the glitch's period on."""
    with hilbench.Bench(target="inprocess:loopback") as bench:
        bench.run(0.01)
        bench.inject_fault("encoder_glitch")
        bench.run(0.01)
        signals = bench.signals()
    echo = signals["echo_encoder"]
    assert np.all(echo[200:] - echo[:200].mean() == 7) and np.ptp(echo[:200]) == 0


def test_an_unknown_kind_is_refused_with_the_nearest_name() -> None:
    with hilbench.Bench(target="inprocess:loopback") as bench:
        with pytest.raises(hilbench.ConfigError, match="encoder_glitch"):
            bench.inject_fault("encoder_glich")
    with pytest.raises(hilbench.ConfigError, match="did you mean 'encoder_glitch'"):
        hilbench.load_config(None, ['scenario=[{at_s = 0.1, fault = "encoder_glich"}]'])


def test_an_adc_offset_shifts_every_channel_by_a_32nd_of_full_scale() -> None:
    """The 10-bit ADC of the loopback target (full scale 1023): 32 codes more, 1023 at most; the
    loopback's duties echo its ADC codes (the pot's and the bus voltage's do not depend on the
    plant), so a twin run without the fault differs by exactly that while the fault lasts."""
    faults = SensorFaults()
    faults.apply("adc_offset", 0.0, None)
    assert faults.filter(sensors(0, adc=(1000, 10, 1023))) == sensors(0, adc=(1023, 42, 1023))
    duties = []
    for fault in (False, True):
        with hilbench.Bench(target="inprocess:loopback") as bench:
            bench.run(0.005)  # periods 0..99
            if fault:
                bench.inject_fault("adc_offset", duration_s=0.005)  # periods 100..199
            bench.run(0.01)
            signals = bench.signals()
        duties.append(np.stack([signals["duty_a"], signals["duty_c"]]))  # the pot and bus channels: not the plant's currents
    shift = duties[1] - duties[0]
    assert np.all(shift[:, :100] == 0) and np.all(shift[:, 200:] == 0)
    during = duties[0][:, 100:200]
    assert np.array_equal(shift[:, 100:200], np.minimum(during + 32, 1023) - during) and np.all(shift[:, 100:200] > 0)


def test_a_missing_edge_mid_run_holds_the_halls_of_the_last_sensors() -> None:
    """Injected long after the start, a missing edge holds the halls the target got last — not
    those of the run's start (the fault's baseline was set once, when the session began)."""
    with hilbench.Bench() as bench:  # AN1017 in process
        bench.set_reference(1000.0)
        bench.press("s2")
        bench.run(0.4)
        assert bench.speed_rpm > 500
        session = bench.session
        assert session is not None
        got: list[Sensors] = []
        step = session.target.step
        session.target.step = lambda s: (got.append(s), step(s))[1]  # type: ignore[method-assign]
        session._rows_changed = True  # the periods' runner binds the step again
        start_halls = int(bench.signals()["hall"][0])
        bench.inject_fault("hall_missing_edge")
        for _ in range(2000):  # one period at a time, up to the first hall change
            before = session.hall_bits_sent
            bench.run(50e-6)
            if session.hall_bits_sent != before:
                break
        else:
            raise AssertionError("no hall change in 0.1 s")
        assert before != start_halls, "the run's start halls again: the test shows nothing"
        assert got[-1].inputs & 7 == before and got[-1].edges == ()  # the last halls, none of the edges


def test_a_missing_edge_after_a_forced_line_holds_the_forced_halls_the_target_got() -> None:
    """A missing edge injected while a stuck line is in force: its baseline is the halls the target
    got (forced), not the plant's, so the forced line's end is the change it holds back once."""
    faults = SensorFaults()
    faults.apply("hall_b_high", 0.0, None, hall_bits=0b001)
    assert faults.filter(sensors(0b001)) == sensors(0b011)  # the target gets b forced high
    faults.apply("hall_missing_edge", 0.1, None, hall_bits=0b001)  # the plant's halls: 0b001
    assert faults.filter(sensors(0b001)) == sensors(0b011, edges=())  # the jump back to the plant's: held once
    assert not faults.on
